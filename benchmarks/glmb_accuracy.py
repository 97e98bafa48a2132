"""Accuracy and speed of the GLMB baseline on a scenario over many seeds.

Prints, per parameter set: mean OSPA (total, localisation, cardinality; c=100, p=1, on
position), OSPA(2) (window 10), mean |N_hat - N|, label switches per run, mean number of
hypotheses kept and ms per frame (median, p95).  Each seed runs in its own process
(``--workers``) and is timed on one core, so the ms figures are single-core figures.
The per-seed runs are the same as ``benchmarks/bnp_accuracy.py`` (same frames for a seed).

    python benchmarks/glmb_accuracy.py --params vo2017 paper --seeds 20
    python benchmarks/glmb_accuracy.py --params vo2017 --seeds 20 --set chain_length=20
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from sinks.metrics import ospa, ospa2_series  # noqa: E402
from sources.scenarios import get_scenario  # noqa: E402
from sources.synthetic import simulate_all  # noqa: E402
from tracker.config import apply_overrides  # noqa: E402
from tracker.glmb import GLMB_PRESETS, make_glmb  # noqa: E402
from tracker.models.params import load_params  # noqa: E402
from tracker.state import run  # noqa: E402


def label_switches(frames, estimates, gate: float = 100.0) -> int:
    """Label changes of the track assigned to each true object (optimal assignment per frame,
    pairs farther than ``gate`` unassigned); an object left unassigned keeps its last label.
    (Same definition as ``benchmarks/bnp_accuracy.py``.)"""
    last: dict[str, str] = {}
    switches = 0
    for f, e in zip(frames, estimates):
        if not e.tracks or not f.truth.ids:
            continue
        D = np.linalg.norm(f.truth.positions[:, None] - e.positions[None], axis=2)
        rows, cols = linear_sum_assignment(np.minimum(D, gate))
        for i, j in zip(rows, cols):
            if D[i, j] >= gate:
                continue
            tid, lab = f.truth.ids[i], e.tracks[j].label
            if tid in last and last[tid] != lab:
                switches += 1
            last[tid] = lab
    return switches


def one_run(job):
    preset, params_name, scenario, seed, overrides, param_overrides = job
    params = get_scenario(scenario).adapt_params(load_params(params_name, param_overrides))
    tracker = make_glmb(params, apply_overrides(GLMB_PRESETS[preset], overrides))
    frames = simulate_all(get_scenario(scenario), params, seed)
    rows, ests = [], []
    for f, e, _ in run(tracker, frames, seed):
        o = ospa(f.truth.positions, e.positions, c=100.0, p=1.0)
        rows.append((o.total, o.localisation, o.cardinality, abs(len(e.tracks) - len(f.truth.ids)),
                     e.diagnostics["ms"], e.diagnostics["n_hypotheses"]))
        ests.append(e)
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [{t.label: t.position for t in e.tracks} for e in ests]
    o2 = ospa2_series(est_tracks, true_tracks, window=10, c=100.0, p=1.0)
    r = np.array(rows)
    return dict(seed=seed, ospa=r[:, 0].mean(), loc=r[:, 1].mean(), card=r[:, 2].mean(),
                ospa2=float(np.mean(o2)), card_err=r[:, 3].mean(), switches=label_switches(frames, ests),
                hyps=r[:, 5].mean(), ms=r[:, 4])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="glmb", choices=sorted(GLMB_PRESETS))
    ap.add_argument("--params", nargs="+", default=["vo2017", "paper"])
    ap.add_argument("--scenario", default="vo2017")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="GLMB config override key=value")
    ap.add_argument("--param-set", dest="param_overrides", action="append", default=[],
                    help="model parameter override key=value (e.g. p_detect=0.9)")
    ap.add_argument("--per-seed", action="store_true", help="also print one line per seed")
    args = ap.parse_args()
    print(f"scenario {args.scenario}, seeds 1..{args.seeds}, GLMB overrides {args.overrides or 'none'}, "
          f"param overrides {args.param_overrides or 'none'}")
    print("| tracker | params | OSPA | loc | card | OSPA(2) w=10 | mean abs(N_hat-N) | label switches/run "
          "| hypotheses | ms/frame median | p95 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:
        for pa in args.params:
            jobs = [(args.preset, pa, args.scenario, s, args.overrides, args.param_overrides)
                    for s in range(1, args.seeds + 1)]
            res = list(pool.map(one_run, jobs))
            ms = np.concatenate([r["ms"] for r in res])
            keys = ("ospa", "loc", "card", "ospa2", "card_err", "switches", "hyps")
            mean = {k: np.mean([r[k] for r in res]) for k in keys}
            print(f"| {args.preset} | {pa} | {mean['ospa']:.2f} | {mean['loc']:.2f} | {mean['card']:.2f} | "
                  f"{mean['ospa2']:.2f} | {mean['card_err']:.3f} | {mean['switches']:.2f} | {mean['hyps']:.0f} | "
                  f"{np.median(ms):.2f} | {np.percentile(ms, 95):.2f} |", flush=True)
            if args.per_seed:
                for r in res:
                    print(f"|  seed {r['seed']} | {pa} | {r['ospa']:.2f} | {r['loc']:.2f} | {r['card']:.2f} | "
                          f"{r['ospa2']:.2f} | {r['card_err']:.3f} | {r['switches']} | {r['hyps']:.0f} | "
                          f"{np.median(r['ms']):.2f} | {np.percentile(r['ms'], 95):.2f} |")


if __name__ == "__main__":
    main()
