"""Where a tracker loses on a scene: missed object-scans (group members / free objects, young / older),
false-track scans, label switches, OSPA(2); per run, mean over seeds (docs/trackers.md, "Two-level model").

Each scan, true objects are matched to tracks within 100 m by optimal assignment. "young": fewer
than 5 scans since the object's first scan; a label switch: the track matched to a true object
changes between two scans in which it is matched; a false-track scan: a track matched to no
object ("near": within 100 m of one).  Keys: miss_grp_young, miss_grp_old, miss_free_*, false,
false_near, false_far, switch_grp, switch_free, meanloc_* (m), ospa2x100 (OSPA(2) x 100);
two-level trackers: members (tracks with a cluster), in_groups (of those, in a cluster of 2+);
pairs of matched objects per scan (docs/trackers.md, "Power-law group sizes"): pair_TP (one
true group, one cluster), pair_FN_split (one true group, two clusters), pair_FN_nocl (one true
group, a member without a cluster), pair_FP_groups (two true groups in one cluster),
pair_FP_single (a true singleton in someone's cluster).

    python benchmarks/groups_errors.py ddp-mb 101 10 groups merge_distance=0
"""

from __future__ import annotations

import os
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sinks.metrics import ospa2_series  # noqa: E402
from bnptrack.sources.scenarios import get_scenario, is_generated  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.registry import build, kind  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def _match(P: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, dict[int, int]]:
    D = np.linalg.norm(P[:, None] - E[None], axis=2) if len(E) and len(P) else np.zeros((len(P), len(E)))
    if not D.size:
        return D, {}
    rows, cols = linear_sum_assignment(np.minimum(D, 100.0))
    return D, {int(r): int(c) for r, c in zip(rows, cols) if D[r, c] < 100.0}


def pair_counts(truth_groups: list[str], clusters: list, c: Counter) -> None:
    """Count the pairs of matched objects by true group (``g*``: a group; else a singleton) and cluster."""
    for a in range(len(clusters)):
        for b in range(a + 1, len(clusters)):
            same_t = truth_groups[a] == truth_groups[b]
            same_c = clusters[a] is not None and clusters[a] == clusters[b]
            if same_t:
                key = "TP" if same_c else ("FN_nocl" if None in (clusters[a], clusters[b]) else "FN_split")
            elif same_c:
                single = not (truth_groups[a].startswith("g") and truth_groups[b].startswith("g"))
                key = "FP_single" if single else "FP_groups"
            else:
                continue
            c[f"pair_{key}"] += 1


def one(job) -> Counter:
    tr, seed, over, scen = job
    sc = get_scenario(scen, seed=seed) if is_generated(scen) else get_scenario(scen)
    params = sc.adapt_params(load_params("vo2017"))
    tracker = build(tr, params, apply_overrides(kind(tr).presets[tr], over))
    frames = simulate_all(sc, params, seed)
    grouped = {i for g in sc.groups for i in g}
    group_of = {i: f"g{k}" for k, g in enumerate(sc.groups) for i in g}
    first, last, c, ests = {}, {}, Counter(), []
    for f, e, _ in run(tracker, frames, seed):
        ests.append(e)
        E = e.positions if len(e.tracks) else np.zeros((0, 2))
        D, matched = _match(f.truth.positions, E)
        for r, i in enumerate(f.truth.ids):
            first.setdefault(i, f.frame)
            g = "grp" if i in grouped else "free"
            c[f"obj_{g}"] += 1
            if r not in matched:
                c[f"miss_{g}_{'young' if f.frame - first[i] < 5 else 'old'}"] += 1
                continue
            lab = e.tracks[matched[r]].label
            c[f"switch_{g}"] += int(i in last and last[i] != lab)
            last[i] = lab
            c[f"locerr_{g}"] += D[r, matched[r]]
        rows = sorted(matched)
        pair_counts([group_of.get(f.truth.ids[r], f.truth.ids[r]) for r in rows],
                    [e.tracks[matched[r]].cluster for r in rows], c)
        sizes = Counter(t.cluster for t in e.tracks if t.cluster is not None)
        c["members"] += sum(sizes.values())
        c["in_groups"] += sum(n for n in sizes.values() if n > 1)
        for j in set(range(len(E))) - set(matched.values()):
            c["false"] += 1
            c["false_near" if len(D) and D[:, j].min() < 100.0 else "false_far"] += 1
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [{t.label: t.position for t in e.tracks} for e in ests]
    c["ospa2x100"] = 100 * float(np.mean(ospa2_series(est_tracks, true_tracks, window=10, c=100.0, p=1.0)))
    return c


def main() -> None:
    tr, s0, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    scen = sys.argv[4] if len(sys.argv) > 4 else "groups"
    over = sys.argv[5:]
    with ProcessPoolExecutor(2) as pool:
        res = list(pool.map(one, [(tr, s, over, scen) for s in range(s0, s0 + n)]))
    tot = Counter()
    for r in res:
        tot.update(r)
    out = {k: round(v / len(res), 2) for k, v in sorted(tot.items()) if not k.startswith("locerr")}
    for g in ("grp", "free"):
        hit = tot[f"obj_{g}"] - tot[f"miss_{g}_young"] - tot[f"miss_{g}_old"]
        if hit:
            out[f"meanloc_{g}"] = round(tot[f"locerr_{g}"] / hit, 2)
    print(tr, scen, over, out)


if __name__ == "__main__":
    main()
