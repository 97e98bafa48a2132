"""CPU time per frame of one tracker under two settings (A: its preset, B: the preset with
``--set`` overrides), the same frames, in one process, the order of A and B alternating from
seed to seed and between two rounds, so that both see the same load.  Prints each side's CPU
ms per frame (``tracker.step`` only) and the ratio A / B.

    python benchmarks/settings_cpu.py --tracker ddp --scenario random --seeds 10 \\
        --set objects.state_update=best-permutation --set share_after=6
    python benchmarks/settings_cpu.py --tracker ddp --scenario vo2017 --scene-set 'params.birth=[]' --seeds 10 \\
        --set objects.state_update=best-permutation --set share_after=6
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(__file__))

from accuracy import setup  # noqa: E402
from bnptrack.tracker.state import tracker_frame_rng  # noqa: E402


def step_seconds(tracker_name: str, params: str, scenario: str, seed: int, overrides: list[str]) -> tuple[float, int]:
    """CPU seconds of ``tracker.step`` over the frames of ``seed``, and the number of frames."""
    _, tracker, frames = setup(tracker_name, params, scenario, seed, overrides)
    state = tracker.initial_state()
    t0 = time.process_time()
    for f in frames:
        state, _ = tracker.step(state, f, tracker_frame_rng(seed, f.frame))
    return time.process_time() - t0, len(frames)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="side B's tracker overrides")
    ap.add_argument("--scene-set", dest="common", action="append", default=[],
                    help="overrides of both sides (params.KEY=V, scene.KEY=V)")
    args = ap.parse_args()
    sides = {"A": list(args.common), "B": list(args.common) + list(args.overrides)}
    cpu, frames = {"A": 0.0, "B": 0.0}, {"A": 0, "B": 0}
    for side in "AB":  # compile (or load) each side's kernels before timing
        step_seconds(args.tracker, args.params, args.scenario, args.first_seed, sides[side])
    for r in range(args.rounds):
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            order = "AB" if (seed + r) % 2 else "BA"
            for side in order:
                s, n = step_seconds(args.tracker, args.params, args.scenario, seed, sides[side])
                cpu[side] += s
                frames[side] += n
    ms = {k: 1e3 * cpu[k] / frames[k] for k in cpu}
    print(f"{args.tracker} {args.scenario} seeds {args.first_seed}..{args.first_seed + args.seeds - 1} x {args.rounds}: "
          f"A (preset) {ms['A']:.2f} ms/frame, B ({' '.join(args.overrides) or 'same'}) {ms['B']:.2f} ms/frame, "
          f"A / B {cpu['A'] / cpu['B']:.3f}")
    print(json.dumps({"ms_a": ms["A"], "ms_b": ms["B"], "ratio": cpu["A"] / cpu["B"]}))


if __name__ == "__main__":
    main()
