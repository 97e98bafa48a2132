"""Monte Carlo throughput of an experiment (runs per minute) with 1 and 2 workers, measured
in the same invocation: local processes (``run_jobs(workers=N)``) and, with ``--dask``, a
Dask ``LocalCluster`` of N single-threaded worker processes (``run_jobs(cluster=address)``;
needs the optional extra ``bnptrack[dask]``).  With ``--repeats R`` the configurations run
R times interleaved (A, B, C, D, A, B, ...) to cancel load drift; the pools and clusters are
started and warmed once (:func:`pipeline.experiments.warm_pool`: imports and compiled kernels
loaded), before the first timing.

Every configuration runs the same jobs; their per-frame results (OSPA, its parts, OSPA(2),
GOSPA, cardinality, everything but the ``ms`` timings) must be equal bit for bit across
configurations, and the script says so.  It prints the wall time, runs/minute, the 10,000-run
extrapolation, the CPU time per run (the worker processes' CPU time before and after: ``psutil`` for the
pool, ``time.process_time`` in every Dask worker) and the
machine's load average before and after; with ``--repeats`` also the median of each
configuration and the speed-up of 2 workers over 1 (wall time; and in CPU-limited form:
runs per CPU second, which is what two free cores would turn into wall time).

    python3 benchmarks/experiment_throughput.py --experiment ddp-vs-glmb --runs 100 --dask --repeats 3

``--trackers ddp-groups glmb`` runs only the paper's pair (two-level DDP-EMM and GLMB; the
experiment's default also runs the single-level ablation ``ddp-mb``); a tracker's series are
the same whichever others run beside it.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.pipeline.experiments import RunJob, get_experiment, run_jobs, select_trackers, warm_pool  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _ab import fingerprint  # noqa: E402



def start_pool(stack: contextlib.ExitStack, workers: int):
    """A warm process pool (:func:`warm_pool`: imports and compiled kernels loaded, one run per
    worker) started outside any timing and shut down at the end."""
    pool = warm_pool(workers)
    stack.callback(pool.shutdown)
    return pool


def _pool_cpu(pool) -> float:
    import psutil

    return sum(sum(psutil.Process(pid).cpu_times()[:2]) for pid in pool._processes)


def timed(pool, jobs) -> tuple[float, float, list]:
    """The jobs on a warm pool; CPU time: the workers' process CPU time before and after."""
    c0, t0 = _pool_cpu(pool), time.perf_counter()
    results = run_jobs(jobs, executor=pool)
    return time.perf_counter() - t0, _pool_cpu(pool) - c0, results


def _process_time() -> float:
    return time.process_time()


def start_cluster(stack: contextlib.ExitStack, n_workers: int):
    """A LocalCluster of ``n_workers`` single-threaded processes and its client, warmed up
    (imports, compiled kernels: one run per worker) outside any timing."""
    from distributed import Client, LocalCluster

    cl = stack.enter_context(LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                          dashboard_address=None, host="127.0.0.1"))
    client = stack.enter_context(Client(cl))
    client.run(_warm)
    return client, cl.scheduler_address


def run_dask(cluster, jobs) -> tuple[float, float, list]:
    """The jobs on a warm cluster; CPU time: the workers' process CPU time before and after."""
    client, address = cluster
    c0 = sum(client.run(_process_time).values())
    t0 = time.perf_counter()
    results = run_jobs(jobs, cluster=address)
    dt = time.perf_counter() - t0
    return dt, sum(client.run(_process_time).values()) - c0, results


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
    ap.add_argument("--repeats", type=int, default=1, help="run the configurations this many times, interleaved")
    ap.add_argument("--trackers", nargs="+", default=(), metavar="NAME",
                    help="only these of the experiment's trackers (registry names or labels, e.g. "
                         "ddp-groups glmb: the paper's pair); default all")
    args = ap.parse_args()
    exp = get_experiment(args.experiment)
    picked = select_trackers(exp, args.trackers)
    jobs = [RunJob(args.experiment, 1, i, "vo2017", exp.variants[0], trackers=tuple(args.trackers))
            for i in range(args.runs)]
    run_jobs(jobs[:1], workers=1)  # warm caches (numba) outside the timing
    print(f"{args.experiment}: {args.runs} runs of {len(picked)} trackers ({', '.join(s.label for s in picked)}) "
          f"x 100 frames; "
          f"load average {os.getloadavg()[0]:.1f} at the start, {os.cpu_count()} cores")
    configs = [("processes", w) for w in args.workers if args.pool] + [("dask", w) for w in args.workers if args.dask]
    with contextlib.ExitStack() as stack:
        clients = {w: start_cluster(stack, w) for kind, w in configs if kind == "dask"}
        pools = {w: start_pool(stack, w) for kind, w in configs if kind == "processes"}
        print("| executor | workers | seconds | runs/minute | 10,000 runs would take | CPU s/run | load | results |")
        print("|---|---|---|---|---|---|---|---|")
        measured, first, last = {}, None, None
        for _ in range(args.repeats):
            for kind, w in configs:
                dt, cpu, results = run_dask(clients[w], jobs) if kind == "dask" else timed(pools[w], jobs)
                fp = fingerprint(results)
                first = first or fp
                same = "same" if fp == first else f"DIFFERENT ({fp})"
                measured.setdefault((kind, w), []).append((dt, cpu))
                print(f"| {kind} | {w} | {dt:.1f} | {60 * args.runs / dt:.1f} | {10000 * dt / args.runs / 60:.1f} min | "
                      f"{cpu / args.runs:.3f} | {os.getloadavg()[0]:.1f} | {fp} {same} |", flush=True)
                last = results
    summarise(measured, args.runs)
    share = {t: np.nansum([np.nansum(r.trackers[t].ms) for r in last]) for t in last[0].trackers}
    total = sum(share.values())
    print("tracker compute share (ms diagnostics): "
          + ", ".join(f"{t} {100 * v / total:.0f} % ({v / 1000:.1f} s)" for t, v in share.items()))
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


def summarise(measured: dict, runs: int) -> None:
    """Median wall and CPU time of each configuration; speed-up of the largest worker count
    over 1 (wall) and the CPU per run of each (equal CPU per run: no parallel overhead)."""
    med = {k: (float(np.median([d for d, _ in v])), float(np.median([c for _, c in v]))) for k, v in measured.items()}
    for (kind, w), (dt, cpu) in med.items():
        print(f"median {kind} x{w}: {dt:.1f} s ({60 * runs / dt:.1f} runs/minute), CPU {cpu / runs:.3f} s/run, "
              f"10,000 runs on {w} free core(s): {10000 * cpu / runs / w / 60:.1f} min")
    for kind in dict.fromkeys(k for k, _ in med):
        ws = sorted(w for k, w in med if k == kind)
        if len(ws) > 1 and ws[0] == 1:
            (d1, c1), (dn, cn) = med[(kind, 1)], med[(kind, ws[-1])]
            print(f"{kind}: {ws[-1]} workers over 1: wall {d1 / dn:.2f}x; CPU per run {cn / c1:.2f}x of 1 worker's")


if __name__ == "__main__":
    main()
