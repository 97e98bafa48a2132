"""Compiled passes of the estimate (:mod:`tracker.bnp.filter`): the cardinality pmf
(:func:`cardinality_pmf`, :mod:`tracker.cardinality`'s arithmetic) and each measurement's
reported assignment (:func:`estimate_assignments`), bit for bit the numpy code's
(:mod:`tracker.bnp._kernels` says how)."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp._kernels import clip01


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


cardinality_pmf = jit(cardinality_pmf)
estimate_assignments = jit(estimate_assignments)
