"""Accuracy and speed of any tracker (ddp, dpyp, ddp-mb, dpyp-mb, glmb) on a scenario over many seeds.

Prints, per tracker and parameter set: mean OSPA (total, localisation, cardinality; c=100,
p=1, on position), OSPA(2) (window 10), mean |N_hat - N|, label switches per run, the
fraction of crossing pairs that keep both labels (generated ``random`` scenes; each seed is
its own scene; below the row, why the others were not: :func:`crossing_failure`) and ms per frame (median, p95).  Each seed runs in its own process (``--workers``) and is timed on one
core, so the ms figures are single-core figures.

    python benchmarks/accuracy.py --trackers ddp dpyp glmb --params vo2017 paper --seeds 20
    python benchmarks/accuracy.py --trackers ddp glmb --params vo2017 --scenario random-cv
"""

from __future__ import annotations

import argparse
import os
from collections import Counter
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sinks.crossings import crossing_label_keeping  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.registry import build, kind  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def label_switches(frames, estimates, gate: float = 100.0) -> int:
    """Label changes of the track assigned to each true object (optimal assignment per frame,
    pairs farther than ``gate`` unassigned); an object left unassigned keeps its last label."""
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


def setup(tracker_name: str, params_name: str, scenario: str, seed: int, overrides):
    """The scene of ``seed`` (a generated family draws its own), the tracker and the frames.

    ``overrides``: ``params.KEY=V`` go to the model parameters (after the scenario's
    defaults), ``scene.KEY=V`` to a generated family's scene, ``[tracker.]KEY=V`` to the
    tracker's preset."""
    p_over = [o.partition(".")[2] for o in overrides if o.startswith("params.")]
    s_over = tuple(o.partition(".")[2] for o in overrides if o.startswith("scene."))
    t_over = [o.removeprefix("tracker.") for o in overrides if not o.startswith(("params.", "scene."))]
    sc = get_scenario(scenario, seed=seed, scene=s_over)
    params = apply_overrides(sc.adapt_params(load_params(params_name)), p_over)
    tracker = build(tracker_name, params, apply_overrides(kind(tracker_name).presets[tracker_name], t_over))
    return sc, tracker, simulate_all(sc, params, seed)


def one_run(job):
    tracker_name, params_name, scenario, seed, overrides = job
    sc, tracker, frames = setup(tracker_name, params_name, scenario, seed, overrides)
    rows, ests = [], []
    for f, e, _ in run(tracker, frames, seed):
        o = ospa(f.truth.positions, e.positions, c=100.0, p=1.0)
        rows.append((o.total, o.localisation, o.cardinality, abs(len(e.tracks) - len(f.truth.ids)), e.diagnostics["ms"]))
        ests.append(e)
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [{t.label: t.position for t in e.tracks} for e in ests]
    o2 = ospa2_series(est_tracks, true_tracks, window=10, c=100.0, p=1.0)
    r = np.array(rows)
    pairs = crossing_label_keeping(true_tracks, est_tracks, sc.crossings).pairs
    kept = [p.kept for p in pairs]
    return dict(ospa=r[:, 0].mean(), loc=r[:, 1].mean(), card=r[:, 2].mean(), ospa2=float(np.mean(o2)),
                card_err=r[:, 3].mean(), switches=label_switches(frames, ests), ms=r[:, 4], kept=kept,
                lost=[crossing_failure(p) for p in pairs if not p.kept])


def crossing_failure(p) -> str:
    """Why a crossing pair did not keep both labels: ``unseen before`` (an object had no
    track at the first scan checked, e.g. not yet confirmed), ``swap`` (the two labels
    exchanged), ``lost after`` (an object had no track at the last scan checked), ``merged``
    (one track for both after), ``relabel`` (an object's track replaced by another)."""
    (a0, b0), (a1, b1) = p.labels_before, p.labels_after
    if None in (a0, b0):
        return "unseen before"
    if (a1, b1) == (b0, a0):
        return "swap"
    if None in (a1, b1):
        return "lost after"
    return "merged" if a1 == b1 else "relabel"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trackers", nargs="+", default=["ddp", "dpyp"])
    ap.add_argument("--params", nargs="+", default=["vo2017", "paper"])
    ap.add_argument("--scenario", default="vo2017")
    ap.add_argument("--seeds", type=int, default=20, help="number of seeds")
    ap.add_argument("--first-seed", type=int, default=1, help="seeds run from this one")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="override: params.KEY=V (model parameters), scene.KEY=V (generated scene) or [tracker.]KEY=V (tracker settings)")
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"scenario {args.scenario}, seeds {seeds.start}..{seeds.stop - 1}, overrides {args.overrides or 'none'}")
    print("| tracker | params | OSPA | loc | card | OSPA(2) w=10 | mean abs(N_hat-N) | label switches/run | "
          "crossings kept | ms/frame median | p95 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:
        for tr in args.trackers:
            for pa in args.params:
                jobs = [(tr, pa, args.scenario, s, args.overrides) for s in seeds]
                res = list(pool.map(one_run, jobs))
                ms = np.concatenate([r["ms"] for r in res])
                mean = {k: np.mean([r[k] for r in res]) for k in ("ospa", "loc", "card", "ospa2", "card_err", "switches")}
                kept = [k for r in res for k in r["kept"]]
                kept_txt = f"{np.mean(kept):.2f} ({sum(kept)}/{len(kept)})" if kept else "n/a"
                lost = Counter(c for r in res for c in r["lost"])
                print(f"| {tr} | {pa} | {mean['ospa']:.2f} | {mean['loc']:.2f} | {mean['card']:.2f} | {mean['ospa2']:.2f} | "
                      f"{mean['card_err']:.3f} | {mean['switches']:.2f} | {kept_txt} | {np.median(ms):.2f} | "
                      f"{np.percentile(ms, 95):.2f} |", flush=True)
                if lost:
                    print(f"  crossing pairs not kept: {dict(sorted(lost.items()))}", flush=True)


if __name__ == "__main__":
    main()
