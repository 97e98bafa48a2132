"""Monte Carlo throughput of an experiment (runs per minute) with 1 and 2 workers, measured
in the same invocation: local processes (``run_jobs(workers=N)``) and, with ``--dask``, a
Dask ``LocalCluster`` of N single-threaded worker processes (``run_jobs(cluster=address)``).

Every configuration runs the same jobs; their per-frame results (OSPA, its parts, OSPA(2),
GOSPA, cardinality, everything but the ``ms`` timings) must be equal bit for bit across
configurations, and the script says so.  It prints the wall time, runs/minute, the 10,000-run
extrapolation, the CPU time of the work (sum of the workers' per-frame ``ms`` is wall time in
the tracker; the process CPU time is ``time.process_time`` of this process plus its children)
and the machine's load average before and after.

    python3 benchmarks/experiment_throughput.py --experiment ddp-vs-glmb --runs 100 --dask
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.pipeline.experiments import RunJob, get_experiment, run_jobs  # noqa: E402

_SERIES = ("ospa", "ospa_loc", "ospa_card", "ospa2", "gospa", "n_est")


def fingerprint(results) -> str:
    """SHA-256 (first 16 hex digits) of every run's per-frame series except the timings."""
    h = hashlib.sha256()
    for r in results:
        h.update(r.n_true.tobytes())
        for label, tr in sorted(r.trackers.items()):
            h.update(label.encode())
            for name in _SERIES:
                h.update(np.ascontiguousarray(getattr(tr, name), dtype=float).tobytes())
    return h.hexdigest()[:16]


def _children_cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def timed(jobs, workers: int, cluster: str | None) -> tuple[float, float, list]:
    c0, t0 = _children_cpu(), time.perf_counter()
    results = run_jobs(jobs, workers=workers, cluster=cluster)
    return time.perf_counter() - t0, _children_cpu() - c0, results


def run_dask(jobs, n_workers: int) -> tuple[float, float, list]:
    """The jobs on a fresh LocalCluster of ``n_workers`` single-threaded processes (started and
    warmed up outside the timing: one job per worker); CPU time is not measured (the workers
    are not children that were waited for)."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
        with Client(cl) as client:
            client.run(_warm)
            t0 = time.perf_counter()
            results = run_jobs(jobs, cluster=cl.scheduler_address)
            return time.perf_counter() - t0, float("nan"), results


def _warm() -> None:
    """Import and load the trackers' compiled kernels in a worker (outside the timing)."""
    from bnptrack.pipeline.experiments import execute_run

    exp = get_experiment("ddp-vs-glmb")
    execute_run(RunJob("ddp-vs-glmb", 999, 0, "vo2017", exp.variants[0]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--experiment", default="ddp-vs-glmb")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--dask", action="store_true", help="also a Dask LocalCluster of each worker count")
    ap.add_argument("--no-pool", dest="pool", action="store_false", help="skip the local process pools")
    args = ap.parse_args()
    exp = get_experiment(args.experiment)
    jobs = [RunJob(args.experiment, 1, i, "vo2017", exp.variants[0]) for i in range(args.runs)]
    run_jobs(jobs[:1], workers=1)  # warm caches (numba) outside the timing
    print(f"{args.experiment}: {args.runs} runs of {len(exp.trackers)} trackers x 100 frames; "
          f"load average {os.getloadavg()[0]:.1f} at the start, {os.cpu_count()} cores")
    print("| executor | workers | seconds | runs/minute | 10,000 runs would take | CPU s/run | results |")
    print("|---|---|---|---|---|---|---|")
    configs = [("processes", w) for w in args.workers if args.pool] + [("dask", w) for w in args.workers if args.dask]
    first, last = None, None
    for kind, w in configs:
        dt, cpu, results = run_dask(jobs, w) if kind == "dask" else timed(jobs, w, None)
        fp = fingerprint(results)
        first = first or fp
        same = "same" if fp == first else f"DIFFERENT ({fp})"
        print(f"| {kind} | {w} | {dt:.1f} | {60 * args.runs / dt:.1f} | {10000 * dt / args.runs / 60:.1f} min | "
              f"{cpu / args.runs:.3f} | {fp} {same} |", flush=True)
        last = results
    share = {t: np.nansum([np.nansum(r.trackers[t].ms) for r in last]) for t in last[0].trackers}
    total = sum(share.values())
    print("tracker compute share (ms diagnostics): "
          + ", ".join(f"{t} {100 * v / total:.0f} % ({v / 1000:.1f} s)" for t, v in share.items()))
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
