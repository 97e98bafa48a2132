"""Reliability of the published existence: per decile of predicted existence, the fraction of
published tracks that are real (matched to a true object within ``--gate`` metres by the
optimal assignment of the frame's tracks to its true objects).

    python benchmarks/existence_calibration.py --scenario random --seeds 20
    python benchmarks/existence_calibration.py --scenario vo2017 --set 'params.birth=[]' --seeds 20
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, os.path.dirname(__file__))

from lag import online_run  # noqa: E402


def real_flags(frame, est, gate: float) -> np.ndarray:
    """Whether each track of ``est`` is matched to a true object within ``gate`` metres."""
    real = np.zeros(len(est.tracks), bool)
    if est.tracks and frame.truth is not None and frame.truth.ids:
        D = np.linalg.norm(est.positions[:, None] - frame.truth.positions[None], axis=2)
        rows, cols = linear_sum_assignment(np.minimum(D, gate))
        real[rows[D[rows, cols] < gate]] = True
    return real


def one_seed(job):
    tracker, params, scenario, seed, overrides, gate = job
    _sc, _tr, frames, online, _ms = online_run(tracker, params, scenario, seed, overrides)
    ex, real = [], []
    for f, e in zip(frames, online):
        ex += [t.existence for t in e.tracks]
        real += list(real_flags(f, e, gate))
    return np.array(ex, float), np.array(real, bool)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--gate", type=float, default=50.0, help="metres within which a track is real")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    jobs = [(args.tracker, args.params, args.scenario, s, args.overrides, args.gate) for s in seeds]
    with ProcessPoolExecutor(args.workers) as pool:
        res = list(pool.map(one_seed, jobs))
    ex = np.concatenate([r[0] for r in res])
    real = np.concatenate([r[1] for r in res])
    print(f"{args.tracker} on {args.scenario}, seeds {seeds.start}..{seeds.stop - 1}, overrides "
          f"{args.overrides or 'none'}, gate {args.gate:g} m: {len(ex)} published track-frames")
    print("| existence | track-frames | mean predicted | fraction real | gap |")
    print("|---|---|---|---|---|")
    edges = np.linspace(0.0, 1.0, 11)
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (ex >= lo) & ((ex < hi) if hi < 1 else (ex <= hi))
        if sel.any():
            p, q = ex[sel].mean(), real[sel].mean()
            print(f"| [{lo:.1f}, {hi:.1f}{')' if hi < 1 else ']'} | {sel.sum()} | {p:.3f} | {q:.3f} | {q - p:+.3f} |")


if __name__ == "__main__":
    main()
