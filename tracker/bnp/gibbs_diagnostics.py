"""The assignment sampler's diagnostics (:func:`tracker.bnp.gibbs.run_gibbs`): the split-chain
R-hat of the assignment probabilities (:func:`split_rhat`) and the unnormalised log posterior of
an assignment vector (:func:`log_joint`), with the compiled forms the sampler's driver calls
(the same sums in numpy's order)."""

from __future__ import annotations

import math

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp._kernels import np_sum
from bnptrack.tracker.bnp.gibbs_problem import GibbsProblem
from bnptrack.tracker.bnp.gibbs_setup import _npmax
from bnptrack.tracker.bnp.swap_moves import CLUTTER, NEW


def split_rhat(hs: np.ndarray, hss: np.ndarray, n: int) -> float:
    r"""Largest split-chain :math:`\hat R` (Gelman et al., BDA3 eq. 11.4) over every
    Rao-Blackwellised assignment probability, from the half-chains' sums ``hs`` and sums of
    squares ``hss`` (``(2 * chains, K)``, ``n`` sweeps each).

    :math:`W` is the mean within-half-chain variance, :math:`B/n` the variance of the
    half-chain means, :math:`\hat R = \sqrt{((n-1)/n\, W + B/n) / W}`.  Quantities whose
    pooled standard deviation is below 1e-3 count as converged (R-hat 1), e.g. a measurement
    no other measurement competes with; a quantity constant within each half-chain but
    different between them (a stuck chain) is capped at 1000.  With one chain a chain stuck
    in one mode for all its sweeps looks converged; two chains from different starts (the
    tracker's default) see it.  Fewer than 2 sweeps per half-chain: 1 (undefined)."""
    if n < 2 or hs.shape[1] == 0:
        return 1.0
    mean = hs / n
    var = np.maximum(hss - n * mean * mean, 0.0) / (n - 1)
    W = var.mean(axis=0)
    dev = mean - mean.mean(axis=0)
    b_over_n = np.einsum("ck,ck->k", dev, dev) / (mean.shape[0] - 1)  # variance of the means
    v_plus = (n - 1) / n * W + b_over_n
    live = v_plus > 1e-6
    if not live.any():
        return 1.0
    r = np.sqrt(v_plus[live] / np.maximum(W[live], 1e-12))
    return float(min(r.max(), 1000.0))


def log_joint(problem: GibbsProblem, c: np.ndarray) -> float:
    r"""Unnormalised log posterior of an assignment vector (point or extended objects).

    The product of the conditional weights in any order (the joint is exchangeable):
    clutter terms, the urn normaliser :math:`\prod_{i<M_o} (\alpha+V)/(\alpha+V+i)`,
    first/subsequent members of transitioned clusters and the new-cluster weights.
    """
    if not problem.extended:
        return _log_joint_point(problem, np.asarray(c))
    out = 0.0
    k_new = 0
    m_obj = 0
    total_mass = problem.alpha + problem.mass
    counts: dict[int, int] = {}
    for m, ch in enumerate(np.asarray(c).tolist()):
        if ch == CLUTTER:
            out += problem.log_clutter[m]
            continue
        if problem.urn_normaliser:
            out += math.log(total_mass / (total_mass + m_obj))
        m_obj += 1
        if ch == NEW:
            out += math.log(problem.alpha + problem.d * (problem.d_bar + k_new)) + problem.log_new[m]
            k_new += 1
        else:
            n = counts.get(ch, 0)
            j = problem.pairs.lookup(m, ch)
            if j < 0:
                return -math.inf  # gated out
            if n == 0:
                out += problem.pairs.log_first[j]
            elif problem.extended:
                out += math.log(n + problem.popularity[ch] - problem.d) + problem.pairs.log_lik[j]
            else:
                return -math.inf
            counts[ch] = n + 1
    return out


def _log_joint_point(problem: GibbsProblem, c: np.ndarray) -> float:
    """:func:`log_joint` for point objects (each cluster at most once), vectorised."""
    obj = c != CLUTTER
    new = c == NEW
    cl = np.flatnonzero(c >= 0)
    if np.unique(c[cl]).size < cl.size:
        return -math.inf
    pr = problem.pairs
    N = max(pr.n_clusters, 1)
    key = pr.rows * N + pr.idx  # sorted: CSR by measurement, clusters ascending
    want = cl * N + c[cl]
    j = np.searchsorted(key, want)
    if cl.size and (np.any(j >= key.size) or np.any(key[np.minimum(j, key.size - 1)] != want)):
        return -math.inf  # gated out
    total_mass = problem.alpha + problem.mass
    n_obj, n_new = int(obj.sum()), int(new.sum())
    urn = np.log(total_mass / (total_mass + np.arange(n_obj))).sum() if problem.urn_normaliser else 0.0
    newk = np.log(problem.alpha + problem.d * (problem.d_bar + np.arange(n_new))).sum()
    return float(problem.log_clutter[~obj].sum() + urn + newk + problem.log_new[new].sum()
                 + pr.log_first[j].sum())


def _log_joint_kernel(c, ptr, idx, log_first, log_clutter, log_new, log_lg, urn, N):
    """:func:`_log_joint_point` (sums in numpy's order; ``log_lg`` the logs of
    :func:`_setup_kernel`'s ``lg``)."""
    M = c.shape[0]
    used = np.zeros(N, dtype=np.bool_)
    buf_cl, buf_new, buf_first = np.empty(M), np.empty(M), np.empty(M)
    n_cl, n_new, n_cluster = np.int64(0), np.int64(0), np.int64(0)  # literal 0s compile np_sum for Literal[int](0)
    for m in range(M):
        ch = c[m]
        if ch == CLUTTER:
            buf_cl[n_cl] = log_clutter[m]
            n_cl += 1
        elif ch == NEW:
            buf_new[n_new] = log_new[m]
            n_new += 1
        elif ch >= 0:
            if ch >= N or used[ch]:
                return -np.inf
            used[ch] = True
            pos = -1
            for j in range(ptr[m], ptr[m + 1]):
                if idx[j] == ch:
                    pos = j
            if pos < 0:
                return -np.inf  # gated out
            buf_first[n_cluster] = log_first[pos]
            n_cluster += 1
    n_obj = M - n_cl
    lo = np.int64(0)
    urn_term = np_sum(log_lg, lo, n_obj) if urn else 0.0
    return (((np_sum(buf_cl, lo, n_cl) + urn_term) + np_sum(log_lg, M, n_new)) + np_sum(buf_new, lo, n_new)
            + np_sum(buf_first, lo, n_cluster))


def _split_rhat_kernel(hs, hss, n):
    """:func:`split_rhat` in numpy's order (row-by-row means, sequential ``einsum``)."""
    C, K = hs.shape
    if n < 2 or K == 0:
        return 1.0
    mean = hs / n
    var = np.empty((C, K))
    for c in range(C):
        for k in range(K):
            var[c, k] = _npmax(hss[c, k] - n * mean[c, k] * mean[c, k], 0.0) / (n - 1)
    top, live = -np.inf, False
    for k in range(K):
        w, mm = 0.0, 0.0
        for c in range(C):
            w += var[c, k]
            mm += mean[c, k]
        w, mm = w / C, mm / C
        b = 0.0
        for c in range(C):
            dev = mean[c, k] - mm
            b += dev * dev
        v_plus = (n - 1) / n * w + b / (C - 1)
        if v_plus > 1e-6:
            live = True
            r = np.sqrt(v_plus / _npmax(w, 1e-12))
            top = _npmax(top, r)
    if not live:
        return 1.0
    return 1000.0 if 1000.0 < top else top


_log_joint_kernel = jit(_log_joint_kernel, kernels_only=True)
_split_rhat_kernel = jit(_split_rhat_kernel, kernels_only=True)
