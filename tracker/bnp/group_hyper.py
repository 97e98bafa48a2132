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

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bnptrack.tracker.bnp.group_config import GroupConfig
from bnptrack.tracker.bnp.group_state import GroupState, _rows_of, previous_rows
from bnptrack.tracker.bnp.urn import ALPHA_GRID, D_GRID, frame_loglik_grid, grid_mean, log_gamma_prior


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
    from bnptrack.tracker.numerics import gammaln  # as tracker.bnp.urn

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


@dataclass(frozen=True)
class GroupHyper:
    """The two-level tracker's :math:`(\\alpha_2, d)`: their grid and priors (a
    :class:`~tracker.bnp.group_config.GroupConfig`'s), the partition's history kept in the state
    (:meth:`history`) and the posterior means given it (:meth:`posterior`)."""

    config: GroupConfig

    @cached_property
    def alpha_grid(self) -> np.ndarray:
        return ALPHA_GRID if self.config.infer_alpha else np.array([self.config.alpha])

    @cached_property
    def d_grid(self) -> np.ndarray:
        return D_GRID if self.config.infer_d else np.array([self.config.d])

    def history(self, state: GroupState, labels: tuple[str, ...], members: np.ndarray, member_ids: np.ndarray,
                g_ids: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int, int, np.ndarray]:
        """The partition of every object ever in it (:func:`update_history`): the members' counts
        moved to their clusters; clusters that no longer transition folded into the dead clusters'
        sufficient statistics.  ``rows``: each label's row in ``state``
        (:func:`tracker.bnp.group_state.previous_rows`, computed when not given).  Returns the
        state's history fields."""
        if rows is None:
            rows = previous_rows(state, labels)
        counted = _rows_of(state.counted, rows)
        totals = dict(zip(state.group_ids.tolist(), state.hist_total.tolist()))
        counted = update_history(counted, members, member_ids, totals)
        live = set(g_ids.tolist())
        dead = np.array([t for c, t in totals.items() if c not in live and t > 0], dtype=np.int64)
        factor = state.dead_factor if state.dead_factor.size else np.zeros(self.d_grid.size)
        if dead.size:
            factor = factor + size_factor(self.d_grid, dead)
        hist_total = np.array([totals[g] for g in g_ids.tolist()], dtype=np.int64)
        return counted, hist_total, state.dead_k + dead.size, state.dead_n + int(dead.sum()), factor

    def history_loglik(self, hist: tuple) -> np.ndarray:
        """The Pitman-Yor EPPF (:func:`eppf_grid`) of the history on the grid."""
        _, total, dead_k, dead_n, dead_factor = hist
        factor = dead_factor + size_factor(self.d_grid, total)
        return eppf_grid(self.alpha_grid[:, None], self.d_grid[None, :], int(total.size + dead_k),
                         int(total.sum() + dead_n), factor)

    def posterior(self, state: GroupState, z: np.ndarray, arrived: np.ndarray, hist: tuple
                  ) -> tuple[float, float, np.ndarray]:
        """(alpha_2, d) on the grid given the object partition: the EPPF of its whole history
        (:meth:`history_loglik`), the arrivals' Pitman-Yor predictive (:func:`arrivals_loglik_grid`)
        or the re-seating (:func:`tracker.bnp.urn.frame_loglik_grid`); ``arrived``: members new to
        the partition."""
        cfg = self.config
        if not cfg.infer_alpha and not cfg.infer_d:
            return state.alpha2, state.d2, state.hyper2_loglik
        if cfg.hyper_likelihood == "history":
            return self._history_hyper(hist)
        if cfg.hyper_likelihood == "arrivals":
            hyper = cfg.hyper_forgetting * state.hyper2_loglik + arrivals_loglik_grid(
                self.alpha_grid[:, None], self.d_grid[None, :], z, arrived)
        else:
            hyper = cfg.hyper_forgetting * state.hyper2_loglik + self._reseat_loglik(state, z)
        return self._grid_posterior(hyper)

    def _grid_posterior(self, hyper: np.ndarray) -> tuple[float, float, np.ndarray]:
        """Posterior means of (alpha_2, d) on the grid given the log-likelihood ``hyper`` and the priors."""
        log_post = hyper + self.alpha_log_prior[:, None]
        if self.d_log_prior is not None:
            log_post = log_post + self.d_log_prior[None, :]
        alpha, d = grid_mean(log_post, self.alpha_grid, self.d_grid)
        return alpha, d, hyper

    @cached_property
    def alpha_log_prior(self) -> np.ndarray:
        """alpha_2's Gamma prior on the grid plus log alpha (the grid is uniform in log alpha)."""
        cfg = self.config
        return log_gamma_prior(self.alpha_grid, cfg.alpha_shape, cfg.alpha_scale) + np.log(self.alpha_grid)

    @cached_property
    def d_log_prior(self) -> np.ndarray | None:
        cfg = self.config
        if cfg.infer_d and cfg.d_prior == "gamma":
            return log_gamma_prior(np.maximum(self.d_grid, 1e-12), cfg.d_shape, cfg.d_scale)
        return None

    @cached_property
    def _history_memo(self) -> dict:
        """The last history's key and result (:meth:`_history_hyper`)."""
        return {}

    def _history_hyper(self, hist: tuple) -> tuple[float, float, np.ndarray]:
        """(alpha_2, d, log-likelihood) from the history's EPPF (:meth:`history_loglik`).  The
        history changes only when an object joins or leaves a cluster: a frame whose history
        equals the last one's (live cluster totals, dead clusters' statistics) reuses its result,
        which is a pure function of them."""
        _, total, dead_k, dead_n, dead_factor = hist
        key = (total.tobytes(), int(dead_k), int(dead_n), np.asarray(dead_factor).tobytes())
        memo = self._history_memo
        hit = memo.get("last")
        if hit is not None and hit[0] == key:
            alpha, d, hyper = hit[1]
            return alpha, d, hyper.copy()
        alpha, d, hyper = self._grid_posterior(self.history_loglik(hist))
        memo["last"] = (key, (alpha, d, hyper.copy()))
        return alpha, d, hyper

    def _reseat_loglik(self, state: GroupState, z: np.ndarray) -> np.ndarray:
        """Every member's seat of this frame counted (objects as customers, clusters as tables)."""
        G = state.group_ids.size
        counts = np.bincount(z[z < G], minlength=G) if G else np.zeros(0, dtype=int)
        n_new = int(np.unique(z[z >= G]).size)
        return frame_loglik_grid(self.alpha_grid[:, None], self.d_grid[None, :],
                                 mass=float(state.group_count.sum()), d_bar=float(G), n_object=float(z.size),
                                 n_new=n_new, seated_popularity=state.group_count, seated_counts=counts)
