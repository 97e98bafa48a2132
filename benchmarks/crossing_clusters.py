"""Why crossing pairs lose their labels under the two-level tracker: the cluster membership of
the two objects' tracks around the crossing scan.

For each crossing pair ``(a, b, c)`` of a generated scene (``random``): the tracks assigned
to ``a`` and ``b`` at each scan ``c-5 .. c+5`` (as :func:`sinks.crossings.crossing_label_keeping`,
optimal assignment within 100 m), whether the two tracks sat in **one motion cluster** at any
scan ``c-2 .. c`` ("shared"), and the pair's outcome (kept, or :func:`accuracy.crossing_failure`).
Prints, per tracker and setting, OSPA / OSPA(2) / card err / crossings kept (as
``benchmarks/accuracy.py``) and the contingency of outcome x shared.

    python benchmarks/crossing_clusters.py --tracker ddp --scenario random --first-seed 101 --seeds 20
    python benchmarks/crossing_clusters.py --tracker ddp --scenario vo2017 --first-seed 1 --seeds 20 --cross-distance 30
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from accuracy import crossing_failure, setup  # noqa: E402
from bnptrack.sinks.crossings import _assigned_labels, crossing_label_keeping  # noqa: E402
from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def pair_shared(ests, true_tracks, a, b, c: int, lo: int = 2) -> bool:
    """The tracks assigned to ``a`` and ``b`` share one cluster at some scan ``c-lo .. c``
    (scans numbered from 1; ``ests[k]`` is scan ``k + 1``)."""
    for s in range(c - lo, c + 1):
        k = s - 1
        if not 0 <= k < len(ests):
            continue
        est = {t.label: t.position for t in ests[k].tracks}
        lab = _assigned_labels(true_tracks[k], est, 100.0)
        la, lb = lab.get(a), lab.get(b)
        if la is None or lb is None or la == lb:
            continue
        cl = {t.label: t.cluster for t in ests[k].tracks}
        if cl.get(la) is not None and cl.get(la) == cl.get(lb):
            return True
    return False


def truth_crossings(true_tracks: list[dict], distance: float) -> list[tuple[str, str, int]]:
    """``(a, b, scan)`` for every pair of true objects whose closest approach is under
    ``distance`` m, at that scan (scans numbered from 1): the crossings of a scene that lists none."""
    ids = sorted({i for scan in true_tracks for i in scan})
    out = []
    for n, a in enumerate(ids):
        for b in ids[n + 1:]:
            d = [(float(np.linalg.norm(np.subtract(s[a], s[b]))), k + 1) for k, s in enumerate(true_tracks)
                 if a in s and b in s]
            if d and min(d)[0] < distance:
                out.append((a, b, min(d)[1]))
    return out


def one_seed(tracker: str, params: str, scenario: str, seed: int, overrides, cross_distance: float = 0.0) -> dict:
    sc, tr, frames = setup(tracker, params, scenario, seed, overrides)
    ests, rows = [], []
    for f, e, _ in run(tr, frames, seed):
        o = ospa(f.truth.positions, e.positions, c=100.0, p=1.0)
        rows.append((o.total, abs(len(e.tracks) - len(f.truth.ids))))
        ests.append(e)
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [{t.label: t.position for t in e.tracks} for e in ests]
    o2 = float(np.mean(ospa2_series(est_tracks, true_tracks, window=10, c=100.0, p=1.0)))
    crossings = truth_crossings(true_tracks, cross_distance) if cross_distance > 0 else sc.crossings
    pairs = crossing_label_keeping(true_tracks, est_tracks, crossings).pairs
    out = [("kept" if p.kept else crossing_failure(p), pair_shared(ests, true_tracks, p.id_a, p.id_b, p.scan))
           for p in pairs]
    r = np.array(rows)
    return dict(ospa=r[:, 0].mean(), card_err=r[:, 1].mean(), ospa2=o2, pairs=out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=101)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--cross-distance", type=float, default=0.0,
                    help="crossing pairs from the truth: objects whose closest approach is under this many m "
                         "(for scenes that list no crossings, e.g. vo2017); 0: the scene's list")
    args = ap.parse_args()
    res = [one_seed(args.tracker, args.params, args.scenario, s, args.overrides, args.cross_distance)
           for s in range(args.first_seed, args.first_seed + args.seeds)]
    pairs = [p for r in res for p in r["pairs"]]
    kept = sum(o == "kept" for o, _ in pairs)
    print(f"{args.tracker} {args.scenario} seeds {args.first_seed}..{args.first_seed + args.seeds - 1} "
          f"{args.overrides or ''}: OSPA {np.mean([r['ospa'] for r in res]):.2f} OSPA(2) "
          f"{np.mean([r['ospa2'] for r in res]):.2f} card err {np.mean([r['card_err'] for r in res]):.3f} "
          f"crossings kept {kept}/{len(pairs)}", flush=True)
    print("  outcome x shared-cluster at c-2..c:", dict(sorted(Counter(pairs).items())), flush=True)


if __name__ == "__main__":
    main()
