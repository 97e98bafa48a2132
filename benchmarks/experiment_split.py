"""Where a run of an experiment (default: experiment 1, ``ddp-vs-glmb``) spends its CPU time
(issue 15, Monte Carlo throughput): each tracker's ``step``, scoring (``RunScorer.update``:
OSPA, OSPA(2), GOSPA), the simulation, the trackers' per-frame random streams and the
run's set-up, measured in one process with ``time.thread_time`` wrappers (no profiler: a
profiler inflates the many small calls of scoring and of the trackers' per-frame Python).

It runs one warm-up run (imports, compiled kernels; not timed), then ``--runs`` runs of seed 1
with the ``vo2017`` parameters (as ``experiment_ab.py``) and prints ms of CPU per run and the
share of each part; "other" is the rest of ``execute_run`` (the result rows, the loop).  The
last line is one JSON object of the same figures.

    NUMBA_CACHE_DIR=... nice -n 10 python3 benchmarks/experiment_split.py --runs 20
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.pipeline import experiments as E  # noqa: E402
from bnptrack.pipeline import resolve as R  # noqa: E402
from bnptrack.sinks import metrics as M  # noqa: E402
from bnptrack.sources import synthetic as SY  # noqa: E402
from bnptrack.tracker import state as S  # noqa: E402

CLOCK = time.thread_time
_DEPTH: collections.Counter = collections.Counter()  # open timed calls per key


def timed(fn, acc: collections.Counter, key: str):
    """``fn`` with its CPU time added to ``acc[key]`` (calls nested in a timed part of the same
    key are counted once)."""
    def wrapper(*args, **kwargs):
        _DEPTH[key] += 1
        t0 = CLOCK()
        try:
            return fn(*args, **kwargs)
        finally:
            _DEPTH[key] -= 1
            if _DEPTH[key] == 0:
                acc[key] += CLOCK() - t0

    return wrapper


def instrument(acc: collections.Counter) -> None:
    """Wrap the parts of ``execute_run`` (module attributes looked up at call time)."""
    M.RunScorer.update = timed(M.RunScorer.update, acc, "scoring")
    SY.simulate_all = timed(SY.simulate_all, acc, "simulation")
    E._run_setup = timed(E._run_setup, acc, "set-up")
    S.tracker_frame_rng = timed(S.tracker_frame_rng, acc, "random streams")
    if hasattr(E, "frame_streams"):
        E.frame_streams = timed(E.frame_streams, acc, "random streams")
    setup = R.tracker_setup

    def tracker_setup(name, **kwargs):
        built = setup(name, **kwargs)
        tracker = built.tracker
        object.__setattr__(tracker, "step", timed(tracker.step, acc, f"step {name}"))
        return built

    R.tracker_setup = tracker_setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--experiment", default="ddp-vs-glmb")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--start", type=int, default=0, help="first run index")
    args = ap.parse_args()
    exp = E.get_experiment(args.experiment)
    E.execute_run(E.RunJob(args.experiment, 999, 0, "vo2017", exp.variants[0]))  # warm-up, not timed
    acc: collections.Counter = collections.Counter()
    instrument(acc)
    jobs = [E.RunJob(args.experiment, 1, i, "vo2017", exp.variants[0]) for i in range(args.start, args.start + args.runs)]
    t0 = CLOCK()
    for job in jobs:
        E.execute_run(job)
    total = CLOCK() - t0
    acc["other"] = total - sum(acc.values())
    print("| part | ms CPU per run | share |\n|---|---|---|")
    for key, v in acc.most_common():
        print(f"| {key} | {1e3 * v / args.runs:.1f} | {100 * v / total:.1f} % |")
    print(f"| total | {1e3 * total / args.runs:.1f} | load {os.getloadavg()[0]:.1f} |")
    print(json.dumps({"ms_per_run": {k: 1e3 * v / args.runs for k, v in acc.items()},
                      "total_ms_per_run": 1e3 * total / args.runs, "load": os.getloadavg()[0]}))


if __name__ == "__main__":
    main()
