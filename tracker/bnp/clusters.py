r"""The clusters (objects) of one frame as plain arrays, and the merge of duplicates: one
object split over exclusive hypotheses."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bnptrack.tracker.numerics import jit, unique_ints
from bnptrack.tracker.bnp import _merge_kernels as _k


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
    if n <= 200:  # candidates, their distances, groups and moments in one compiled pass
        ii, jj, undecided, ptr, members, mean, cov, r, keep, done = _k.merge_pass(
            c.mean, c.cov, c.existence, float(max_d2), _BOUND_MARGIN)
        if done:
            return _relabel(c, ptr, members, mean, cov, r, keep) if ptr.size > 1 else c
    else:
        ii, jj, undecided = _merge_candidates(c, max_d2)
    if undecided.any():  # the exact test for the pairs the compiled bound could not decide
        u = np.flatnonzero(undecided)
        diff = c.mean[ii[u]][:, _POS_VEL] - c.mean[jj[u]][:, _POS_VEL]
        S = (c.cov[ii[u]] + c.cov[jj[u]])[:, _POS_VEL][:, :, _POS_VEL]
        d2 = np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])
        near = np.ones(ii.size, dtype=bool)
        near[u] = d2 <= max_d2
        ii, jj = ii[near], jj[near]
    if ii.size == 0:
        return c
    ptr, members = _k.merge_groups(c.existence, ii, jj)
    return _apply_groups(c, ptr, members) if ptr.size > 1 else c


#: Relative margin of the lower bound that leaves a pair out of the exact distance test.
_BOUND_MARGIN = 1e-3


def _merge_candidates(c: _Clusters, max_d2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Above 200 clusters: the pairs ``i < j`` of a KD-tree (:func:`_near_pairs`) whose
    existences sum to at most 1, all ``undecided`` (the exact test decides them)."""
    r = c.existence
    ii, jj = _near_pairs(c, max_d2, exclusive=True)
    both = r[ii] + r[jj] <= 1.0  # pairs that may both be one
    return ii[both], jj[both], np.ones(int(both.sum()), dtype=bool)


def _near_pairs(c: _Clusters, max_d2: float, exclusive: bool = False) -> tuple[np.ndarray, np.ndarray]:
    r"""Pairs ``i < j`` that can be within ``max_d2`` (a superset, from a grid on positions:
    :func:`ball_hits`; the same pairs as a KD-tree's ball queries).

    The position-velocity distance is at least the position-only one, which is at least
    :math:`\lVert \Delta p \rVert^2 / (\lambda_i + \lambda_j)` with :math:`\lambda` the
    largest eigenvalue of a cluster's position covariance; so pair ``(i, j)`` is a candidate
    only if :math:`\lVert \Delta p\rVert^2 \le d^2_{max} (\lambda_i + \lambda_j) \le 2 d^2_{max}
    \max(\lambda_i, \lambda_j)`: each cluster queries the ball of radius
    :math:`\sqrt{2 d^2_{max} \lambda_i}`, which holds every partner with a smaller :math:`\lambda`.
    The pairs returned are those of the test below (the same numpy expression, in key order);
    the balls only have to hold them.  ``exclusive``: only the pairs whose existences sum to at
    most 1 (:func:`exclusive_near_pairs`; the same pairs, in the same order, as those of all
    clusters that pass that test)."""
    n = len(c.labels)
    if n <= 200:  # few clusters: every pair (cheaper than a tree)
        lo, hi = np.triu_indices(n, k=1)
        return lo.astype(np.int64), hi.astype(np.int64)
    pos = c.mean[:, [0, 2]]
    a, b, d = c.cov[:, 0, 0], c.cov[:, 2, 2], c.cov[:, 0, 2]
    lam = 0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + d * d)
    ok = np.flatnonzero(np.isfinite(pos).all(axis=1) & np.isfinite(lam))
    if ok.size < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    radius = np.sqrt(2.0 * max_d2 * lam[ok]) * (1.0 + 1e-9)
    if exclusive:  # the pairs once each, already through the test below: in key order
        a, b = exclusive_near_pairs(np.ascontiguousarray(pos[ok]), radius, np.ascontiguousarray(c.existence[ok]),
                                    np.ascontiguousarray(lam[ok]), float(max_d2))
        key = np.sort(ok[a] * len(c.labels) + ok[b])
        return key // len(c.labels), key % len(c.labels)
    a, b = ball_hits(np.ascontiguousarray(pos[ok]), radius)
    i, j = ok[a], ok[b]
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    key = unique_ints(lo[lo < hi] * len(c.labels) + hi[lo < hi])
    lo, hi = key // len(c.labels), key % len(c.labels)
    d2p = np.sum((pos[lo] - pos[hi]) ** 2, axis=1)
    near = d2p <= max_d2 * (lam[lo] + lam[hi]) * (1.0 + 1e-9)
    return lo[near], hi[near]


def _merge_groups(c: _Clusters, groups: list[list[int]]) -> _Clusters:
    """Each group (leader first) becomes one cluster in its leader's place: existences added,
    existence-weighted moment match, the oldest member's label; the other clusters are kept."""
    ptr = np.zeros(len(groups) + 1, dtype=np.int64)
    np.cumsum([len(g) for g in groups], out=ptr[1:])
    return _apply_groups(c, ptr, np.concatenate([np.asarray(g, dtype=np.int64) for g in groups]))


def _apply_groups(c: _Clusters, ptr: np.ndarray, members: np.ndarray, oldest: np.ndarray | None = None) -> _Clusters:
    """:func:`_merge_groups` of the groups in CSR form (``members[ptr[g]:ptr[g + 1]]``, leader
    first), the arithmetic in :func:`tracker.bnp._merge_kernels.merge_moments`; ``oldest``: each
    group's :func:`oldest_members` when known."""
    return _relabel(c, ptr, members, *_k.merge_moments(c.mean, c.cov, c.existence, ptr, members), oldest)


def oldest_members(ptr: np.ndarray, members: np.ndarray, birth: np.ndarray) -> np.ndarray:
    """Each group's (``members[ptr[g]:ptr[g + 1]]``) oldest member: the first, in group order, of
    those with the smallest ``birth`` (the member ``min(group, key=birth)`` picks)."""
    gid = np.repeat(np.arange(ptr.size - 1), np.diff(ptr))
    order = np.lexsort((np.arange(members.size), birth[members], gid))
    return members[order[ptr[:-1]]]


def _relabel(c: _Clusters, ptr: np.ndarray, members: np.ndarray, mean: np.ndarray, cov: np.ndarray,
             r: np.ndarray, keep: np.ndarray, oldest: np.ndarray | None = None) -> _Clusters:
    """The clusters after the merge of the groups ``members[ptr[g]:ptr[g + 1]]`` (leader first)
    whose moments are ``mean``, ``cov``, ``r`` (every row) and rows ``keep``: each leader takes
    its oldest member's label (``oldest``: each group's, when known)."""
    labels = list(c.labels)
    if oldest is None:
        for a, b in zip(ptr[:-1].tolist(), ptr[1:].tolist()):
            group = members[a:b].tolist()
            labels[group[0]] = min((c.labels[i] for i in group), key=_birth_frame)
    else:
        for leader, k in zip(members[ptr[:-1]].tolist(), oldest.tolist()):
            labels[leader] = c.labels[k]
    kept = np.flatnonzero(keep)
    return _Clusters(tuple(labels[k] for k in kept.tolist()), mean[kept], cov[kept],
                     np.minimum(r[kept], 1.0), c.popularity[kept])


@lru_cache(maxsize=1 << 14)  # a cluster keeps its label for many frames
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
    if not b.labels:  # a frame without births: the same arrays (nothing mutates them), no copies
        return a
    return _Clusters(a.labels + b.labels, np.concatenate([a.mean, b.mean]), np.concatenate([a.cov, b.cov]),
                     np.concatenate([a.existence, b.existence]), np.concatenate([a.popularity, b.popularity]))


def _cell_range(lo: float, hi: float, h: float, n: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """The cells ``0 .. n - 1`` of width ``h`` that ``[lo, hi]`` overlaps (clamped before the
    conversion to int)."""
    return int(min(max(np.floor(lo / h), 0.0), n - 1.0)), int(min(max(np.floor(hi / h), 0.0), n - 1.0))


def _grid_shape(pos: np.ndarray, radius: np.ndarray) -> tuple[float, float, float, int, int]:  # pragma: no cover - compiled
    """The grid of :func:`ball_hits` over ``pos`` (n >= 1): its corner ``(x0, y0)``, cell width
    ``h`` (about the median radius, doubled until at most 4 n + 16 cells) and cells ``nx x ny``."""
    n = pos.shape[0]
    x0, x1, y0, y1 = pos[:, 0].min(), pos[:, 0].max(), pos[:, 1].min(), pos[:, 1].max()
    h = np.median(radius)
    if not (np.isfinite(h) and h > 1e-9 * max(x1 - x0, y1 - y0, 1.0)):
        h = max(x1 - x0, y1 - y0, 1.0)
    while (np.floor((x1 - x0) / h) + 1.0) * (np.floor((y1 - y0) / h) + 1.0) > 4.0 * n + 16.0:
        h *= 2.0
    nx, ny = int(np.floor((x1 - x0) / h)) + 1, int(np.floor((y1 - y0) / h)) + 1
    return x0, y0, h, nx, ny


def ball_hits(pos: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Pairs ``(a, b)``, ``a != b``, with point ``b`` within about ``radius[a]`` of point ``a``
    (squared distance at most ``radius[a]^2 (1 + 1e-6)``: a superset of the ball's points) from
    cell lists on a uniform grid (cells of about the median radius, at most 4 n + 16 of them);
    ``pos`` (n, 2) and ``radius`` (n,) finite.  In no particular order."""
    n = pos.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    x0, y0, h, nx, ny = _grid_shape(pos, radius)
    start, members = _grid_members(pos, np.arange(n), x0, y0, h, nx, ny)
    out_a, out_b, count = np.empty(4 * n, dtype=np.int64), np.empty(4 * n, dtype=np.int64), 0
    for a in range(n):
        r = radius[a] * (1.0 + 1e-6)
        r2 = radius[a] * radius[a] * (1.0 + 1e-6)
        if not np.isfinite(r2):  # no ball (a query with a radius that is not finite finds nothing)
            continue
        i0, i1 = _cell_range(pos[a, 0] - r - x0, pos[a, 0] + r - x0, h, nx)
        j0, j1 = _cell_range(pos[a, 1] - r - y0, pos[a, 1] + r - y0, h, ny)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(start[i * ny + j], start[i * ny + j + 1]):
                    b = members[k]
                    dx, dy = pos[b, 0] - pos[a, 0], pos[b, 1] - pos[a, 1]
                    if b != a and dx * dx + dy * dy <= r2:
                        if count == out_a.size:
                            out_a, out_b = np.concatenate((out_a, out_a)), np.concatenate((out_b, out_b))
                        out_a[count], out_b[count] = a, b
                        count += 1
    return out_a[:count].copy(), out_b[:count].copy()


def _grid_members(pos: np.ndarray, idx: np.ndarray, x0: float, y0: float, h: float, nx: int, ny: int
                  ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Cell lists of the points ``idx`` on :func:`ball_hits`' grid: ``members[start[c]:start[c + 1]]``
    the points of cell ``c`` (in ``idx`` order)."""
    cell = np.empty(idx.size, dtype=np.int64)
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for q in range(idx.size):
        k = idx[q]
        cell[q] = min(int((pos[k, 0] - x0) / h), nx - 1) * ny + min(int((pos[k, 1] - y0) / h), ny - 1)
        start[cell[q] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill, members = start[:-1].copy(), np.empty(idx.size, dtype=np.int64)
    for q in range(idx.size):
        members[fill[cell[q]]] = idx[q]
        fill[cell[q]] += 1
    return start, members


def exclusive_near_pairs(pos: np.ndarray, radius: np.ndarray, existence: np.ndarray, lam: np.ndarray, max_d2: float
                         ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    r""":func:`ball_hits`' pairs ``(a, b)`` with ``existence[a] + existence[b] <= 1`` that pass :func:`_near_pairs`' test
    :math:`\lVert \Delta p\rVert^2 \le d^2_{max} (\lambda_a + \lambda_b)` (the same expression),
    each once as ``(a, b)`` with ``a < b``, in no particular order.  A pair that passes the test
    lies in the ball of its member of larger :math:`\lambda` (``radius`` grows with it), so only
    that member's search keeps it (ties: the smaller index; a member whose ball is not finite
    searches nothing and leaves the pair to the other): no pair is found twice."""
    n = pos.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    x0, y0, h, nx, ny = _grid_shape(pos, radius)
    start_all, members_all = _grid_members(pos, np.arange(n), x0, y0, h, nx, ny)
    weak = existence <= 0.5
    start_weak, members_weak = _grid_members(pos, np.flatnonzero(weak), x0, y0, h, nx, ny)
    finite = np.empty(n, dtype=np.bool_)
    for a in range(n):
        finite[a] = np.isfinite(radius[a] * radius[a] * (1.0 + 1e-6))
    out_a, out_b, count = np.empty(2 * n, dtype=np.int64), np.empty(2 * n, dtype=np.int64), 0
    for a in range(n):
        if not finite[a]:
            continue
        r = radius[a] * (1.0 + 1e-6)
        r2 = radius[a] * radius[a] * (1.0 + 1e-6)
        start, members = (start_all, members_all) if weak[a] else (start_weak, members_weak)
        i0, i1 = _cell_range(pos[a, 0] - r - x0, pos[a, 0] + r - x0, h, nx)
        j0, j1 = _cell_range(pos[a, 1] - r - y0, pos[a, 1] + r - y0, h, ny)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(start[i * ny + j], start[i * ny + j + 1]):
                    b = members[k]
                    if b == a or (finite[b] and (lam[b] > lam[a] or (lam[b] == lam[a] and b < a))):
                        continue  # b's search keeps this pair
                    dx, dy = pos[b, 0] - pos[a, 0], pos[b, 1] - pos[a, 1]
                    if not (existence[a] + existence[b] <= 1.0 and dx * dx + dy * dy <= r2):
                        continue
                    lo, hi = min(a, b), max(a, b)
                    ex, ey = pos[lo, 0] - pos[hi, 0], pos[lo, 1] - pos[hi, 1]
                    if ex * ex + ey * ey <= max_d2 * (lam[lo] + lam[hi]) * (1.0 + 1e-9):
                        if count == out_a.size:
                            out_a, out_b = np.concatenate((out_a, out_a)), np.concatenate((out_b, out_b))
                        out_a[count], out_b[count] = lo, hi
                        count += 1
    return out_a[:count].copy(), out_b[:count].copy()


_cell_range = jit(_cell_range)
_grid_shape = jit(_grid_shape)
ball_hits = jit(ball_hits)
_grid_members = jit(_grid_members)
exclusive_near_pairs = jit(exclusive_near_pairs)
