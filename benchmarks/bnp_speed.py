"""ms per frame of DDP-EMM and DPY-STP on vo2017 (one process, one core), in the same run:
the session-3 sampler (one chain, single-site moves only: ``swap_moves=false chains=1``) and
today's default (two chains with pair exchanges), compiled by numba, and the default with
the sampler's kernels interpreted (the same functions; ``gibbs.interpreted_kernels``: the
sweeps and their set-up, not the rest of the step's kernels in ``tracker/bnp/_kernels.py``).

    taskset -c 0 python3 benchmarks/bnp_speed.py --seeds 3 [--repeats 5]

The first frame of the compiled run includes loading numba's on-disk cache; it is excluded
(``--warmup`` frames per run are dropped from the statistics).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import msgspec
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import bnptrack.tracker.bnp.gibbs as gibbs  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp import TRACKER_PRESETS, make_tracker  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def ms_per_frame(name: str, seeds: int, warmup: int, old: bool = False) -> tuple[np.ndarray, float]:
    """Wall-clock ms of each frame (the estimate's ``ms``) and the mean CPU ms per frame of
    this thread (``time.thread_time``, which a loaded machine inflates much less)."""
    params = get_scenario("vo2017").adapt_params(load_params("vo2017"))  # with its birth regions
    cfg = TRACKER_PRESETS[name]
    tracker = make_tracker(name, params, msgspec.structs.replace(cfg, swap_moves=False, chains=1) if old else cfg)
    out, cpu, n = [], 0.0, 0
    for seed in range(1, seeds + 1):
        frames = simulate_all(get_scenario("vo2017"), params, seed)
        list(run(tracker, frames[:warmup], seed))
        t0 = time.thread_time()
        ms = [e.diagnostics["ms"] for _, e, _ in run(tracker, frames, seed)]
        cpu += time.thread_time() - t0
        n += len(frames)
        out.extend(ms[warmup:])
    return np.array(out), cpu * 1e3 / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=1,
                    help="run each setting this many times, interleaved; each frame's figure is its minimum "
                         "over the repeats (robust to other processes on a shared machine)")
    args = ap.parse_args()
    compiled = {k: getattr(gibbs, k) for k in gibbs.interpreted_kernels()}

    def measure(name: str, old: bool, interpreted: bool) -> tuple[np.ndarray, float]:
        for k, fn in (gibbs.interpreted_kernels() if interpreted else compiled).items():
            setattr(gibbs, k, fn)
        try:
            return ms_per_frame(name, args.seeds, args.warmup, old)
        finally:
            for k, fn in compiled.items():
                setattr(gibbs, k, fn)

    settings = (("1 chain, no swaps", "numba", True, False), ("default", "numba", False, False),
                ("default", "interpreted", False, True))
    print(f"minimum over {args.repeats} interleaved repeat(s) per frame")
    print("| tracker | sampler | kernel | ms/frame median | p95 | CPU ms/frame mean | ratio to default compiled (median) |")
    print("|---|---|---|---|---|---|---|")
    for name in ("ddp-mb", "dpyp-mb"):
        runs: dict[int, list] = {i: [] for i in range(len(settings))}
        for _ in range(args.repeats):
            for i, (_, _, old, interp) in enumerate(settings):
                runs[i].append(measure(name, old, interp))
        rows = [(np.min([r[0] for r in runs[i]], axis=0), min(r[1] for r in runs[i])) for i in runs]
        ref = np.median(rows[1][0])
        for (label, kernel, _, _), (x, c) in zip(settings, rows):
            print(f"| {name} | {label} | {kernel} | {np.median(x):.2f} | {np.percentile(x, 95):.2f} "
                  f"| {c:.2f} | {np.median(x) / ref:.2f} |")


if __name__ == "__main__":
    main()
