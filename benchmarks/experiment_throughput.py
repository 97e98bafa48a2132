"""Monte Carlo throughput of an experiment (runs per minute) with 1 and 2 local workers,
measured in the same invocation, plus the per-tracker share of the compute.

    python benchmarks/experiment_throughput.py --experiment ddp-vs-glmb --runs 10
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.pipeline.experiments import RunJob, get_experiment, run_jobs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--experiment", default="ddp-vs-glmb")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    exp = get_experiment(args.experiment)
    jobs = [RunJob(args.experiment, 1, i, "vo2017", exp.variants[0]) for i in range(args.runs)]
    run_jobs(jobs[:1], workers=1)  # warm caches (numba) outside the timing
    print(f"{args.experiment}: {args.runs} runs of {len(exp.trackers)} trackers x 100 frames")
    print("| workers | seconds | runs/minute | 1,000 runs would take |")
    print("|---|---|---|---|")
    last = None
    for w in args.workers:
        t0 = time.perf_counter()
        last = run_jobs(jobs, workers=w)
        dt = time.perf_counter() - t0
        print(f"| {w} | {dt:.1f} | {60 * args.runs / dt:.1f} | {1000 * dt / args.runs / 60:.1f} min |", flush=True)
    share = {t: np.nansum([np.nansum(r.trackers[t].ms) for r in last]) for t in last[0].trackers}
    total = sum(share.values())
    print("tracker compute share: " + ", ".join(f"{t} {100 * v / total:.0f} % ({v / 1000:.1f} s)" for t, v in share.items()))


if __name__ == "__main__":
    main()
