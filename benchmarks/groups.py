"""The two-level model's benchmark: accuracy, group recovery and speed on a scenario over seeds.

Per tracker: mean OSPA (c=100, p=1, position), OSPA(2) (window 10), mean |N_hat - N|, the adjusted
Rand index of the inferred object partition against the true groups (per frame, over the true
objects matched to a track within 100 m by optimal assignment, frames where some true group has
at least 2 matched members;
a track without a ``cluster`` is a singleton, so a single-level tracker scores 0 when the truth
has groups), the discount ``d2`` of the object partition (mean over frames >= 20; two-level
trackers), and ms per frame (median; each seed in its own process, one core).

    python benchmarks/groups.py --trackers ddp ddp-mb glmb --scenario groups --seeds 20
    python benchmarks/groups.py --trackers ddp --set sharing=false --first-seed 101 --seeds 10
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.sinks.partitions import adjusted_rand_index  # noqa: E402
from bnptrack.sources.scenarios import get_scenario, is_generated  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.registry import build, kind  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def frame_ari(truth, est, group_of: dict[str, str], gate: float = 100.0, cluster_of: dict | None = None) -> float | None:
    """ARI of the tracks' clusters against the true groups over the matched objects (``None``: < 2).
    ``cluster_of``: each track label's block, instead of the tracks' own ``cluster`` (a label
    not in it is a block of its own)."""
    if len(truth.ids) < 2 or len(est.tracks) < 2:
        return None
    D = np.linalg.norm(truth.positions[:, None] - est.positions[None], axis=2)
    rows, cols = linear_sum_assignment(np.minimum(D, gate))
    ok = D[rows, cols] < gate
    true = [group_of.get(truth.ids[i], truth.ids[i]) for i in rows[ok]]
    if len(set(true)) == len(true):  # no true group with 2 matched members: ARI says nothing
        return None
    if cluster_of is not None:
        inferred = [str(cluster_of.get(est.tracks[j].label, est.tracks[j].label)) for j in cols[ok]]
    else:
        inferred = [est.tracks[j].label if est.tracks[j].cluster is None else f"c{est.tracks[j].cluster}"
                    for j in cols[ok]]
    return adjusted_rand_index(true, inferred)


def one_run(job):
    tracker_name, params_name, scenario, seed, overrides, scene = job
    p_over = [o.partition(".")[2] for o in overrides if o.startswith("params.")]
    t_over = [o.removeprefix("tracker.") for o in overrides if not o.startswith("params.")]
    sc = get_scenario(scenario, seed=seed, scene=scene) if is_generated(scenario) else get_scenario(scenario)
    params = apply_overrides(sc.adapt_params(load_params(params_name)), p_over)
    tracker = build(tracker_name, params, apply_overrides(kind(tracker_name).presets[tracker_name], t_over))
    frames = simulate_all(sc, params, seed)
    group_of = {i: f"g{k}" for k, g in enumerate(sc.groups) for i in g}
    rows, ests, aris, d2, d2_all = [], [], [], [], []
    for f, e, _ in run(tracker, frames, seed):
        o = ospa(f.truth.positions, e.positions, c=100.0, p=1.0)
        rows.append((o.total, abs(len(e.tracks) - len(f.truth.ids)), e.diagnostics["ms"]))
        ests.append(e)
        a = frame_ari(f.truth, e, group_of)
        if a is not None:
            aris.append(a)
        if f.frame >= 20 and "d2" in e.diagnostics:
            d2.append(e.diagnostics["d2"])
        d2_all.append(e.diagnostics.get("d2", float("nan")))
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [{t.label: t.position for t in e.tracks} for e in ests]
    o2 = ospa2_series(est_tracks, true_tracks, window=10, c=100.0, p=1.0)
    r = np.array(rows)
    return dict(ospa=r[:, 0].mean(), ospa2=float(np.mean(o2)), card_err=r[:, 1].mean(),
                ari=float(np.mean(aris)) if aris else float("nan"),
                d2=float(np.mean(d2)) if d2 else float("nan"), ms=r[:, 2], d2_series=np.array(d2_all))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trackers", nargs="+", default=["ddp", "ddp-mb", "glmb"])
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="groups")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="params.KEY=V or [tracker.]KEY=V (applied to every tracker)")
    ap.add_argument("--scene", action="append", default=[], help="scene KEY=V (generated scenarios)")
    ap.add_argument("--trajectory", action="store_true",
                    help="also print d2 (mean over seeds, with the 10/90 %% quantiles) every 10th frame")
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"scenario {args.scenario}, params {args.params}, seeds {seeds.start}..{seeds.stop - 1}, "
          f"overrides {args.overrides or 'none'}, scene {args.scene or 'default'}")
    print("| tracker | OSPA | OSPA(2) w=10 | mean abs(N_hat-N) | ARI | d2 | ms/frame median |")
    print("|---|---|---|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:
        for tr in args.trackers:
            jobs = [(tr, args.params, args.scenario, s, args.overrides, tuple(args.scene)) for s in seeds]
            res = list(pool.map(one_run, jobs))
            m = {k: np.nanmean([r[k] for r in res]) if not all(np.isnan(r[k]) for r in res) else float("nan")
                 for k in ("ospa", "ospa2", "card_err", "ari", "d2")}
            ms = np.concatenate([r["ms"] for r in res])
            print(f"| {tr} | {m['ospa']:.2f} | {m['ospa2']:.2f} | {m['card_err']:.3f} | {m['ari']:.3f} | "
                  f"{m['d2']:.3f} | {np.median(ms):.2f} |", flush=True)
            if args.trajectory:
                print_trajectory(tr, [r["d2_series"] for r in res])


def print_trajectory(tracker: str, series: list[np.ndarray]) -> None:
    """d2 at frames 1, 10, 20, ...: mean over seeds and the 10 % / 90 % quantiles."""
    n = min(s.size for s in series)
    S = np.stack([s[:n] for s in series])
    cells = [f"{k + 1}: {np.mean(S[:, k]):.3f} [{np.quantile(S[:, k], 0.1):.2f}, {np.quantile(S[:, k], 0.9):.2f}]"
             for k in [0, *range(9, n, 10)]]
    print(f"  d2 trajectory ({tracker}): " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
