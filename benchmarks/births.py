"""How fast new objects are confirmed, and what it costs in false tracks.

For every true object: the confirmation delay, the number of scans from its first scan to the
first scan at which a reported track lies within ``--gate`` metres of it (an object never
confirmed counts its whole life).  Per run: false-track scans (reported tracks farther than
the gate from every object) and missed-object scans.  Also the mean of the frame diagnostic
``p_birth`` (probability that a measurement no cluster explains opens a new one) and the
final ``alpha``.  What sets the delay is in docs/trackers.md ("Births anywhere").

    python benchmarks/births.py --scenario random --seeds 20
    python benchmarks/births.py --scenario vo2017 --seeds 20 --set params.birth=[]
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from accuracy import setup  # noqa: E402  (benchmarks/accuracy.py)
from bnptrack.tracker.state import run  # noqa: E402


def one_run(job) -> dict:
    tracker_name, scenario, seed, overrides, gate = job
    sc, tracker, frames = setup(tracker_name, "vo2017", scenario, seed, overrides)
    first: dict[str, int] = {}
    false_scans = missed_scans = 0
    p_birth, alpha = [], float("nan")
    for f, e, _ in run(tracker, frames, seed):
        T, E = f.truth.positions, e.positions
        D = np.linalg.norm(T[:, None] - E[None], axis=2) if len(T) and len(E) else np.full((len(T), len(E)), np.inf)
        for i, tid in enumerate(f.truth.ids):
            if tid not in first and D.shape[1] and D[i].min() < gate:
                first[tid] = f.frame
        false_scans += int(np.sum(D.min(axis=0) >= gate)) if len(T) else len(E)
        missed_scans += int(np.sum(D.min(axis=1) >= gate)) if len(E) else len(T)
        if "p_birth" in e.diagnostics:  # BNP trackers only
            p_birth.append(e.diagnostics["p_birth"])
        alpha = e.diagnostics.get("alpha", np.nan)
    births = dict(zip(sc.ids, sc.births.tolist()))
    deaths = dict(zip(sc.ids, sc.deaths.tolist()))
    delays = [first.get(t, deaths[t] + 1) - births[t] for t in sc.ids]
    return dict(delays=delays, never=sum(t not in first for t in sc.ids), false=false_scans, missed=missed_scans, p_birth=float(np.mean(p_birth)) if p_birth else float("nan"), alpha=alpha)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trackers", nargs="+", default=["ddp"])
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--gate", type=float, default=100.0, help="metres (OSPA's cut-off)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="params.KEY=V (model parameters) or [tracker.]KEY=V (tracker settings)")
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"scenario {args.scenario}, seeds {seeds.start}..{seeds.stop - 1}, overrides {args.overrides or 'none'}")
    print("| tracker | objects | delay mean | median | p90 | never confirmed | false-track scans/run | "
          "missed-object scans/run | mean p_birth | final alpha |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:
        for tr in args.trackers:
            res = list(pool.map(one_run, [(tr, args.scenario, s, args.overrides, args.gate) for s in seeds]))
            d = np.concatenate([r["delays"] for r in res])
            lives = sum(len(r["delays"]) for r in res)
            never = sum(r["never"] for r in res)
            print(f"| {tr} | {lives} | {d.mean():.2f} | {np.median(d):.0f} | {np.percentile(d, 90):.0f} | {never} | "
                  f"{np.mean([r['false'] for r in res]):.1f} | {np.mean([r['missed'] for r in res]):.1f} | "
                  f"{np.mean([r['p_birth'] for r in res]):.4f} | {np.mean([r['alpha'] for r in res]):.3f} |", flush=True)


if __name__ == "__main__":
    main()
