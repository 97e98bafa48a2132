"""The reference kernel of the object -> cluster Gibbs (``kernel = "scan"`` of
:func:`tracker.bnp.group_sample.sample_partition`): every table scored at every move, the last
sweep's conditionals kept dense and collected after (:func:`_collect_shares`).  The gated kernel
(:mod:`tracker.bnp.group_partition`) draws the same sample bit for bit."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp.group_fma import dot2, gemv2
from bnptrack.tracker.bnp.group_partition import _inv_into, _move


def _option_logw(n, v_star, alpha, d, logw, occupied=False) -> None:
    """Urn weights (:func:`tracker.bnp.group_sample.urn_log_weights`) of every table; the first
    empty table stands for "new"."""
    K = 0
    for t in range(n.size):
        if occupied:
            K += 1 if n[t] > 0 else 0
        else:
            K += 1 if n[t] + v_star[t] > 0 else 0
    free = -1
    for t in range(n.size):
        load = n[t] + v_star[t]
        if load > 0:
            logw[t] = np.log(v_star[t]) if occupied and n[t] == 0 else np.log(load - d)
        elif free < 0:
            free = t
            logw[t] = np.log(alpha + d * K)
        else:
            logw[t] = -np.inf


def _draw(logw, w, u) -> int:
    """The option of uniform ``u`` given log weights ``logw`` (T,); ``w`` (T,) receives the
    normalised weights.  The numbers of ``w = exp(logw - max); w /= w.sum()`` and of
    ``min(searchsorted(cumsum(w), u, "right"), T - 1)``, in loops without temporaries
    (``sum`` and ``cumsum`` add in index order from the first entry)."""
    T = logw.size
    top = logw[0]
    for t in range(1, T):
        if logw[t] > top:
            top = logw[t]
    total = 0.0
    for t in range(T):
        w[t] = np.exp(logw[t] - top)
        total += w[t]
    for t in range(T):
        w[t] = w[t] / total
    acc = 0.0
    for t in range(T):
        acc += w[t]
        if acc > u:
            return t
    return T - 1


def _partition_kernel(sw, urn, rec_p, rec_mu, rec_cov) -> None:
    """Collapsed Gibbs sweeps over ``sw.z`` in place (numba-compiled when available); ``urn``: the
    urn's parameters and reading (:class:`~tracker.bnp.group_bundles.Urn`,
    :func:`tracker.bnp.group_sample.urn_log_weights`).

    ``sw`` (:class:`~tracker.bnp.group_bundles.Sweeps`): ``v`` (P, L, 2), ``R`` (P, L, 2, 2), the
    members' parts; ``lam0``/``eta0`` (P, T, 2, 2)/(P, T, 2): the tables' priors; ``u`` (S, L)
    uniforms.  The last sweep's conditionals go to ``rec_p`` (L, T); part 0's theta given the
    table's *other current members* and H_2 (``sw.h_lam``, ``sw.h_eta``: information form), not
    the transitioned prior, which carries object l's own past, goes to ``rec_mu`` (L, T, 2),
    ``rec_cov`` (L, T, 2, 2).
    """
    v, R, lam0, eta0, h_lam, h_eta, v_star, z, u = sw
    alpha, d, occupied = urn
    P, L, T = v.shape[0], v.shape[1], lam0.shape[1]
    n = np.zeros(T)
    lam, eta = lam0.copy(), eta0.copy()
    Ri = np.empty((P, L, 2, 2))
    Riv = np.empty((P, L, 2))
    for p in range(P):
        for l in range(L):
            _inv_into(R[p, l], Ri[p, l])
            gemv2(Ri[p, l], v[p, l], Riv[p, l])  # = Ri @ v (BLAS's rounding: group_fma)
    for l in range(L):
        _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, 1.0)
    logw = np.empty(T)
    cov = np.empty((2, 2))
    Si = np.empty((2, 2))
    # each table's theta posterior (cov, mu) per part, recomputed only when its members change:
    # the same operations on the same values as computing it for every object
    t_cov = np.empty((P, T, 2, 2))
    t_mu = np.empty((P, T, 2))
    fresh = np.zeros(T, dtype=np.bool_)
    A = np.empty((2, 2))
    r = np.empty(2)
    Sir = np.empty(2)
    B = np.empty((2, 2))
    e = np.empty(2)
    w = np.empty(T)
    S = u.shape[0]
    for s in range(S):
        for l in range(L):
            _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, -1.0)
            fresh[z[l]] = False
            _option_logw(n, v_star, alpha, d, logw, occupied)
            for t in range(T):
                if logw[t] == -np.inf:
                    continue
                if not fresh[t]:
                    for p in range(P):
                        _inv_into(lam[p, t], cov)
                        gemv2(cov, eta[p, t], t_mu[p, t])  # = cov @ eta, into place
                        t_cov[p, t] = cov
                    fresh[t] = True
                for p in range(P):
                    for i in range(2):  # t_cov + R and v - mu, into buffers
                        r[i] = v[p, l, i] - t_mu[p, t, i]
                        for j in range(2):
                            A[i, j] = t_cov[p, t, i, j] + R[p, l, i, j]
                    det = _inv_into(A, Si)
                    gemv2(Si, r, Sir)  # = Si @ r, into a buffer
                    logw[t] += -0.5 * dot2(r, Sir) - 0.5 * np.log(det) - np.log(2.0 * np.pi)
                    if p == 0 and s == S - 1:
                        for i in range(2):  # lam - lam0 + h_lam, eta - eta0 + h_eta entry by entry
                            e[i] = eta[0, t, i] - eta0[0, t, i] + h_eta[i]
                            for j in range(2):
                                B[i, j] = lam[0, t, i, j] - lam0[0, t, i, j] + h_lam[i, j]
                        _inv_into(B, rec_cov[l, t])
                        gemv2(rec_cov[l, t], e, rec_mu[l, t])
            k = _draw(logw, w, u[s, l])
            while w[k] == 0.0:  # never land on an impossible table through round-off
                k -= 1
            z[l] = k
            if s == S - 1:
                rec_p[l] = w
            _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, 1.0)
            fresh[z[l]] = False


_option_logw = jit(_option_logw)
_draw = jit(_draw)
_partition_kernel = jit(_partition_kernel)


def _collect_shares(rec_p, rec_mu, rec_cov, min_p):  # pragma: no cover - compiled
    """The options with conditional probability above ``min_p`` (row-major, as ``np.nonzero``), their
    weights normalised per object (sums in index order from 0.0, as ``np.bincount``), thetas."""
    L, T = rec_p.shape
    count = 0
    for l in range(L):
        for t in range(T):
            if rec_p[l, t] > min_p:
                count += 1
    obj = np.empty(count, dtype=np.int64)
    w = np.empty(count)
    mu = np.empty((count, 2))
    cov = np.empty((count, 2, 2))
    k = 0
    for l in range(L):
        first, total = k, 0.0
        for t in range(T):
            if rec_p[l, t] > min_p:
                obj[k], w[k], mu[k], cov[k] = l, rec_p[l, t], rec_mu[l, t], rec_cov[l, t]
                total += rec_p[l, t]
                k += 1
        for j in range(first, k):
            w[j] = w[j] / total
    return obj, w, mu, cov


_collect_shares = jit(_collect_shares)
