"""Compiled passes of the duplicate merging of :mod:`tracker.bnp.clusters`: the candidate pairs
(:func:`merge_candidates`), the exact distance test (:func:`cholesky_distance`), the groups
(:func:`merge_groups`), their moments (:func:`merge_moments`) and the whole pass
(:func:`merge_pass`), bit for bit the numpy code's (:mod:`tracker.bnp._kernels` says how)."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import argsort_stable, jit
from bnptrack.tracker.bnp._kernels import divide


def merge_candidates(mean, cov, r, max_d2, margin):  # pragma: no cover - compiled
    r"""Pairs ``i < j`` (in ``np.triu_indices`` order) whose existences sum to at most 1 and
    whose position-velocity distance :math:`\Delta^T (P_i + P_j)^{-1} \Delta` may be within
    ``max_d2``, and which of them the exact test (``np.linalg.solve``) must still decide.

    A pair is left out when a lower bound of its distance exceeds ``max_d2 (1 + margin)``:
    :math:`\Delta^T S^{-1} \Delta \ge \lVert\Delta\rVert^2 / \mathrm{tr}\, S` for a positive
    definite ``S``.  Otherwise the distance is computed here (Cholesky) and decides the pair
    when it lies farther from ``max_d2`` than a bound of the rounding error of either
    computation (:math:`10^3 \epsilon \kappa^2`, :math:`\kappa \le \lVert S\rVert_F
    \lVert L^{-1}\rVert_F^2` the condition number); a pair with a symmetric ``S`` that is
    not positive definite, non-finite, or too close to call is flagged ``undecided``.  The
    decisions are therefore those of testing every pair with ``np.linalg.solve``."""
    n = r.shape[0]
    out_i = np.empty(n * (n - 1) // 2, dtype=np.int64)
    out_j = np.empty(n * (n - 1) // 2, dtype=np.int64)
    undecided = np.empty(n * (n - 1) // 2, dtype=np.bool_)
    S = np.empty((4, 4))
    e = np.empty(4)
    k = 0
    for i in range(n):
        for j in range(i + 1, n):
            if not (r[i] + r[j] <= 1.0):
                continue
            dist, tr = 0.0, 0.0
            for a in range(4):
                e[a] = mean[i, a] - mean[j, a]
                dist += e[a] * e[a]
                tr += cov[i, a, a] + cov[j, a, a]
            if tr > 0.0 and dist == dist and tr < np.inf and dist > max_d2 * (1.0 + margin) * tr:
                continue
            for a in range(4):
                for b in range(4):
                    S[a, b] = cov[i, a, b] + cov[j, a, b]
            d2 = cholesky_distance(S, e, max_d2)
            if d2 == -1.0:
                state = 2  # undecided
            elif d2 <= max_d2:
                state = 1  # near
            else:
                state = 0
            if state == 0:
                continue
            out_i[k], out_j[k], undecided[k] = i, j, state == 2
            k += 1
    return out_i[:k], out_j[:k], undecided[:k]


def cholesky_distance(S, e, max_d2):  # pragma: no cover - compiled
    """:math:`e^T S^{-1} e` of a 4 x 4 ``S`` by Cholesky, or -1 when that cannot decide the
    comparison with ``max_d2`` as ``np.linalg.solve`` would (see :func:`merge_candidates`)."""
    L = np.zeros((4, 4))
    s_norm = 0.0
    for a in range(4):
        for b in range(4):
            if S[a, b] != S[b, a] or not np.isfinite(S[a, b]):
                return -1.0
            s_norm += S[a, b] * S[a, b]
    for a in range(4):
        acc = S[a, a]
        for c in range(a):
            acc -= L[a, c] * L[a, c]
        if not acc > 0.0:
            return -1.0
        L[a, a] = np.sqrt(acc)
        for b in range(a + 1, 4):
            acc = S[b, a]
            for c in range(a):
                acc -= L[b, c] * L[a, c]
            L[b, a] = acc / L[a, a]
    inv = np.zeros((4, 4))  # L^-1, lower triangular
    inv_norm = 0.0
    for col in range(4):
        for a in range(col, 4):
            acc = 1.0 if a == col else 0.0
            for c in range(col, a):
                acc -= L[a, c] * inv[c, col]
            inv[a, col] = acc / L[a, a]
            inv_norm += inv[a, col] * inv[a, col]
    d2 = 0.0
    for a in range(4):
        y = 0.0
        for c in range(a + 1):
            y += inv[a, c] * e[c]
        d2 += y * y
    kappa = np.sqrt(s_norm) * inv_norm  # >= the 2-norm condition number of S
    tol = 1e3 * 2.220446049250313e-16 * kappa * kappa + 1e-12
    if not (d2 == d2 and tol < 0.5 and abs(d2 - max_d2) > tol * max(d2, max_d2)):
        return -1.0
    return d2


def merge_groups(r, ii, jj):  # pragma: no cover - compiled
    """The greedy groups of ``merge_duplicates``: leaders in order of decreasing existence
    (stable), each absorbing its free neighbours (pairs ``ii``, ``jj``) in that order while
    the existences absorbed sum to at most 1.  Returns the groups of two or more as CSR
    (``ptr``, ``members``, leader first), leaders in the order they were formed."""
    n = r.shape[0]
    order = argsort_stable(-r)
    rank = np.empty(n, dtype=np.int64)
    for k in range(n):
        rank[order[k]] = k
    deg = np.zeros(n + 1, dtype=np.int64)
    for p in range(ii.shape[0]):
        deg[ii[p] + 1] += 1
        deg[jj[p] + 1] += 1
    for k in range(n):
        deg[k + 1] += deg[k]
    nb_rank = np.empty(deg[n], dtype=np.int64)
    fill = deg[:n].copy()
    for p in range(ii.shape[0]):
        a, b = ii[p], jj[p]
        nb_rank[fill[a]] = rank[b]
        fill[a] += 1
        nb_rank[fill[b]] = rank[a]
        fill[b] += 1
    for k in range(n):  # each cluster's neighbours' ranks, ascending
        seg = nb_rank[deg[k]:deg[k + 1]].copy()
        ascending = argsort_stable(seg)
        for q in range(seg.shape[0]):
            nb_rank[deg[k] + q] = seg[ascending[q]]
    free = np.ones(n, dtype=np.bool_)
    ptr = np.zeros(n + 1, dtype=np.int64)
    members = np.empty(n, dtype=np.int64)
    n_groups, n_members = 0, 0
    for k in range(n):
        i = order[k]
        if deg[i] == deg[i + 1] or not free[i]:
            continue
        free[i] = False
        start, total = n_members, r[i]
        members[n_members] = i
        n_members += 1
        for q in range(deg[i], deg[i + 1]):
            j = order[nb_rank[q]]
            if free[j] and total + r[j] <= 1.0:
                free[j] = False
                members[n_members] = j
                n_members += 1
                total += r[j]
        if n_members - start > 1:
            n_groups += 1
            ptr[n_groups] = n_members
        else:
            n_members = start
    return ptr[:n_groups + 1], members[:n_members]


def merge_moments(mean0, cov0, r, ptr, members):  # pragma: no cover - compiled
    """Each group (leader first) moment-matched into its leader's row in the order of
    :func:`tracker.bnp.clusters._merge_groups_numpy` (``np.bincount`` / ``np.add.at`` over the
    members): existence the sum, mean and covariance existence-weighted.  Returns the new
    ``mean``, ``cov``, ``r`` (every row; the absorbed ones unchanged) and the mask of the rows
    kept (all but the absorbed)."""
    mean, cov, r_out = mean0.copy(), cov0.copy(), r.copy()
    keep = np.ones(r.shape[0], dtype=np.bool_)
    d = mean0.shape[1]
    dev = np.empty(d)
    for g in range(ptr.shape[0] - 1):
        lead = members[ptr[g]]
        tot = 0.0
        for q in range(ptr[g], ptr[g + 1]):
            tot += r[members[q]]
        r_out[lead] = tot
        mean[lead, :] = 0.0
        for q in range(ptr[g], ptr[g + 1]):
            m = members[q]
            w = divide(r[m], tot)
            for a in range(d):
                mean[lead, a] += w * mean0[m, a]
        cov[lead, :, :] = 0.0
        for q in range(ptr[g], ptr[g + 1]):
            m = members[q]
            w = divide(r[m], tot)
            for a in range(d):
                dev[a] = mean0[m, a] - mean[lead, a]
            for a in range(d):
                for b in range(d):
                    cov[lead, a, b] += w * (cov0[m, a, b] + dev[a] * dev[b])
            if q > ptr[g]:
                keep[m] = False
    return mean, cov, r_out, keep


def merge_pass(mean, cov, r, max_d2, margin):  # pragma: no cover - compiled
    """:func:`merge_candidates`, then, when the kernel decided every pair, :func:`merge_groups`
    and :func:`merge_moments` in the same call (one kernel to load, not three).  Returns the
    candidates and their ``undecided`` flags, and ``done``: the groups and the merged moments
    (with ``done`` False, the caller decides the undecided pairs and groups them itself)."""
    ii, jj, undecided = merge_candidates(mean, cov, r, max_d2, margin)
    n = r.shape[0]
    if undecided.any() or ii.shape[0] == 0:
        return (ii, jj, undecided, np.zeros(1, np.int64), np.zeros(0, np.int64), mean, cov, r,
                np.ones(n, np.bool_), False)
    ptr, members = merge_groups(r, ii, jj)
    if ptr.shape[0] <= 1:
        return ii, jj, undecided, ptr, members, mean, cov, r, np.ones(n, np.bool_), True
    m2, c2, r2, keep = merge_moments(mean, cov, r, ptr, members)
    return ii, jj, undecided, ptr, members, m2, c2, r2, keep, True


cholesky_distance = jit(cholesky_distance)
merge_candidates = jit(merge_candidates)
merge_groups = jit(merge_groups)
merge_moments = jit(merge_moments)
merge_pass = jit(merge_pass)
