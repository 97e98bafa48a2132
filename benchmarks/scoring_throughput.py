"""CPU time of scoring a Monte Carlo run's frames (issue 15): OSPA, OSPA(2) and GOSPA per frame,
as ``pipeline.experiments`` scores them, on the estimates of experiment 1's trackers.

It runs ``--runs`` runs of ``ddp-vs-glmb`` once (not timed), then scores every tracker's
frames ``--repeats`` times and prints the best microseconds per tracker-frame and a SHA-256 of
every score.  On code without ``RunScorer(gospa_alpha=...)`` (before issue 15's scoring pass)
it scores GOSPA with :func:`sinks.metrics.gospa` instead, as the experiments did, so two
checkouts can be compared in one session (A, B, A, B):

    PYTHONPATH=$PWD nice -n 10 python3 benchmarks/scoring_throughput.py
    PYTHONPATH=/tmp/base nice -n 10 python3 $PWD/benchmarks/scoring_throughput.py

Where ``RunScorer(compiled=True)`` exists (session 8) it scores as the Monte Carlo runner
does, with the compiled OSPA(2) window; ``--numpy`` scores with the numpy window instead.
"""

from __future__ import annotations

import argparse
import hashlib
import inspect
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.pipeline.experiments import RunJob, _run_setup, get_experiment  # noqa: E402
from bnptrack.pipeline.resolve import tracker_setup  # noqa: E402
from bnptrack.sinks.metrics import RunScorer, gospa  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.state import run as run_tracker  # noqa: E402

SHARED = "gospa_alpha" in inspect.signature(RunScorer).parameters
#: RunScorer(compiled=True), the Monte Carlo runner's scorer since session 8 (False before)
COMPILED = "compiled" in inspect.signature(RunScorer).parameters


def record(runs: int) -> list[tuple[list, list]]:
    exp = get_experiment("ddp-vs-glmb")
    out = []
    for i in range(runs):
        _, scenario, params, seed = _run_setup(RunJob("ddp-vs-glmb", 1, i, "vo2017", exp.variants[0]))
        frames = simulate_all(scenario, params, seed)
        for spec in exp.trackers:
            tracker = tracker_setup(spec.name, params=params, config=spec.preset).tracker
            out.append((frames, [e for _, e, _ in run_tracker(tracker, frames, seed)]))
    return out


def score(frames: list, estimates: list, compiled: bool = COMPILED) -> list[tuple]:
    rows = []
    if compiled:
        scorer = RunScorer(100.0, 1.0, 10, gospa_alpha=2.0, compiled=True)
    else:
        scorer = RunScorer(100.0, 1.0, 10, gospa_alpha=2.0) if SHARED else RunScorer(100.0, 1.0, 10)
    for f, e in zip(frames, estimates):
        s = scorer.update(f, e)
        g = s["gospa"] if SHARED else gospa(f.truth.positions, e.positions, c=100.0, p=1.0, alpha=2.0)
        o = s["ospa"]
        rows.append((o.total, o.localisation, o.cardinality, s["ospa2"], g.total, g.localisation, g.missed,
                     g.false, g.n_missed, g.n_false))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=6)
    ap.add_argument("--numpy", dest="compiled", action="store_false",
                    help="score with the numpy OSPA(2) window (RunScorer's default) even where the "
                         "compiled one (the runner's, session 8) exists")
    args = ap.parse_args()
    compiled = COMPILED and args.compiled
    data = record(args.runs)
    score(*data[0], compiled=compiled)  # scipy's first import (and the kernel) outside the timing
    best, rows = float("inf"), []
    for _ in range(args.repeats):
        t0 = time.process_time()
        rows = [score(f, e, compiled) for f, e in data]
        best = min(best, time.process_time() - t0)
    n = sum(len(f) for f, _ in data)
    digest = hashlib.sha256(np.array(rows, dtype=float).tobytes()).hexdigest()[:16]
    kind = ("shared" if SHARED else "separate") + (", compiled window" if compiled else "")
    print(f"{kind} scoring: {1e6 * best / n:.1f} us per tracker-frame "
          f"(best of {args.repeats}, {n} frames), scores {digest}, load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
