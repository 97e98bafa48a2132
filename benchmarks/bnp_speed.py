"""ms per frame of DDP-EMM and DPY-STP on vo2017 (one process, one core), with the Gibbs
sweeps compiled by numba and, in the same run, interpreted (the same kernel function).

    python benchmarks/bnp_speed.py --seeds 3

The first frame of the compiled run includes loading numba's on-disk cache; it is excluded
(``--warmup`` frames per run are dropped from the statistics).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import tracker.gibbs as gibbs  # noqa: E402
from sources.scenarios import get_scenario  # noqa: E402
from sources.synthetic import simulate_all  # noqa: E402
from tracker.bnp_tracker import make_tracker  # noqa: E402
from tracker.models.params import load_params  # noqa: E402
from tracker.state import run  # noqa: E402


def ms_per_frame(name: str, seeds: int, warmup: int) -> np.ndarray:
    params = load_params("vo2017")
    tracker = make_tracker(name, params)
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
    compiled = gibbs._sweeps
    print("| tracker | kernel | ms/frame median | p95 | ratio to compiled (median) |")
    print("|---|---|---|---|---|")
    for name in ("ddp", "dpyp"):
        gibbs._sweeps = compiled
        a = ms_per_frame(name, args.seeds, args.warmup)
        gibbs._sweeps = gibbs._sweep_kernel
        b = ms_per_frame(name, args.seeds, args.warmup)
        gibbs._sweeps = compiled
        print(f"| {name} | numba | {np.median(a):.2f} | {np.percentile(a, 95):.2f} | 1.00 |")
        print(f"| {name} | interpreted | {np.median(b):.2f} | {np.percentile(b, 95):.2f} | {np.median(b) / np.median(a):.1f} |")


if __name__ == "__main__":
    main()
