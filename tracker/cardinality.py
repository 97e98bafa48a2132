r"""The posterior cardinality distribution every tracker puts in its estimate.

``Estimate.cardinality_pmf`` is the vector :math:`p(n) = \Pr(|X| = n)`, ``n = 0 .. N_max``:

* **DDP-EMM / DPY-STP (and the two-level trackers)**: the state is a multi-Bernoulli of
  independent objects, each present with its existence :math:`r_i`.  The number present is
  then Poisson-binomial: :math:`p = \ast_i\,[1 - r_i,\ r_i]` (the convolution over *all*
  hypothesised objects of the state, reported or not: the reporting threshold is a choice of
  the estimator, the cardinality is the posterior's).  :func:`poisson_binomial`.
* **GLMB**: its exact cardinality distribution,
  :math:`\rho(n) = \sum_{I:\,|I| = n} w^{(I)}` (the cardinality of a GLMB, Vo & Vo 2013),
  from the hypothesis weights: ``GlmbState.cardinality`` (:mod:`tracker.glmb.state`).

Both are truncated by :func:`truncate_tail`: the entries past the last ``n`` whose upper tail
:math:`\sum_{n' > n} p(n')` is at least ``TAIL`` (1e-9) are dropped, so the vector stays short
(hundreds of unlikely hypothesised objects add no entries) and sums to 1 within 1e-9; the kept
entries are exact (not renormalised).
"""

from __future__ import annotations

import numpy as np

__all__ = ["TAIL", "poisson_binomial", "truncate_tail", "existence_cardinality", "pmf_mean",
           "pmf_map"]

#: Upper tail mass below which the trailing entries of a cardinality pmf are dropped.
TAIL = 1e-9


def poisson_binomial(r: np.ndarray) -> np.ndarray:
    r"""Exact pmf of the number of successes of independent Bernoullis with probabilities ``r``.

    The standard :math:`O(N^2)` recursion in the linear domain: adding object :math:`i` maps
    :math:`p_{i}(n) = (1 - r_i)\,p_{i-1}(n) + r_i\,p_{i-1}(n - 1)`, a convex combination of
    non-negative numbers (no cancellation: stable; entries that underflow are below any tail
    that matters).  Objects with :math:`r_i = 1` only shift the pmf and :math:`r_i = 0` leave it
    unchanged, so they are counted, not convolved.  Returns ``(N + 1,)`` before truncation.
    """
    r = np.clip(np.asarray(r, dtype=float).ravel(), 0.0, 1.0)
    if not np.isfinite(r).all():
        raise ValueError("poisson_binomial: existence probabilities must be finite")
    n_sure = int(np.sum(r >= 1.0))
    mid = r[(r > 0.0) & (r < 1.0)]
    p = np.zeros(mid.size + 1)
    p[0] = 1.0
    for i, ri in enumerate(mid.tolist()):
        p[1:i + 2] = (1.0 - ri) * p[1:i + 2] + ri * p[0:i + 1]
        p[0] *= 1.0 - ri
    return np.concatenate([np.zeros(n_sure), p])


def truncate_tail(p: np.ndarray, tail: float = TAIL) -> np.ndarray:
    """``p[: n + 1]`` for the smallest ``n`` whose upper tail ``sum(p[n + 1:])`` is below
    ``tail`` (at least one entry is kept)."""
    p = np.asarray(p, dtype=float).ravel()
    if p.size <= 1:
        return p.copy()
    upper = np.cumsum(p[::-1])[::-1]  # upper[n] = sum(p[n:])
    over = np.flatnonzero(upper[1:] >= tail)  # tails sum(p[n + 1:]) that are kept
    return p[: (int(over[-1]) + 2 if over.size else 1)].copy()


def existence_cardinality(existence: np.ndarray) -> np.ndarray:
    """The truncated Poisson-binomial of a multi-Bernoulli's existences (what the BNP trackers
    report)."""
    return truncate_tail(poisson_binomial(existence))


def pmf_mean(p: np.ndarray) -> float:
    """Mean of a cardinality pmf."""
    p = np.asarray(p, dtype=float)
    return float(np.dot(np.arange(p.size), p))


def pmf_map(p: np.ndarray) -> int:
    """MAP (most probable) cardinality of a pmf (the smallest on a tie)."""
    return int(np.argmax(np.asarray(p, dtype=float)))
