"""ms per frame of DDP-EMM and DPY-STP on vo2017 (one process, one core), in the same run:
the session-3 sampler (one chain, single-site moves only: ``swap_moves=false chains=1``) and
today's default (two chains with pair exchanges), compiled by numba, and the default with
every kernel interpreted (the same functions).

    taskset -c 0 python3 benchmarks/bnp_speed.py --seeds 3

The first frame of the compiled run includes loading numba's on-disk cache; it is excluded
(``--warmup`` frames per run are dropped from the statistics).
"""

from __future__ import annotations

import argparse
import os
import sys

import msgspec
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import tracker.gibbs as gibbs  # noqa: E402
from sources.scenarios import get_scenario  # noqa: E402
from sources.synthetic import simulate_all  # noqa: E402
from tracker.bnp_tracker import TRACKER_PRESETS, make_tracker  # noqa: E402
from tracker.models.params import load_params  # noqa: E402
from tracker.state import run  # noqa: E402


def ms_per_frame(name: str, seeds: int, warmup: int, old: bool = False) -> np.ndarray:
    params = load_params("vo2017")
    cfg = TRACKER_PRESETS[name]
    tracker = make_tracker(name, params, msgspec.structs.replace(cfg, swap_moves=False, chains=1) if old else cfg)
    out = []
    for seed in range(1, seeds + 1):
        frames = simulate_all(get_scenario("vo2017"), params, seed)
        ms = [e.diagnostics["ms"] for _, e, _ in run(tracker, frames, seed)]
        out.extend(ms[warmup:])
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1)
    args = ap.parse_args()
    compiled = {k: getattr(gibbs, k) for k in gibbs.interpreted_kernels()}
    print("| tracker | sampler | kernel | ms/frame median | p95 | ratio to default compiled (median) |")
    print("|---|---|---|---|---|---|")
    for name in ("ddp", "dpyp"):
        old = ms_per_frame(name, args.seeds, args.warmup, old=True)
        a = ms_per_frame(name, args.seeds, args.warmup)
        for k, fn in gibbs.interpreted_kernels().items():
            setattr(gibbs, k, fn)
        b = ms_per_frame(name, args.seeds, args.warmup)
        for k, fn in compiled.items():
            setattr(gibbs, k, fn)
        ref = np.median(a)
        for label, kernel, x in (("1 chain, no swaps", "numba", old), ("default", "numba", a),
                                 ("default", "interpreted", b)):
            print(f"| {name} | {label} | {kernel} | {np.median(x):.2f} | {np.percentile(x, 95):.2f} "
                  f"| {np.median(x) / ref:.2f} |")


if __name__ == "__main__":
    main()
