r"""The dependent Polya urn of DDP-EMM / DPY-STP: predictive weights, EPPF, hyperparameters.

Paper mapping (Moraffah & Papandreou-Suppappola, Secs. 4-5):

* A *table* (cluster) is an object; its *customers* are the measurements assigned to it.
* A cluster that transitions from frame :math:`k-1` arrives *pre-seated* with popularity
  :math:`v_l = v^\star_{l,k|k-1}` (eq. (1)-(2); decayed, see ``docs/trackers.md``).
* Predictive weights for the next customer, given current counts :math:`n_l` at frame :math:`k`
  (cases D1-D3, eqs. (1), (3), (5); P1-P3, eqs. (17)-(19)):

  .. math::

      \Pr(\text{table } l) \propto n_l + v_l - d \quad (\text{D1/P1 if } n_l>0,
      \text{ D2/P2 if } n_l = 0), \qquad
      \Pr(\text{new}) \propto \alpha + d\,K

  with :math:`K` the number of occupied tables (pre-seated ones included).  :math:`d = 0`
  gives the DDP-EMM weights exactly.
* The implied exchangeable partition probability function, for a partition of :math:`n`
  customers into pre-seated tables with counts :math:`n_l` and :math:`K_\text{new}` new tables
  with sizes :math:`m_j` (eq. (16), with the factorial the paper's eq. (16) omits):

  .. math::

      p = \frac{\prod_{l} (v_l - d)^{\overline{n_l}}
               \prod_{j=1}^{K_\text{new}} (\alpha + d (D + j - 1)) (1-d)^{\overline{m_j - 1}}}
              {(\alpha + V)^{\overline{n}}},
      \qquad V = \sum_l v_l,\; D = \#\{l\}

  where :math:`x^{\overline{n}} = x (x+1)\cdots(x+n-1)`.  With no pre-seated tables and
  :math:`d=0` this is the CRP EPPF :math:`\alpha^K \prod_j (m_j-1)! / \alpha^{\overline n}`.
"""

from __future__ import annotations


import numpy as np


def log_rising(x: float | np.ndarray, n: int | np.ndarray) -> np.ndarray:
    """:math:`\\log x^{\\overline{n}} = \\log\\Gamma(x+n) - \\log\\Gamma(x)` (``n >= 0``, ``x > 0``)."""
    x = np.asarray(x, dtype=float)
    from bnptrack.tracker.numerics import gammaln  # scipy.special's, without importing it (docs/performance.md)

    return gammaln(x + n) - gammaln(x)


def log_eppf(
    new_sizes: np.ndarray,
    alpha: float,
    d: float = 0.0,
    seated_counts: np.ndarray | None = None,
    popularity: np.ndarray | None = None,
) -> float:
    """Log probability of one labelled partition under the (pre-seated) Pitman-Yor urn.

    ``new_sizes``: sizes of the tables opened by the customers (in any order);
    ``seated_counts``/``popularity``: customers joining each pre-seated table and its
    popularity :math:`v_l`.  See the module docstring for the formula.
    """
    new_sizes = np.asarray(new_sizes, dtype=int)
    v = np.zeros(0) if popularity is None else np.asarray(popularity, dtype=float)
    nl = np.zeros(0, dtype=int) if seated_counts is None else np.asarray(seated_counts, dtype=int)
    n = int(new_sizes.sum() + nl.sum())
    D = v.size
    out = float(np.sum(log_rising(v - d, nl))) if D else 0.0
    j = np.arange(new_sizes.size)
    out += float(np.sum(np.log(alpha + d * (D + j))))
    out += float(np.sum(log_rising(1.0 - d, new_sizes - 1)))
    out -= float(log_rising(alpha + v.sum(), n))
    return out


def sample_crp_partition(
    rng: np.random.Generator, n: int, alpha: float, d: float = 0.0
) -> np.ndarray:
    """Draw table labels ``(n,)`` for ``n`` customers by the sequential Pitman-Yor urn."""
    labels = np.empty(n, dtype=int)
    counts: list[float] = []
    for i in range(n):
        k = len(counts)
        w = np.array([c - d for c in counts] + [alpha + d * k])
        # rng.choice(k + 1, p=w / w.sum()) draw for draw, without its checks of p
        cdf = (w / w.sum()).cumsum()
        cdf /= cdf[-1]
        j = int(cdf.searchsorted(rng.random(), side="right"))
        if j == k:
            counts.append(1.0)
        else:
            counts[j] += 1.0
        labels[i] = j
    return labels


def gibbs_partition_sweep(
    rng: np.random.Generator, labels: np.ndarray, alpha: float, d: float = 0.0
) -> np.ndarray:
    """One collapsed Gibbs sweep over table labels under the PY urn alone (no likelihood).

    The conditional of customer ``i`` is the urn's predictive weight given the others
    (exchangeability): existing table ``n_j^{-i} - d``, new table ``alpha + d K^{-i}``.
    Used to test that the urn weights leave the EPPF invariant.
    """
    labels = labels.copy()
    for i in range(labels.size):
        others = np.delete(labels, i)
        tables, counts = np.unique(others, return_counts=True)
        w = np.append(counts - d, alpha + d * tables.size)
        j = int(rng.choice(w.size, p=w / w.sum()))
        if j < tables.size:
            labels[i] = tables[j]
        else:
            free = np.setdiff1d(np.arange(labels.size + 1), others)
            labels[i] = free[0]
    return labels


# --- hyperparameters -----------------------------------------------------------------------

#: Grid of the concentration alpha (log-spaced) and of the discount d.
ALPHA_GRID = np.geomspace(1e-4, 30.0, 72)
D_GRID = np.linspace(0.0, 0.95, 20)


def frame_loglik_grid(
    alpha: np.ndarray,
    d: np.ndarray,
    *,
    mass: float,
    d_bar: float,
    n_object: float,
    n_new: float,
    seated_popularity: np.ndarray,
    seated_counts: np.ndarray,
    urn_normaliser: bool = True,
) -> np.ndarray:
    r"""Log-likelihood of one frame's sampled partition on an ``(alpha, d)`` grid.

    Object-originated measurements are :math:`\mathrm{Poisson}(\alpha + V)`; given their
    number :math:`M_o` they follow the pre-seated urn (module docstring), so

    .. math::
        \log L(\alpha, d) = -(\alpha + V) + M_o \log(\alpha + V)
            - \log (\alpha + V)^{\overline{M_o}}
            + \sum_{j=0}^{K_\text{new}-1} \log(\alpha + d(\bar D + j))
            + \sum_l \log (v_l - d)^{\overline{n_l}} .

    ``alpha`` and ``d`` broadcast (e.g. ``(A, 1)`` and ``(1, D)``).  ``n_object`` and
    ``n_new`` may be expected (fractional) counts: the last, partial new table enters with
    its fraction as the exponent of its factor.

    ``urn_normaliser=False`` is the likelihood of the point-object model whose Gibbs weights
    have ``g_m = 1`` (:class:`tracker.bnp.config.BnpConfig.urn_normaliser`): the weights are
    the unnormalised urn weights times :math:`e^{-(\alpha + V)}`, so the normaliser's two
    terms :math:`M_o \log(\alpha + V) - \log (\alpha + V)^{\overline{M_o}}` drop out (as
    they do from :func:`tracker.bnp.gibbs.log_joint`); with ``d = 0`` the alpha part is the
    Poisson birth count's :math:`-\alpha + K_\text{new} \log \alpha`.
    """
    alpha = np.asarray(alpha, dtype=float)
    d = np.asarray(d, dtype=float)
    total = alpha + mass
    out = -total + n_object * np.log(total) - log_rising(total, n_object) if urn_normaliser else -total
    j = 0
    while j < n_new:
        out = out + min(1.0, n_new - j) * np.log(alpha + d * (d_bar + j))
        j += 1
    v = np.asarray(seated_popularity, dtype=float)
    n = np.asarray(seated_counts, dtype=int)
    used = n > 0
    if used.any():  # depends on d only: evaluate on d's axis and broadcast over alpha
        d_axis = d.reshape(1, -1) if d.ndim == 2 else d[None]
        seated = np.sum(log_rising(v[used][:, None] - d_axis.ravel()[None], n[used][:, None]), axis=0)
        out = out + seated.reshape(d_axis.shape)
    return out


def log_gamma_prior(x: np.ndarray, shape: float, scale: float) -> np.ndarray:
    """Unnormalised log density of Gamma(shape, scale) at ``x > 0``."""
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore"):
        return (shape - 1.0) * np.log(x) - x / scale


def sample_grid(rng: np.random.Generator, log_post: np.ndarray) -> tuple[int, ...]:
    """Draw one cell of a grid with probabilities proportional to ``exp(log_post)``."""
    flat = log_post.ravel()
    p = np.exp(flat - flat.max())
    idx = int(np.searchsorted(np.cumsum(p), rng.random() * p.sum(), side="right"))
    return np.unravel_index(min(idx, flat.size - 1), log_post.shape)


def grid_mean(log_post: np.ndarray, alpha: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """Posterior means of ``alpha`` (rows) and ``d`` (columns) under ``exp(log_post)`` on the grid."""
    p = np.exp(log_post - log_post.max())
    p /= p.sum()
    return float(p.sum(axis=1) @ alpha), float(p.sum(axis=0) @ d)
