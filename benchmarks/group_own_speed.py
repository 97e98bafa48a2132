"""What the own (sharing-free) estimate costs the two-level tracker.

``ddp`` with ``membership=shared`` (the default) and with ``membership=own`` (and the given
``--set`` overrides) step the same frames in one process, one right after the other,
alternating which goes first; each step is timed with this thread's CPU time and the ratio of
the medians (frames 5 on) is printed per seed.

    python benchmarks/group_own_speed.py --scenario groups --seeds 1 2
    python benchmarks/group_own_speed.py --scenario vo2017 --seeds 1 --set share_base=own
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import msgspec
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp.groups import GROUP_PRESETS, GroupTracker  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import tracker_frame_rng  # noqa: E402


def time_seed(scenario: str, seed: int, overrides: list[str]) -> dict[str, float]:
    """Median CPU ms per frame of the default and of ``membership=own`` (plus ``overrides``)."""
    sc = get_scenario(scenario, seed)
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, seed)
    cfg = GROUP_PRESETS["ddp"]
    trackers = {"shared": GroupTracker(params, cfg),
                "own": GroupTracker(params, apply_overrides(msgspec.structs.replace(cfg, membership="own"), overrides))}
    states = {k: t.initial_state() for k, t in trackers.items()}
    times: dict[str, list[float]] = {k: [] for k in trackers}
    for i, f in enumerate(frames):
        for k in (list(trackers) if i % 2 == 0 else list(trackers)[::-1]):
            t0 = time.thread_time()
            states[k], _ = trackers[k].step(states[k], f, tracker_frame_rng(seed, f.frame))
            times[k].append(time.thread_time() - t0)
    return {k: float(np.median(v[5:]) * 1e3) for k, v in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="groups")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="KEY=V for the own tracker")
    args = ap.parse_args()
    for seed in args.seeds:
        ms = time_seed(args.scenario, seed, args.overrides)
        print(f"{args.scenario} seed {seed}: shared {ms['shared']:.3f} ms, own {ms['own']:.3f} ms, "
              f"ratio own/shared {ms['own'] / ms['shared']:.3f}")


if __name__ == "__main__":
    main()
