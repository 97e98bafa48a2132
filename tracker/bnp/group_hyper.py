r"""The object partition's :math:`(\alpha_2, d)` likelihood from the objects' arrivals (two-level tracker).

Eq. (condd) of the paper: given the previous frame, the object partition of frame :math:`k` is
marginally :math:`\mathrm{PYP}(d, \alpha, H_1)`.  Its exchangeable partition probability, built
one object at a time (the Pitman-Yor Chinese restaurant, the :math:`d`-form of cases P1-P3), is

.. math::
    \Pr(\ell \to \text{table } c) = \frac{n_c - d}{\alpha + n}, \qquad
    \Pr(\ell \to \text{new table}) = \frac{\alpha + d K}{\alpha + n}

with :math:`n_c` the objects already at table :math:`c`, :math:`n` all objects seated before
:math:`\ell` and :math:`K` the occupied tables.  :func:`arrivals_loglik_grid` counts each object
**once**, at the frame it enters the partition (its existence first reaches
``member_existence``), seated after the objects already there.  Over a stream the product is the
partition's Pitman-Yor EPPF :math:`\prod_{k<K}(\alpha + k d)\,/\,(\alpha+1)^{\overline{n-1}}
\prod_c (1-d)^{\overline{n_c-1}}` (for objects that stay).  Re-counting every frame's re-seating
(``hyper_likelihood = "reseat"``, :func:`tracker.bnp.urn.frame_loglik_grid`) multiplies in a
factor :math:`(v^*_c + i - d)` for each of ~50 re-seats of every object, each falling with
:math:`d`, and drives :math:`d` to 0 whatever the group sizes.
"""

from __future__ import annotations

import numpy as np


def arrivals_loglik_grid(alpha: np.ndarray, d: np.ndarray, z: np.ndarray, arrived: np.ndarray) -> np.ndarray:
    """Log Pitman-Yor predictive of this frame's arrivals on the ``(alpha, d)`` grid (broadcast shapes).

    ``z`` (L,): every member's table this frame; ``arrived`` (L,) bool: members that entered the
    partition this frame (seated in index order, after the others)."""
    alpha = np.asarray(alpha, dtype=float)
    d = np.asarray(d, dtype=float)
    out = np.zeros(np.broadcast_shapes(alpha.shape, d.shape))
    tables, counts = np.unique(z[~arrived], return_counts=True)
    seated = dict(zip(tables.tolist(), counts.tolist()))
    n = int(counts.sum())
    for t in z[arrived].tolist():
        c = seated.get(t, 0)
        out = out + np.log(c - d if c > 0 else alpha + d * len(seated)) - np.log(alpha + n)
        seated[t] = c + 1
        n += 1
    return out


# -- the whole history of the object partition (hyper_likelihood = "history") ----------------
def log_rising_grid(x: np.ndarray, n: np.ndarray | float) -> np.ndarray:
    r""":math:`\log x^{\overline n} = \log\Gamma(x+n) - \log\Gamma(x)` (``x > 0``, ``n >= 0``)."""
    from bnptrack.tracker._numerics import gammaln  # as tracker.bnp.urn

    return gammaln(x + n) - gammaln(x)


def size_factor(d: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    r""":math:`\sum_j \log (1-d)^{\overline{n_j-1}}` on the ``d`` grid (``d`` (D,), ``sizes`` (K,) >= 1)."""
    sizes = np.asarray(sizes, dtype=float)
    d = np.asarray(d, dtype=float)
    if sizes.size == 0:
        return np.zeros_like(d)
    return log_rising_grid(1.0 - d[:, None], sizes[None, :] - 1.0).sum(axis=1)


def eppf_grid(alpha: np.ndarray, d: np.ndarray, K: int, n: int, factor: np.ndarray) -> np.ndarray:
    r"""The Pitman-Yor EPPF of a partition of ``n`` objects into ``K`` clusters on the grid:

    .. math::
        \log p = \sum_{k=1}^{K-1} \log(\alpha + k d) - \log (\alpha+1)^{\overline{n-1}}
                 + \sum_j \log (1-d)^{\overline{n_j - 1}}

    (Pitman 1995; the joint of cases P1 and P3, eqs. (17), (19) [eq1, eq3], with no
    transitioned clusters), with ``factor`` (D,) the last sum (:func:`size_factor`);
    :math:`\prod_{k=1}^{K-1}(\alpha + k d) = d^{K-1}\,\Gamma(\alpha/d + K) / \Gamma(\alpha/d + 1)`
    for :math:`d > 0`, :math:`\alpha^{K-1}` at :math:`d = 0`.  ``alpha`` (A, 1), ``d`` (1, D)."""
    alpha = np.asarray(alpha, dtype=float)
    d = np.asarray(d, dtype=float)
    if K == 0:
        return np.zeros(np.broadcast_shapes(alpha.shape, d.shape))
    pos = d > 0
    safe = np.where(pos, d, 1.0)
    ratio = alpha / safe
    tables = np.where(pos, (K - 1) * np.log(safe) + log_rising_grid(ratio + 1.0, K - 1.0), (K - 1) * np.log(alpha))
    return tables - log_rising_grid(alpha + 1.0, n - 1.0) + np.reshape(factor, d.shape)


def update_history(counted: np.ndarray, members: np.ndarray, member_ids: np.ndarray,
                   totals: dict[int, int]) -> np.ndarray:
    """Move each member's count to its cluster this frame (in place on ``totals``: cluster id ->
    objects ever counted in it).  ``counted`` (N,): the cluster each object's count sits in (-1:
    never counted); returns the updated copy.  An object counted in a cluster that has since
    died (not in ``totals``) is counted again: its old count stays with the dead cluster."""
    counted = counted.copy()
    for i, c in zip(members.tolist(), member_ids.tolist()):
        old = int(counted[i])
        if old == c:
            continue
        if old in totals:
            totals[old] -= 1
        totals[c] = totals.get(c, 0) + 1
        counted[i] = c
    return counted
