"""How fast new objects are confirmed, and what it costs in false tracks.

For every true object: the confirmation delay, the number of scans from its first scan to the
first scan at which a reported track lies within ``--gate`` metres of it (an object never
confirmed counts its whole life).  Per run: false-track scans (reported tracks farther than
the gate from every object) and missed-object scans.  Also the mean of the frame diagnostic
``p_birth`` (probability that a measurement no cluster explains opens a new one) and the
final ``alpha``.  What sets the delay is in docs/trackers.md ("Births anywhere").

``--decompose`` prints instead where each frame's OSPA (c = ``--gate``, p = 1) comes from,
averaged over frames and seeds (the parts add up to the mean OSPA): ``loc`` the distances of
the optimally assigned pairs nearer than c; ``far`` assigned pairs at c or more; the
cardinality part ``c |n - m| / max(n, m)`` split over the excess objects or tracks:
``missed new`` (objects at most 3 scans old, the youngest first), ``missed old`` (older),
``false dead`` (tracks whose last assigned object has died), ``false other``.

``--calibration`` prints instead whether the clusters' existences are calibrated, by age (scans
since the cluster's birth measurement; 4 = 4 and more) and existence bin: how often the
measurement that opened the cluster was an object's detection (the simulator's draws replayed,
``benchmarks/dropped_bound.labelled_detections``).  Calibrated young clusters have that
fraction near their mean existence (for old clusters the birth measurement says little).

    python benchmarks/births.py --scenario random --seeds 20
    python benchmarks/births.py --scenario vo2017 --seeds 20 --set params.birth=[]
    python benchmarks/births.py --scenario random --first-seed 101 --seeds 20 --decompose
    python benchmarks/births.py --scenario random --first-seed 101 --seeds 10 --calibration
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks.accuracy import setup  # noqa: E402
from scipy.optimize import linear_sum_assignment  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402

PARTS = ("loc", "far", "missed new", "missed old", "false dead", "false other")
YOUNG = 3  # scans: an object at most this old counts as "new"


def ospa_parts(frame, est, births: dict, owner: dict, c: float) -> dict:
    """One frame's OSPA (p = 1) split into :data:`PARTS` (they sum to the frame's OSPA).
    ``owner`` (track label -> the object it was last assigned to) is updated in place."""
    T, E = frame.truth.positions, est.positions
    n, m = len(T), len(E)
    out = dict.fromkeys(PARTS, 0.0)
    if max(n, m) == 0:
        return out
    w = 1.0 / max(n, m)
    labels = [t.label for t in est.tracks]
    D = np.linalg.norm(T[:, None] - E[None], axis=2) if n and m else np.zeros((n, m))
    rows, cols = linear_sum_assignment(np.minimum(D, c)) if n and m else ((), ())
    near = [(i, j) for i, j in zip(rows, cols) if D[i, j] < c]
    out["loc"] = w * sum(D[i, j] for i, j in near)
    out["far"] = w * c * (len(rows) - len(near))
    age = {i: frame.frame - births[frame.truth.ids[i]] for i in range(n)}
    if n > m:  # the excess objects: the youngest unassigned ones
        for i in sorted(set(range(n)) - set(rows), key=age.__getitem__):
            out["missed new" if age[i] <= YOUNG else "missed old"] += w * c
    alive = set(frame.truth.ids)
    for j in sorted(set(range(m)) - set(cols)):  # the excess tracks
        dead = labels[j] in owner and owner[labels[j]] not in alive
        out["false dead" if dead else "false other"] += w * c
    owner.update({labels[j]: frame.truth.ids[i] for i, j in near})
    return out


def decompose_run(job) -> dict:
    """Mean per-frame OSPA parts of one seed (:func:`ospa_parts`)."""
    tracker_name, scenario, seed, overrides, gate = job
    sc, tracker, frames = setup(tracker_name, "vo2017", scenario, seed, overrides)
    births = dict(zip(sc.ids, sc.births.tolist()))
    owner: dict = {}
    total = dict.fromkeys(PARTS, 0.0)
    for f, e, _ in run(tracker, frames, seed):
        for k, v in ospa_parts(f, e, births, owner, gate).items():
            total[k] += v
    return {k: v / len(frames) for k, v in total.items()}


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
    ap.add_argument("--decompose", action="store_true", help="print the OSPA decomposition instead")
    ap.add_argument("--calibration", action="store_true", help="print the existences' calibration by age instead")
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"scenario {args.scenario}, seeds {seeds.start}..{seeds.stop - 1}, overrides {args.overrides or 'none'}")
    if args.decompose:
        return print_decomposition(args, seeds)
    if args.calibration:
        return print_calibration(args, seeds)
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


def print_decomposition(args, seeds) -> None:
    print("| tracker | OSPA | " + " | ".join(PARTS) + " |")
    print("|---|---|" + "---|" * len(PARTS))
    with ProcessPoolExecutor(args.workers) as pool:
        for tr in args.trackers:
            res = list(pool.map(decompose_run, [(tr, args.scenario, s, args.overrides, args.gate) for s in seeds]))
            mean = {k: float(np.mean([r[k] for r in res])) for k in PARTS}
            print(f"| {tr} | {sum(mean.values()):.2f} | " + " | ".join(f"{mean[k]:.2f}" for k in PARTS) + " |",
                  flush=True)


CAL_BINS = np.array([0.0, 0.05, 0.15, 0.35, 0.5, 0.65, 0.8, 0.9, 1.0 + 1e-9])
CAL_AGES = 5  # ages 0..3 and "4 and more"


def object_rows(params, frame, seed: int) -> set[int]:
    """Rows of ``frame.z`` that are objects' detections (the simulator's draws replayed)."""
    from benchmarks.dropped_bound import labelled_detections
    rows: set[int] = set()
    for z in labelled_detections(params, frame, seed).values():
        rows.update(np.flatnonzero(np.all(np.isclose(frame.z, z[None]), axis=1)).tolist())
    return rows


def calibration_run(job) -> np.ndarray:
    """``(CAL_AGES, bins, 3)``: per age and existence bin, [clusters, object-born, sum of existence]
    over every cluster of every frame (BNP trackers: labels ``"<birth frame>.<row>"``)."""
    tracker_name, scenario, seed, overrides = job
    sc, tracker, frames = setup(tracker_name, "vo2017", scenario, seed, overrides)
    real = {f.frame: object_rows(tracker.params, f, seed) for f in frames}
    acc = np.zeros((CAL_AGES, CAL_BINS.size - 1, 3))
    for f, _, state in run(tracker, frames, seed):
        for lab, r in zip(state.labels, state.existence.tolist()):
            born, _, row = lab.partition(".")
            age = min(f.frame - int(born), CAL_AGES - 1)
            b = int(np.searchsorted(CAL_BINS, r, side="right")) - 1
            acc[age, b] += (1.0, float(int(row) in real[int(born)]), r)
    return acc


def print_calibration(args, seeds) -> None:
    with ProcessPoolExecutor(args.workers) as pool:
        for tr in args.trackers:
            acc = sum(pool.map(calibration_run, [(tr, args.scenario, s, args.overrides) for s in seeds]))
            print(f"{tr}: per age, existence bin: clusters n, mean existence r, fraction object-born")
            for age in range(CAL_AGES):
                cells = [f"[{CAL_BINS[i]:.2f},{min(CAL_BINS[i + 1], 1):.2f}) n={int(n)} r={s / n:.2f} obj={k / n:.2f}"
                         for i, (n, k, s) in enumerate(acc[age]) if n > 0]
                print(f"age {age}{'+' if age == CAL_AGES - 1 else ''}: " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
