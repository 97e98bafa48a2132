"""Time per frame of ``ddp`` (two-level) against ``ddp-mb``, interleaved frame by frame in one process.

On a shared machine the load changes from second to second, so the two trackers are timed on
the same frame one right after the other (alternating which goes first) and the ratio of the
medians is reported.

    python benchmarks/groups_speed.py --scenario groups --seeds 1 2 3

``--experiment NAME`` times the two trackers on that experiment's runs instead (its scene, the
paper's parameters and its first variant, e.g. ``ddp-vs-glmb``: experiment 1 at -3 dB; runs
``0 .. --runs - 1`` of seed 1, each tracker with the experiment's preset):

    python benchmarks/groups_speed.py --experiment ddp-vs-glmb --runs 20

``--fingerprint`` times nothing: it prints a digest of each tracker's output per seed (every
frame's track labels, states, covariances, existences, clusters, assignments and their
probabilities, cardinality pmf, and the state's objects and clusters), to compare two checkouts
bit for bit:

    PYTHONPATH=$PWD python benchmarks/groups_speed.py --fingerprint --scenario vo2017 --seeds 1 2 3 4 5 \
        --trackers ddp dpyp
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sources.scenarios import get_scenario, is_generated  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.registry import build  # noqa: E402
from bnptrack.tracker.state import tracker_frame_rng  # noqa: E402


def fingerprint(name: str, scenario: str, seed: int) -> str:
    """SHA-256 (16 hex digits) of a two-level tracker's whole output on one run."""
    sc = get_scenario(scenario, seed=seed) if is_generated(scenario) else get_scenario(scenario)
    params = sc.adapt_params(load_params("vo2017"))
    tracker = build(name, params)
    state, h = tracker.initial_state(), hashlib.sha256()
    for f in simulate_all(sc, params, seed):
        state, est = tracker.step(state, f, tracker_frame_rng(seed, f.frame))
        for t in est.tracks:
            h.update(t.label.encode() + t.state.tobytes() + t.covariance.tobytes())
            h.update(np.float64(t.existence).tobytes() + str(t.cluster).encode())
        h.update(repr(est.assignments).encode() + np.asarray(est.assignment_prob).tobytes())
        h.update(np.asarray(est.cardinality_pmf).tobytes())
        for a in (state.mean, state.cov, state.existence, state.cluster, state.group_mean, state.group_cov,
                  state.group_ids, np.float64(state.alpha2), np.float64(state.d2), state.hyper2_loglik):
            h.update(np.asarray(a).tobytes())
    return h.hexdigest()[:16]


def _experiment_runs(name: str, runs: int, tracker_names: list[str]):
    """(trackers by name, frames, seed) of runs ``0 .. runs - 1`` (seed 1) of experiment ``name``."""
    from bnptrack.pipeline import experiments as E
    from bnptrack.pipeline.resolve import tracker_setup

    exp = E.get_experiment(name)
    specs = {s.name: s for s in exp.trackers}
    for run in range(runs):
        _, scenario, params, seed = E._run_setup(E.RunJob(name, 1, run, "vo2017", exp.variants[0]))
        trackers = {t: tracker_setup(specs[t].name, params=params, config=specs[t].preset).tracker
                    for t in tracker_names}
        yield trackers, simulate_all(scenario, params, seed), seed


def _scenario_runs(scenario: str, seeds: list[int], tracker_names: list[str]):
    """(trackers by name, frames, seed) of ``scenario`` on each seed (``vo2017`` parameters)."""
    for seed in seeds:
        sc = get_scenario(scenario, seed=seed) if is_generated(scenario) else get_scenario(scenario)
        params = sc.adapt_params(load_params("vo2017"))
        yield {t: build(t, params) for t in tracker_names}, simulate_all(sc, params, seed), seed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="groups")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--trackers", nargs=2, default=["ddp", "ddp-mb"])
    ap.add_argument("--fingerprint", action="store_true", help="print output digests instead of timing")
    ap.add_argument("--experiment", help="time on this experiment's runs (e.g. ddp-vs-glmb) instead of --scenario")
    ap.add_argument("--runs", type=int, default=20, help="with --experiment: runs 0 .. RUNS-1 of seed 1")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="wall (perf_counter) or this thread's CPU time (thread_time: robust to load)")
    args = ap.parse_args()
    if args.fingerprint:
        for name in args.trackers:
            for seed in args.seeds:
                print(f"{name} {args.scenario} {seed} {fingerprint(name, args.scenario, seed)}", flush=True)
        return
    ms: dict[str, list[float]] = {t: [] for t in args.trackers}
    runs = (_experiment_runs(args.experiment, args.runs, args.trackers) if args.experiment
            else _scenario_runs(args.scenario, args.seeds, args.trackers))
    clock = time.perf_counter if args.clock == "wall" else time.thread_time
    for trackers, frames, seed in runs:
        states = {t: tr.initial_state() for t, tr in trackers.items()}
        for f in frames:
            order = args.trackers if f.frame % 2 else args.trackers[::-1]
            for t in order:
                t0 = clock()
                states[t], _ = trackers[t].step(states[t], f, tracker_frame_rng(seed, f.frame))
                ms[t].append((clock() - t0) * 1e3)
    a, b = args.trackers
    ma, mb = np.median(ms[a][5:]), np.median(ms[b][5:])  # the first frames include compilation
    where = f"{args.experiment}, runs 0-{args.runs - 1}" if args.experiment else f"{args.scenario}, seeds {args.seeds}"
    print(f"{where} ({args.clock} clock): {a} {ma:.2f} ms/frame, {b} {mb:.2f} ms/frame (median), "
          f"ratio {ma / mb:.2f}; means {np.mean(ms[a][5:]):.2f} / {np.mean(ms[b][5:]):.2f}")


if __name__ == "__main__":
    main()
