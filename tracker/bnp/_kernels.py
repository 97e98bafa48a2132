r"""Compiled passes of the DDP-EMM / DPY-STP step: the same arithmetic as the numpy
reference code, bit for bit.

The step chained about a hundred numpy calls on arrays of a few dozen entries, so the
interpreter's per-call cost, not the arithmetic, set its time.  Here the bookkeeping runs in a
few numba kernels (``cache=True``; ``BNPTRACK_NO_JIT=1`` runs the same functions interpreted).
Their results equal the numpy reference's to the last bit, which the kernels keep by
construction:

* ``exp`` and ``log`` stay in numpy (its SIMD versions differ from the C library's, which
  numba calls, in the last bit); a kernel takes their values as inputs or returns what numpy
  must transform.  ``math.log`` of the Python code is the C library's, as in numba.
* Sums run in numpy's order: ``np.bincount`` and ``np.add.at`` add in index order from 0.0;
  ``np.sum`` of a contiguous array is numpy's pairwise summation (:func:`np_sum`).
* No fused multiply-add (numba does not contract without ``fastmath``).

Each kernel's test (``tests/tracker/test_bnp_kernels.py``) compares it with the numpy code on
seed-pinned random inputs, bit for bit.
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker._lsap import lsap
from bnptrack.tracker.numerics import jit


def np_sum(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """``np.sum(a[lo:lo + n])`` in numpy's order (``pairwise_sum``): blocks of at most 128
    terms (:func:`_pairwise_block`), and above 128 the sum of the two halves, split at a
    multiple of 8.  The halving runs on an explicit stack, not by recursion: a cached kernel
    that calls a recursive one crashes when it is loaded from numba's cache."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    f_lo = np.empty(64, dtype=np.int64)  # depth <= log2(n / 128) + 1
    f_n = np.empty(64, dtype=np.int64)
    f_left = np.empty(64)
    f_right = np.zeros(64, dtype=np.bool_)  # the left half is summed; its right half is on top
    depth, f_lo[0], f_n[0] = 0, lo, n
    while True:
        cl, cn = f_lo[depth], f_n[depth]
        if cn > 128:  # descend into the left half
            n2 = cn // 2
            n2 -= n2 % 8
            depth += 1
            f_lo[depth], f_n[depth], f_right[depth] = cl, n2, False
            continue
        ret = _pairwise_block(a, cl, cn)
        while True:  # hand the finished sum to the parents
            if depth == 0:
                return ret
            is_right = f_right[depth]
            depth -= 1
            if not is_right:
                f_left[depth] = ret
                pl, pn = f_lo[depth], f_n[depth]
                n2 = pn // 2
                n2 -= n2 % 8
                depth += 1
                f_lo[depth], f_n[depth], f_right[depth] = pl + n2, pn - n2, True
                break
            ret = f_left[depth] + ret


def _pairwise_block(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """numpy's ``pairwise_sum`` of at most 128 terms: a plain loop below 8 terms, else eight
    interleaved partial sums, combined pairwise, then the remainder."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


# -- duplicate merging (tracker.bnp.clusters) ----------------------------------------------------

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
    order = np.argsort(-r, kind="mergesort")
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
    for k in range(n):
        nb_rank[deg[k]:deg[k + 1]].sort()
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


def divide(a, b):  # pragma: no cover - compiled
    """``a / b`` with numpy's result for ``b == 0`` (nan or +-inf; numba's default raises)."""
    if b != 0.0:
        return a / b
    if a == 0.0 or a != a:
        return np.nan
    return np.inf if (a > 0.0) == (np.copysign(1.0, b) > 0.0) else -np.inf


# -- the sampler's inputs (tracker.bnp.filter._problem) ------------------------------------------

def problem_log_args(p_detect, q_pred, pop, d, eps):  # pragma: no cover - compiled
    """The arguments of the cluster weights' logs, ``[q, P_D, miss, v - d]`` (one vector for
    numpy's ``log``), with ``P_D`` clipped to ``[0, 1 - 1e-9]``, ``q`` to ``[0, 1]`` and
    ``miss = max(q (1 - P_D) + 1 - q, eps)``; and the clipped ``q``.  A zero argument is
    given as 1 and flagged in ``zero`` (its log is ``-inf``: no divide warning to silence)."""
    N = q_pred.shape[0]
    out = np.empty(4 * N)
    q = np.empty(N)
    for l in range(N):
        pd = p_detect[l]
        if pd < 0.0:
            pd = 0.0
        elif pd > 1.0 - 1e-9:
            pd = 1.0 - 1e-9
        q[l] = clip01(q_pred[l])
        out[l] = q[l]
        out[N + l] = pd
        out[2 * N + l] = npmax(q[l] * (1.0 - pd) + 1.0 - q[l], eps)
        out[3 * N + l] = pop[l] - d
    zero = out == 0.0
    out[zero] = 1.0
    return out, q, zero


def problem_pairs(logs, zero, q, pop, ti, mi, log_lik, M):  # pragma: no cover - compiled
    """The gated pairs' ``log_first = log q + log P_D - log miss + log(v - d) + log_lik`` (the
    numpy code's order; ``logs`` the logs of :func:`problem_log_args`), those with a finite
    one kept as CSR by measurement (``ptr``, ``idx``, ``log_first``, ``log_lik``); and the
    urn mass ``sum(q v)`` and ``sum(q)`` in numpy's order."""
    N = q.shape[0]
    logs = logs.copy()
    logs[zero] = -np.inf
    L = ti.shape[0]
    keep = np.zeros(L, dtype=np.bool_)
    lf = np.empty(L)
    ptr = np.zeros(M + 1, dtype=np.int64)
    for k in range(L):
        l = ti[k]
        lf[k] = (((logs[l] + logs[N + l]) - logs[2 * N + l]) + logs[3 * N + l]) + log_lik[k]
        if np.isfinite(lf[k]):
            keep[k] = True
            ptr[mi[k] + 1] += 1
    for m in range(M):
        ptr[m + 1] += ptr[m]
    qv = np.empty(N)
    for l in range(N):
        qv[l] = q[l] * pop[l]
    return ptr, ti[keep], lf[keep], log_lik[keep], np_sum(qv, np.int64(0), N), np_sum(q, np.int64(0), N)


# -- the existing clusters' update (tracker.bnp.filter, tracker.bnp.assignment) -----------------

def npmax(a, b):  # pragma: no cover - compiled
    """``np.maximum`` of two floats: nan if either is."""
    return a if a >= b or a != a else b


def clip01(x):  # pragma: no cover - compiled
    """``np.clip(x, 0.0, 1.0)`` of a float (nan stays nan)."""
    if x < 0.0:
        return 0.0
    return 1.0 if x > 1.0 else x


def existence_update(ptr, idx, p_pairs, N, pd, q, pop, rho, eps):  # pragma: no cover - compiled
    """The start of ``BnpTracker._update_existing``: the sampler's pairs sorted by cluster then
    measurement (``ti``, ``mi``, ``p``), each cluster's detection probability (``bincount``,
    clipped), the missed-detection weight ``w_miss``, the existence ``r`` and the decayed
    popularity."""
    M = ptr.shape[0] - 1
    nnz = idx.shape[0]
    first = np.zeros(N + 1, dtype=np.int64)
    for j in range(nnz):
        first[idx[j] + 1] += 1
    for l in range(N):
        first[l + 1] += first[l]
    ti, mi, p = np.empty(nnz, dtype=np.int64), np.empty(nnz, dtype=np.int64), np.empty(nnz)
    for m in range(M):
        for j in range(ptr[m], ptr[m + 1]):
            k = first[idx[j]]
            ti[k], mi[k], p[k] = idx[j], m, p_pairs[j]
            first[idx[j]] += 1
    p_det = np.zeros(N)
    for k in range(nnz):
        p_det[ti[k]] += p[k]
    w_miss, r, pop_new = np.empty(N), np.empty(N), np.empty(N)
    for l in range(N):
        p_det[l] = clip01(p_det[l])
        miss_alive = q[l] * (1.0 - pd[l])
        eps_alive = miss_alive / npmax(miss_alive + 1.0 - q[l], eps)
        w_miss[l] = (1.0 - p_det[l]) * eps_alive
        r[l] = clip01(p_det[l] + w_miss[l])
        n_expected = p_det[l] / npmax(r[l], eps)
        pop_new[l] = npmax(rho * pop[l] + (1.0 - rho) * n_expected, 1.0)
    return ti, mi, p, w_miss, r, pop_new


def jpda_select(n, ti, mi, p, small_limit):  # pragma: no cover - compiled
    """The start of :func:`tracker.bnp.assignment.best_permutation_pairs`: the live pairs
    (``p > 0`` of a cluster whose summed ``p`` is above 1e-9), each live cluster (ascending)
    with its most likely measurement (the lowest on a tie) and summed ``p``; whether two
    clusters prefer one measurement; whether the assignment is small (clusters x
    measurements <= ``small_limit``: one block); and the arguments of its ``log``
    (``[p of the live pairs, max(1 - p_det, 1e-300) per live cluster]``)."""
    p_det = np.zeros(n)
    for k in range(ti.shape[0]):
        p_det[ti[k]] += p[k]
    best_p = np.full(n, -1.0)
    best_m = np.zeros(n, dtype=np.int64)
    keep = np.zeros(ti.shape[0], dtype=np.bool_)
    m_max = -1
    for k in range(ti.shape[0]):
        t = ti[k]
        if p[k] > 0.0 and p_det[t] > 1e-9:
            keep[k] = True
            m_max = max(m_max, mi[k])
            if p[k] > best_p[t] or (p[k] == best_p[t] and mi[k] < best_m[t]):
                best_p[t], best_m[t] = p[k], mi[k]
    lt, lm, lp = ti[keep], mi[keep], p[keep]
    clusters = np.flatnonzero(best_p >= 0.0)
    choice = best_m[clusters]
    seen = np.zeros(m_max + 1, dtype=np.bool_)
    conflict = False
    for c in choice:
        conflict = conflict or seen[c]
        seen[c] = True
    args = np.empty(lp.shape[0] + clusters.shape[0])
    for i in range(lp.shape[0]):  # not args[:n] = lp: a slice assignment compiles numba's string code
        args[i] = lp[i]
    for i in range(clusters.shape[0]):
        args[lp.shape[0] + i] = npmax(1.0 - p_det[clusters[i]], 1e-300)
    small = clusters.shape[0] * (m_max + 1) <= small_limit
    return clusters, choice, p_det, lt, lm, lp, conflict, small, args


def jpda_solve(logs, clusters, choice, lt, lm, forbidden):  # pragma: no cover - compiled
    """The JPDA* assignment of every live cluster in one block (``assignment._solve_block``):
    cost ``min(-log p, forbidden)`` per live pair, ``-log(1 - p_det)`` on each cluster's
    private "missed" column; a cluster the optimum leaves missed keeps ``choice``.  ``logs``:
    numpy's ``log`` of :func:`jpda_select`'s ``args``.  Returns the new ``choice``."""
    L = clusters.shape[0]
    cols = np.unique(lm)
    C = cols.shape[0]
    cost = np.full((L, C + L), forbidden)
    for k in range(lt.shape[0]):
        row = np.searchsorted(clusters, lt[k])
        col = np.searchsorted(cols, lm[k])
        cost[row, col] = min(-logs[k], forbidden)
    for i in range(L):
        cost[i, C + i] = -logs[lt.shape[0] + i]
    out = choice.copy()
    col4row = lsap(cost)
    for i in range(L):
        if col4row[i] < C:
            out[i] = cols[col4row[i]]
    return out


def moment_match(w_miss, r, ti, p, m_pred, P_pred, mu, P_upd, eps):  # pragma: no cover - compiled
    """``filter._moment_match`` in the numpy code's order: each cluster's Gaussian over
    "missed" (weight ``w_miss / r``) and its pairs ``ti`` (weight ``p / r``, updated means
    ``mu``, covariance ``P_upd``; ``np.add.at`` in pair order), then symmetrised."""
    N, d = m_pred.shape
    inv_r = np.empty(N)
    mean = np.empty((N, d))
    for l in range(N):
        inv_r[l] = 1.0 / npmax(r[l], eps)
        w0 = w_miss[l] * inv_r[l]
        for a in range(d):
            mean[l, a] = w0 * m_pred[l, a]
    L = ti.shape[0]
    wp = np.empty(L)
    for k in range(L):
        wp[k] = p[k] * inv_r[ti[k]]
        for a in range(d):
            mean[ti[k], a] += wp[k] * mu[k, a]
    cov = np.empty((N, d, d))
    dev = np.empty(d)
    w_det = np.zeros(N)
    for k in range(L):
        w_det[ti[k]] += wp[k]
    for l in range(N):
        w0 = w_miss[l] * inv_r[l]
        for a in range(d):
            dev[a] = m_pred[l, a] - mean[l, a]
        for a in range(d):
            for b in range(d):
                cov[l, a, b] = w0 * (P_pred[l, a, b] + dev[a] * dev[b]) + w_det[l] * P_upd[l, a, b]
    for k in range(L):
        l = ti[k]
        for a in range(d):
            dev[a] = mu[k, a] - mean[l, a]
        for a in range(d):
            for b in range(d):
                cov[l, a, b] += wp[k] * dev[a] * dev[b]
    out = np.empty((N, d, d))
    for l in range(N):
        for a in range(d):
            for b in range(d):
                out[l, a, b] = 0.5 * (cov[l, a, b] + cov[l, b, a])
    return mean, out


# -- births (tracker.bnp.base_measure) and the cardinality pmf (tracker.cardinality) ------------

def birth_moments(w, mu_b, P_upd, pos, pcov, var_v, var_turn):  # pragma: no cover - compiled
    """``BaseDistribution.posterior``'s moment match of each measurement's mixture: components
    ``b < B`` (updated means ``mu_b[b, m]``, covariance ``P_upd[b]``) and the uniform part (last
    row of ``w``: position ``pos[m]`` with covariance ``pcov[m]``, velocity variance ``var_v``
    per axis, turn-rate variance ``var_turn``), with weights ``w (B + 1, M)`` summed over ``b``
    in order as ``np.einsum`` does; ``w`` with no rows: the uniform part alone."""
    B, M = mu_b.shape[0], pos.shape[0]
    mean_u = np.zeros((M, 5))
    cov_u = np.zeros((M, 5, 5))
    for m in range(M):
        mean_u[m, 0], mean_u[m, 2] = pos[m, 0], pos[m, 1]
        cov_u[m, 0, 0], cov_u[m, 0, 2] = pcov[m, 0, 0], pcov[m, 0, 1]
        cov_u[m, 2, 0], cov_u[m, 2, 2] = pcov[m, 1, 0], pcov[m, 1, 1]
        cov_u[m, 1, 1] = var_v
        cov_u[m, 3, 3] = var_v
        cov_u[m, 4, 4] = var_turn
    if w.shape[0] == 0:
        return mean_u, cov_u
    mean = np.zeros((M, 5))
    for b in range(B + 1):
        for m in range(M):
            for i in range(5):
                mean[m, i] += w[b, m] * (mu_b[b, m, i] if b < B else mean_u[m, i])
    cov_w = np.zeros((M, 5, 5))
    cov_d = np.zeros((M, 5, 5))
    dev = np.empty(5)
    for b in range(B + 1):
        for m in range(M):
            for i in range(5):
                dev[i] = (mu_b[b, m, i] if b < B else mean_u[m, i]) - mean[m, i]
            for i in range(5):
                for j in range(5):
                    cov_w[m, i, j] += w[b, m] * (P_upd[b, i, j] if b < B else cov_u[m, i, j])
                    cov_d[m, i, j] += w[b, m] * dev[i] * dev[j]
    out = np.empty((M, 5, 5))
    for m in range(M):
        for i in range(5):
            for j in range(5):
                out[m, i, j] = 0.5 * ((cov_w[m, i, j] + cov_d[m, i, j]) + (cov_w[m, j, i] + cov_d[m, j, i]))
    return mean, out


def cardinality_pmf(r, tail):  # pragma: no cover - compiled
    """``truncate_tail(poisson_binomial(r), tail)`` of :mod:`tracker.cardinality`, the same
    arithmetic (the recursion in the linear domain, the sure objects counted; the upper tails
    summed from the end).  ``ok`` is False when an ``r`` is not finite (no pmf then)."""
    n_sure, n_mid = 0, 0
    mid = np.empty(r.shape[0])
    for i in range(r.shape[0]):
        x = clip01(r[i])
        if not np.isfinite(x):
            return np.zeros(0), False
        if x >= 1.0:
            n_sure += 1
        elif x > 0.0:
            mid[n_mid] = x
            n_mid += 1
    p = np.zeros(n_sure + n_mid + 1)
    q = p[n_sure:]
    q[0] = 1.0
    for i in range(n_mid):
        ri = mid[i]
        for j in range(i + 1, 0, -1):
            q[j] = (1.0 - ri) * q[j] + ri * q[j - 1]
        q[0] *= 1.0 - ri
    if p.shape[0] <= 1:
        return p, True
    keep, acc = 1, 0.0
    for n in range(p.shape[0] - 1, 0, -1):  # acc = sum(p[n:]), the tail beyond n - 1
        acc += p[n]
        if acc >= tail:
            keep = n + 1
            break
    return p[:keep].copy(), True


# -- the estimate's assignments (tracker.bnp.filter) ---------------------------------------------

def estimate_assignments(ptr, idx, p_pairs, rep, p_new, born_m):  # pragma: no cover - compiled
    """Each measurement's reported assignment: its most probable reported transitioned cluster
    (the lowest index on a tie) or its own reported newborn (``born_m``: the measurements whose
    newborn is reported; the transitioned cluster wins a tie), unless "none of the reported"
    (``1 - `` their summed probability, clipped) is at least as probable.  Returns per
    measurement the choice (cluster index, -2 its newborn, -1 none) and its probability."""
    M = ptr.shape[0] - 1
    choice = np.full(M, -1, dtype=np.int64)
    prob = np.empty(M)
    born_p = np.zeros(M)
    for m in born_m:
        born_p[m] = p_new[m]
    for m in range(M):
        p_sum, p_ex, t_ex = 0.0, 0.0, -1
        for j in range(ptr[m], ptr[m + 1]):
            if rep[idx[j]]:
                p_sum += p_pairs[j]
                if t_ex < 0 or p_pairs[j] > p_ex:
                    p_ex, t_ex = p_pairs[j], idx[j]
        use_born = born_p[m] > p_ex
        p_best = born_p[m] if use_born else p_ex
        p_none = clip01(1.0 - (p_sum + born_p[m]))
        if p_best <= p_none:
            prob[m] = p_none
        else:
            choice[m] = -2 if use_born else t_ex
            prob[m] = p_best
    return choice, prob


_pairwise_block = jit(_pairwise_block)
np_sum = jit(np_sum)
divide = jit(divide, inline=True)
cholesky_distance = jit(cholesky_distance)
merge_candidates = jit(merge_candidates)
merge_groups = jit(merge_groups)
merge_moments = jit(merge_moments)
merge_pass = jit(merge_pass)
npmax = jit(npmax, inline=True)
clip01 = jit(clip01, inline=True)
existence_update = jit(existence_update)
jpda_select = jit(jpda_select)
jpda_solve = jit(jpda_solve)
moment_match = jit(moment_match)
birth_moments = jit(birth_moments)
cardinality_pmf = jit(cardinality_pmf)
estimate_assignments = jit(estimate_assignments)
problem_log_args = jit(problem_log_args)
problem_pairs = jit(problem_pairs)
