"""The inputs and outputs of one frame's assignment sampler (:func:`tracker.bnp.gibbs.run_gibbs`):
the gated (cluster, measurement) pairs in sparse form (:class:`SparsePairs`), the problem
(:class:`GibbsProblem`) and the posterior summaries (:class:`GibbsResult`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class SparsePairs:
    """The allowed (cluster, measurement) pairs of a frame, CSR by measurement: the clusters
    of measurement ``m`` are ``idx[ptr[m]:ptr[m+1]]`` (ascending), with their ``log_first`` and
    ``log_lik`` (see :class:`GibbsProblem`).  Memory and every sweep grow with the pairs in
    gates, not with clusters x measurements."""

    n_clusters: int
    ptr: np.ndarray  # (M+1,) int64
    idx: np.ndarray  # (nnz,) int64
    log_first: np.ndarray  # (nnz,)
    log_lik: np.ndarray  # (nnz,)

    @property
    def n_meas(self) -> int:
        return self.ptr.size - 1

    @cached_property
    def rows(self) -> np.ndarray:
        """Measurement index of each pair, ``(nnz,)``."""
        return np.repeat(np.arange(self.n_meas, dtype=np.int64), np.diff(self.ptr))

    @staticmethod
    def from_pairs(n_clusters: int, n_meas: int, cl: np.ndarray, ms: np.ndarray, log_first: np.ndarray,
                   log_lik: np.ndarray) -> "SparsePairs":
        """From pairs sorted by measurement then cluster; pairs with a non-finite
        ``log_first`` (gated out, dead cluster) are dropped."""
        ok = np.isfinite(log_first)
        cl, ms = cl[ok], ms[ok]
        ptr = np.zeros(n_meas + 1, dtype=np.int64)
        np.cumsum(np.bincount(ms, minlength=n_meas), out=ptr[1:])
        return SparsePairs(int(n_clusters), ptr, cl.astype(np.int64), log_first[ok], log_lik[ok])

    @staticmethod
    def from_dense(log_first: np.ndarray, log_lik: np.ndarray) -> "SparsePairs":
        N, M = log_first.shape
        mt, lt = np.nonzero(np.isfinite(log_first.T))  # sorted by measurement
        return SparsePairs.from_pairs(N, M, lt, mt, log_first[lt, mt], log_lik[lt, mt])

    def dense(self, values: np.ndarray, fill: float = -np.inf) -> np.ndarray:
        """``(N, M)`` matrix holding ``values`` (one per pair) and ``fill`` elsewhere."""
        out = np.full((self.n_clusters, self.n_meas), fill)
        out[self.idx, self.rows] = values
        return out

    def lookup(self, m: int, l: int) -> int:
        """Position of pair ``(l, m)`` or -1."""
        lo, hi = int(self.ptr[m]), int(self.ptr[m + 1])
        j = lo + int(np.searchsorted(self.idx[lo:hi], l))
        return j if j < hi and self.idx[j] == l else -1


@dataclass(frozen=True)
class GibbsProblem:
    """Inputs of one frame's assignment sampler (log domain, no validation: internal).

    ``log_first[l, m]``: log weight of measurement ``m`` taking free cluster ``l``
    (D2/P2 row above, ``-inf`` when gated out or dead); ``log_lik[l, m]``: log predictive
    density (used by D1 in extended mode); ``log_clutter[m]``; ``log_new[m] = log u_H(z_m)``.
    Give the dense ``(N, M)`` ``log_first``/``log_lik`` (then ``pairs`` is derived from them)
    or ``pairs`` alone (the tracker's gated, sparse form; the dense matrices are then ``None``).
    """

    log_first: np.ndarray | None
    log_lik: np.ndarray | None
    log_clutter: np.ndarray
    log_new: np.ndarray
    popularity: np.ndarray
    alpha: float
    d: float
    d_bar: float
    mass: float
    """Transitioned urn mass ``V``; ``alpha + V`` is the Poisson rate of object measurements."""
    extended: bool = False
    pairs: SparsePairs | None = None
    urn_normaliser: bool = True
    """Multiply every object weight by the urn normaliser :math:`g_m` (the paper's eq. (1)).
    ``False``: :math:`g_m = 1`, the point-object Poisson-birth / Bernoulli-object model (see
    :class:`tracker.bnp.config.BnpConfig.urn_normaliser`)."""

    def __post_init__(self) -> None:
        if self.log_first is None and self.pairs is None:
            raise ValueError("GibbsProblem: give the dense log_first/log_lik or pairs")
        if self.log_first is not None:  # the dense form wins (``dataclasses.replace`` of it stays right)
            object.__setattr__(self, "pairs", SparsePairs.from_dense(np.asarray(self.log_first, dtype=float),
                                                                     np.asarray(self.log_lik, dtype=float)))

    @property
    def shape(self) -> tuple[int, int]:
        """``(N clusters, M measurements)``."""
        return self.pairs.n_clusters, self.pairs.n_meas

    def dense_first(self) -> np.ndarray:
        """``log_first`` as an ``(N, M)`` matrix (small problems: tests, enumeration)."""
        return self.log_first if self.log_first is not None else self.pairs.dense(self.pairs.log_first)


@dataclass(frozen=True)
class GibbsResult:
    """Posterior summaries from the kept sweeps (Rao-Blackwellised: the average of each
    visit's full conditional, which resolves small probabilities that draw counts cannot).

    ``p_pairs[j] = Pr(c_m = l)`` for pair ``j = (l, m)`` of ``pairs`` (``p_cluster`` is the
    dense ``(N, M)`` view), ``p_clutter[m]``, ``p_new[m]``; ``last`` is the final
    assignment vector (cluster index, ``CLUTTER`` or ``NEW``); ``log_joint`` its unnormalised
    log posterior (up to a constant); ``n_kept`` the number of kept sweeps (all chains).
    """

    pairs: SparsePairs
    p_pairs: np.ndarray
    p_clutter: np.ndarray
    p_new: np.ndarray
    last: np.ndarray
    log_joint: float
    n_kept: int
    rhat_max: float = 1.0
    """Largest split-chain R-hat of the assignment probabilities (:func:`split_rhat`)."""
    swaps_accepted: int = 0
    """Accepted pair exchanges, out of ``swaps_proposed`` (pairs x sweeps x chains)."""
    swaps_proposed: int = 0

    @property
    def p_cluster(self) -> np.ndarray:
        """``(N, M)``: ``Pr(c_m = l)`` (0 outside the gates)."""
        return self.pairs.dense(self.p_pairs, 0.0)

