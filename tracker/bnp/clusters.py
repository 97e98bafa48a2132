r"""The clusters (objects) of one frame as plain arrays, and the merge of duplicates: one
object split over exclusive hypotheses."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import chain

import numpy as np


@dataclass(frozen=True)
class _Clusters:
    labels: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    existence: np.ndarray
    popularity: np.ndarray

    @staticmethod
    def empty() -> "_Clusters":
        return _Clusters((), np.zeros((0, 5)), np.zeros((0, 5, 5)), np.zeros(0), np.zeros(0))

    def take(self, idx: np.ndarray) -> "_Clusters":
        return _Clusters(tuple(self.labels[i] for i in idx.tolist()), self.mean[idx], self.cov[idx],
                         self.existence[idx], self.popularity[idx])


_POS_VEL = np.array([0, 1, 2, 3])


def merge_duplicates(c: _Clusters, max_d2: float) -> _Clusters:
    r"""Merge clusters that are one object split over exclusive hypotheses.

    A measurement that a young cluster and the base distribution explain about equally well
    is shared between them, and the object's existence is split over duplicates.  Greedily, in
    order of decreasing existence, a leader absorbs every cluster whose position-velocity state
    lies within squared Mahalanobis distance ``max_d2`` of it (covariance :math:`P_i + P_j`)
    while the existences absorbed so far sum to at most 1 (existences of exclusive hypotheses
    add; two objects that both exist are never merged).  The merged cluster keeps the label of
    its oldest member (the object's identity: a newborn duplicate never renames a track, nor
    counts as a second birth of the object) and the leader's popularity, its existence is the sum, and its Gaussian is the existence-weighted
    moment match.
    """
    n = len(c.labels)
    if max_d2 <= 0.0 or n < 2:
        return c
    r = c.existence
    ii, jj = _near_pairs(c, max_d2)
    both = r[ii] + r[jj] <= 1.0  # pairs that may both be one
    ii, jj = ii[both], jj[both]
    if ii.size == 0:
        return c
    diff = c.mean[ii][:, _POS_VEL] - c.mean[jj][:, _POS_VEL]
    S = (c.cov[ii] + c.cov[jj])[:, _POS_VEL][:, :, _POS_VEL]
    d2 = np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])
    near = d2 <= max_d2
    if not near.any():
        return c
    neighbours: dict[int, set[int]] = {}
    for i, j in zip(ii[near].tolist(), jj[near].tolist()):
        neighbours.setdefault(i, set()).add(j)
        neighbours.setdefault(j, set()).add(i)
    order = np.argsort(-r, kind="stable")
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    free = np.ones(n, dtype=bool)
    groups: list[list[int]] = []  # groups of two or more; every other cluster stays as it is
    for i in sorted(neighbours, key=rank.__getitem__):
        if not free[i]:
            continue
        group, total = [i], r[i]
        for j in sorted(neighbours[i], key=rank.__getitem__):  # decreasing existence
            if free[j] and total + r[j] <= 1.0:
                group.append(j)
                total += r[j]
        free[group] = False
        if len(group) > 1:
            groups.append(group)
    return _merge_groups(c, groups) if groups else c


def _near_pairs(c: _Clusters, max_d2: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Pairs ``i < j`` that can be within ``max_d2`` (a superset, from a KD-tree on positions).

    The position-velocity distance is at least the position-only one, which is at least
    :math:`\lVert \Delta p \rVert^2 / (\lambda_i + \lambda_j)` with :math:`\lambda` the
    largest eigenvalue of a cluster's position covariance; so pair ``(i, j)`` is a candidate
    only if :math:`\lVert \Delta p\rVert^2 \le d^2_{max} (\lambda_i + \lambda_j) \le 2 d^2_{max}
    \max(\lambda_i, \lambda_j)`: each cluster queries the ball of radius
    :math:`\sqrt{2 d^2_{max} \lambda_i}`, which holds every partner with a smaller :math:`\lambda`."""
    n = len(c.labels)
    if n <= 200:  # few clusters: every pair (cheaper than a tree)
        lo, hi = np.triu_indices(n, k=1)
        return lo.astype(np.int64), hi.astype(np.int64)
    from scipy.spatial import cKDTree  # lazy: few clusters need no tree, and scipy.spatial is slow to import

    pos = c.mean[:, [0, 2]]
    a, b, d = c.cov[:, 0, 0], c.cov[:, 2, 2], c.cov[:, 0, 2]
    lam = 0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + d * d)
    ok = np.flatnonzero(np.isfinite(pos).all(axis=1) & np.isfinite(lam))
    if ok.size < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    radius = np.sqrt(2.0 * max_d2 * lam[ok]) * (1.0 + 1e-9)
    hits = cKDTree(pos[ok]).query_ball_point(pos[ok], radius, return_sorted=False)
    lens = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))
    i = ok[np.repeat(np.arange(ok.size), lens)]
    j = ok[np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=int(lens.sum()))]
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    key = np.unique(lo[lo < hi] * len(c.labels) + hi[lo < hi])
    lo, hi = key // len(c.labels), key % len(c.labels)
    d2p = np.sum((pos[lo] - pos[hi]) ** 2, axis=1)
    near = d2p <= max_d2 * (lam[lo] + lam[hi]) * (1.0 + 1e-9)
    return lo[near], hi[near]


def _merge_groups(c: _Clusters, groups: list[list[int]]) -> _Clusters:
    """Each group (leader first) becomes one cluster in its leader's place: existences added,
    existence-weighted moment match, the oldest member's label; the other clusters are kept."""
    n = len(c.labels)
    mean, cov, r = c.mean.copy(), c.cov.copy(), c.existence.copy()
    labels = list(c.labels)
    leaders = np.array([g[0] for g in groups])
    members = np.concatenate([np.asarray(g) for g in groups])
    gk = np.repeat(leaders, [len(g) for g in groups])  # member -> its leader
    w = c.existence[members]
    r[leaders] = np.bincount(gk, weights=w, minlength=n)[leaders]
    w = w / r[gk]
    mean[leaders] = 0.0
    np.add.at(mean, gk, w[:, None] * c.mean[members])
    dev = c.mean[members] - mean[gk]
    cov[leaders] = 0.0
    np.add.at(cov, gk, w[:, None, None] * (c.cov[members] + dev[:, :, None] * dev[:, None, :]))
    for g in groups:
        labels[g[0]] = min((c.labels[i] for i in g), key=_birth_frame)
    keep = np.setdiff1d(np.arange(n), np.concatenate([np.asarray(g[1:]) for g in groups]))
    return _Clusters(tuple(labels[k] for k in keep.tolist()), mean[keep], cov[keep],
                     np.minimum(r[keep], 1.0), c.popularity[keep])


def _birth_frame(label: str) -> int:
    """Birth frame of a cluster label ``"<frame>.<measurement>"`` (labels sort by it)."""
    head, _, _ = label.partition(".")
    return int(head) if head.lstrip("-").isdigit() else 0


def _born_at(c: _Clusters, frame: int) -> float:
    """Expected number of objects born at ``frame``: the summed existence of the clusters whose
    label (``"<birth frame>.<measurement>"``) says they were born then."""
    prefix = f"{frame}."
    return float(sum(r for lab, r in zip(c.labels, c.existence.tolist()) if lab.startswith(prefix)))


def _concat(a: _Clusters, b: _Clusters) -> _Clusters:
    return _Clusters(a.labels + b.labels, np.concatenate([a.mean, b.mean]), np.concatenate([a.cov, b.cov]),
                     np.concatenate([a.existence, b.existence]), np.concatenate([a.popularity, b.popularity]))
