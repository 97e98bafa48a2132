"""Compiled passes of the frame's update in :mod:`tracker.bnp.filter` and
:mod:`tracker.bnp.assignment`: the sampler's inputs (:func:`problem_log_args`,
:func:`problem_pairs`), the existing clusters' existence (:func:`existence_update`) and moments
(:func:`moment_match`, :func:`moment_match_combined`), and the JPDA* choice (:func:`jpda_select`, :func:`jpda_solve`), bit for
bit the numpy code's (:mod:`tracker.bnp._kernels` says how)."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker._lsap import lsap
from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp._kernels import clip01, np_sum, npmax


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


def moment_match_combined(w_miss, r, ti, p, m_pred, P_pred, mu, P_upd, eps):  # pragma: no cover - compiled
    """:func:`moment_match` with the detection branch as one component (``state_update =
    "combined"``): its mean the probability-weighted mean of the updated means ``mu`` (the
    combined innovation), its covariance ``P_upd``; the spread of the updated means about it
    is left out.  The spread between "missed" and that component stays."""
    N, d = m_pred.shape
    inv_r = np.empty(N)
    mean = np.empty((N, d))
    det = np.zeros((N, d))
    w_det = np.zeros(N)
    for l in range(N):
        inv_r[l] = 1.0 / npmax(r[l], eps)
        w0 = w_miss[l] * inv_r[l]
        for a in range(d):
            mean[l, a] = w0 * m_pred[l, a]
    for k in range(ti.shape[0]):
        wp = p[k] * inv_r[ti[k]]
        w_det[ti[k]] += wp
        for a in range(d):
            mean[ti[k], a] += wp * mu[k, a]
            det[ti[k], a] += wp * mu[k, a]
    out = np.empty((N, d, d))
    dev0, dev1 = np.empty(d), np.empty(d)
    for l in range(N):
        w0 = w_miss[l] * inv_r[l]
        for a in range(d):
            dev0[a] = m_pred[l, a] - mean[l, a]
            dev1[a] = det[l, a] / w_det[l] - mean[l, a] if w_det[l] > 0.0 else 0.0
        for a in range(d):
            for b in range(d):
                out[l, a, b] = w0 * (P_pred[l, a, b] + dev0[a] * dev0[b]) + w_det[l] * (P_upd[l, a, b] + dev1[a] * dev1[b])
        for a in range(d):
            for b in range(a + 1, d):
                out[l, a, b] = out[l, b, a] = 0.5 * (out[l, a, b] + out[l, b, a])
    return mean, out


existence_update = jit(existence_update)
jpda_select = jit(jpda_select)
jpda_solve = jit(jpda_solve)
moment_match = jit(moment_match)
moment_match_combined = jit(moment_match_combined)
problem_log_args = jit(problem_log_args)
problem_pairs = jit(problem_pairs)
