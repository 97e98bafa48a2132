"""CPU time per run of experiment 1 (or any experiment): this tree against another checkout,
interleaved, the same runs on both sides.

Round ``r`` runs, one after the other, a fresh process per tree (``PYTHONPATH`` = that tree,
base first) that runs one warm-up run (imports, compiled kernels), then runs
``r * N .. r * N + N - 1`` (seed 1, ``vo2017`` parameters) one after the other and reports
its CPU time per run (``time.process_time``) and the SHA-256 fingerprint of every run's series
(as ``experiment_throughput.py``: OSPA, its parts, OSPA(2), GOSPA, cardinality).
``--trackers`` keeps only those of the experiment's trackers (by patching the experiment in
the measuring process, so it works on checkouts without ``RunJob.trackers``).  It prints each
round, the means, the ratio of the means, the median per-round ratio and the 10,000-run
extrapolation on two free cores; equal fingerprints mean the same results bit for bit.
``--repeats R`` times the same runs R times in each process and keeps the fastest pass (a
burst of load on the shared machine inflates one pass, not all); ``--alternate`` runs this
tree first in odd rounds.  ``--base-numba-cache DIR`` gives the base's processes their own
``NUMBA_CACHE_DIR`` (each checkout keeps a warm cache; otherwise the first round's warm-up
compiles the base's kernels into this one's).

    nice -n 10 python3 benchmarks/experiment_ab.py --base /tmp/base --rounds 8 --runs 25 --trackers ddp-groups glmb
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

from _ab import fingerprint, last_json_line

HERE = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))

def measure(experiment: str, start: int, n: int, names: list[str], repeats: int = 1) -> dict:
    """Runs ``start .. start + n - 1`` in this process: CPU s per run (the fastest of
    ``repeats`` passes over the same runs) and their fingerprint (every pass must give it)."""
    import dataclasses

    from bnptrack.pipeline import experiments as E

    exp = E.get_experiment(experiment)
    if names:
        E.EXPERIMENTS[experiment] = dataclasses.replace(exp, trackers=tuple(
            s for s in exp.trackers if s.name in names or s.label in names))
    E.execute_run(E.RunJob(experiment, 999, 0, "vo2017", exp.variants[0]))  # warm-up, not timed
    jobs = [E.RunJob(experiment, 1, i, "vo2017", exp.variants[0]) for i in range(start, start + n)]
    cpus, fps = [], set()
    for _ in range(max(repeats, 1)):
        c0 = time.process_time()
        results = [E.execute_run(j) for j in jobs]
        cpus.append(time.process_time() - c0)
        fps.add(fingerprint(results))
    fp = fps.pop() if len(fps) == 1 else "PASSES-DIFFER"
    return {"cpu_per_run": min(cpus) / n, "fp": fp, "load": os.getloadavg()[0]}

def run_tree(root: str, args: argparse.Namespace, start: int) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--measure", "--experiment", args.experiment,
           "--start", str(start), "--runs", str(args.runs)] + (["--trackers", *args.trackers] if args.trackers else []) \
        + (["--repeats", str(args.repeats)] if args.repeats > 1 else [])
    cache = args.base_numba_cache if root != HERE else os.environ.get("NUMBA_CACHE_DIR")
    saved = dict(os.environ)
    if cache:  # each tree its own warm kernel cache (numba keys its files by the source's path)
        os.environ["NUMBA_CACHE_DIR"] = cache
    try:
        return last_json_line(cmd, root)
    finally:
        os.environ.clear()
        os.environ.update(saved)

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", help="the other checkout (the baseline)")
    ap.add_argument("--experiment", default="ddp-vs-glmb")
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--runs", type=int, default=25, help="runs per round and side")
    ap.add_argument("--trackers", nargs="+", default=[], metavar="NAME")
    ap.add_argument("--repeats", type=int, default=1,
                    help="passes over the same runs per process; the fastest counts (filters out load bursts)")
    ap.add_argument("--alternate", action="store_true", help="this tree first in odd rounds (default: base first)")
    ap.add_argument("--base-numba-cache", metavar="DIR",
                    help="NUMBA_CACHE_DIR for the base's processes (default: this process's, as for this tree)")
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--start", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        sys.path.insert(0, os.getcwd())
        print(json.dumps(measure(args.experiment, args.start, args.runs, args.trackers, args.repeats)))
        return
    print("| round | base CPU s/run | this tree CPU s/run | ratio | load | fingerprints |\n|---|---|---|---|---|---|")
    base_cpu, new_cpu, ratios = [], [], []
    for r in range(args.rounds):
        if r % 2 and args.alternate:  # odd rounds: this tree first (cancels a drift within the round)
            t = run_tree(HERE, args, r * args.runs)
            b = run_tree(os.path.abspath(args.base), args, r * args.runs)
        else:
            b = run_tree(os.path.abspath(args.base), args, r * args.runs)
            t = run_tree(HERE, args, r * args.runs)
        base_cpu.append(b["cpu_per_run"])
        new_cpu.append(t["cpu_per_run"])
        ratios.append(t["cpu_per_run"] / b["cpu_per_run"])
        same = "equal" if b["fp"] == t["fp"] else f"DIFFERENT {b['fp']} / {t['fp']}"
        print(f"| {r} | {b['cpu_per_run']:.3f} | {t['cpu_per_run']:.3f} | {ratios[-1]:.3f} | "
              f"{b['load']:.1f} / {t['load']:.1f} | {same} {t['fp']} |", flush=True)
    mb, mt = statistics.mean(base_cpu), statistics.mean(new_cpu)
    print(f"{args.rounds} rounds x {args.runs} runs: base {mb:.3f}, this tree {mt:.3f} CPU s/run; ratio of means "
          f"{mt / mb:.3f}; median per-round ratio {statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}); "
          f"10,000 runs on 2 free cores: base {1e4 * mb / 2 / 60:.1f} min, this tree {1e4 * mt / 2 / 60:.1f} min")

if __name__ == "__main__":
    main()
