"""Mixing of the frame Gibbs sampler, old (single-site only) against new
(single-site + pair exchanges), in the same run:

1. the toy of ``tests/tracker/test_urn_gibbs.py``: two measurements at 0.29 and 0.33 compete for one
   cluster at 0.31; run-to-run SD of Pr(c_0 = cluster) over ``--runs`` runs of 30 sweeps
   (burn-in 5), against the exact value by enumeration;
2. vo2017 (DDP-EMM, seeds 1..``--seeds``): per-frame split-chain R-hat (``rhat_max``) and
   ms/frame for each (swap moves, chains, sweeps per chain) setting; burn-in min(5, sweeps // 4).

    taskset -c 0 python3 benchmarks/gibbs_mixing.py --seeds 3 --runs 200
"""

from __future__ import annotations

import argparse
import os
import sys

import msgspec
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp import TRACKER_PRESETS, make_tracker  # noqa: E402
from bnptrack.tracker.bnp.gibbs import CLUTTER, NEW, GibbsProblem, log_joint, run_gibbs  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def toy() -> GibbsProblem:
    """1-D: clutter and new ~ U(0, 1) (lambda_c = 2), one cluster N(0.31, 0.05^2) with D2 weight 3."""
    z = np.array([0.29, 0.33])
    ll = -0.5 * ((z - 0.31) / 0.05) ** 2 - np.log(0.05 * np.sqrt(2 * np.pi))
    return GibbsProblem(np.log(3.0) + ll[None], ll[None], np.full(2, np.log(2.0)), np.zeros(2), np.ones(1),
                        alpha=0.6, d=0.0, d_bar=1.4, mass=1.7)


def exact_marginal(prob: GibbsProblem) -> float:
    opts = [CLUTTER, NEW, 0]
    w = {(a, b): np.exp(log_joint(prob, np.array([a, b]))) for a in opts for b in opts}
    return sum(v for (a, _), v in w.items() if a == 0) / sum(w.values())


def toy_table(runs: int) -> None:
    prob = toy()
    print(f"toy: exact Pr(c_0 = cluster) = {exact_marginal(prob):.4f}; {runs} runs")
    print("| swaps | chains x sweeps (burn-in) | mean | run-to-run SD | R-hat median | runs with R-hat > 1.1 |")
    print("|---|---|---|---|---|---|")
    for swaps, chains, sweeps, burn in ((False, 1, 30, 5), (True, 1, 30, 5), (False, 2, 30, 5), (True, 2, 30, 5),
                                        (True, 2, 15, 3)):
        res = [run_gibbs(prob, np.random.default_rng(i), sweeps, burn, swaps=swaps, chains=chains)
               for i in range(runs)]
        est = np.array([r.p_cluster[0, 0] for r in res])
        rh = np.array([r.rhat_max for r in res])
        print(f"| {swaps} | {chains} x {sweeps} ({burn}) | {est.mean():.4f} | {est.std(ddof=1):.4f} "
              f"| {np.median(rh):.3f} | {np.mean(rh > 1.1):.1%} |")


def vo_table(seeds: int, settings: list[tuple[bool, int, int]]) -> None:
    params = get_scenario("vo2017").adapt_params(load_params("vo2017"))  # with its birth regions
    frames = {s: simulate_all(get_scenario("vo2017"), params, s) for s in range(1, seeds + 1)}
    print(f"\nvo2017, DDP-EMM, seeds 1-{seeds}, {sum(map(len, frames.values()))} frames; rhat_max per frame")
    print("| swaps | chains x sweeps | R-hat median | p90 | p99 | frames > 1.1 | frames > 1.5 | swap accept | ms/frame median | p95 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for swaps, chains, sweeps in settings:
        cfg = msgspec.structs.replace(TRACKER_PRESETS["ddp-mb"], swap_moves=swaps, chains=chains, sweeps=sweeps,
                                      burn_in=min(5, sweeps // 4))
        tracker = make_tracker("ddp-mb", params, cfg)
        d = [e.diagnostics for s, fr in frames.items() for _, e, _ in run(tracker, fr, s)][1:]
        rh = np.array([x["rhat_max"] for x in d])
        ms = np.array([x["ms"] for x in d])
        acc = np.mean([x["swap_accept"] for x in d])
        print(f"| {swaps} | {chains} x {sweeps} | {np.median(rh):.3f} | {np.percentile(rh, 90):.3f} | {np.percentile(rh, 99):.3f} "
              f"| {np.mean(rh > 1.1):.1%} | {np.mean(rh > 1.5):.1%} | {acc:.3f} | {np.median(ms):.2f} | {np.percentile(ms, 95):.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--sweeps", type=int, nargs="+", default=[8, 12, 16, 20, 30])
    args = ap.parse_args()
    toy_table(args.runs)
    vo_table(args.seeds, [(False, 1, 30), (False, 2, 30)] + [(True, 2, s) for s in args.sweeps])


if __name__ == "__main__":
    main()
