"""The object -> cluster collapsed Gibbs of the two-level tracker (:func:`sample_partition`):
the urn's prior weights (:func:`urn_log_weights`), theta's parts (:class:`Block`), the last
sweep's conditionals (:class:`Shares`), and the compiled set-up and compaction around the
sweeps' kernels (:mod:`tracker.bnp.group_scan`, :mod:`tracker.bnp.group_partition`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp.group_bundles import BlockArrays, Sweeps, Urn
from bnptrack.tracker.bnp.group_partition import gated_kernel
from bnptrack.tracker.bnp.group_scan import _collect_shares, _partition_kernel
from bnptrack.tracker.bnp.group_theta import prior_information

__all__ = ["PARTITION_KERNELS", "Block", "Shares", "sample_partition", "urn_log_weights"]


def urn_log_weights(n: np.ndarray, v_star: np.ndarray, alpha: float, d: float,
                    occupied: bool = False) -> np.ndarray:
    r"""Log prior weights of one object's options: each table then a new one (eqs. (case1)-(case3),
    Pitman-Yor (eq1)-(eq3)).  ``occupied`` False (reading "all"): table :math:`c` weighs
    :math:`n_c + v^*_c - d` (D1/P1 if chosen this frame, D2/P2 if only transitioned), new
    :math:`\alpha + d K`, K = tables with :math:`n_c + v^*_c > 0`.  ``occupied`` True (reading
    "occupied"): the discount acts on the tables the other objects occupy this frame only: a
    chosen table :math:`n_c + v^*_c - d` (eq. (17)), a transitioned one not yet chosen
    :math:`v^*_c` (eq. (18) without its discount), new :math:`\alpha + d D^{(\ell-1)}` with
    :math:`D^{(\ell-1)}` = tables with :math:`n_c > 0`, "the clusters used by the previous objects"
    (eq. (19) as written).  Both sum to :math:`\sum n + \sum v^* + \alpha`.
    Tables with :math:`n_c + v^*_c = 0` get weight 0."""
    occ = (n + v_star) > 0
    if occupied:
        chosen = n > 0
        w = np.where(chosen, n + v_star - d, np.where(occ, v_star, 0.0))
        new = alpha + d * chosen.sum()
    else:
        w = np.where(occ, n + v_star - d, 0.0)
        new = alpha + d * occ.sum()
    with np.errstate(divide="ignore"):
        return np.log(np.append(w, new))


@dataclass(frozen=True)
class Shares:
    """The last sweep's conditionals: object ``obj[p]`` joins an option with probability ``w[p]``,
    whose theta, given the option's other members, is N(``mu[p]``, ``cov[p]``)."""

    obj: np.ndarray  # (P,)
    w: np.ndarray  # (P,)
    mu: np.ndarray  # (P, 2)
    cov: np.ndarray  # (P, 2, 2)

    @staticmethod
    def empty() -> "Shares":
        return Shares(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2, 2)))


@dataclass(frozen=True)
class Block:
    """One independent 2-vector part of theta: members ``v`` (L, 2) ~ N(theta, ``R`` (L, 2, 2));
    transitioned clusters' priors N(``prior_mean`` (G, 2), ``prior_cov`` (G, 2, 2)); H_2's part
    N(``h_mean``, ``h_cov``)."""

    v: np.ndarray
    R: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    h_mean: np.ndarray
    h_cov: np.ndarray


def _table_priors(prior_cov, prior_mean, h_lam, h_eta, lam0, eta0) -> None:  # pragma: no cover - compiled
    """Each table's prior in information form into ``lam0`` (T, 2, 2) and ``eta0`` (T, 2): the
    G transitioned tables' (2x2 inverses as :func:`tracker.bnp.group_theta.inv2`, products as
    ``np.einsum``: from 0.0 in index order), then H_2's (``h_lam``, ``h_eta``) for the new ones."""
    G = prior_cov.shape[0]
    for g in range(G):
        a, b, c, d = prior_cov[g, 0, 0], prior_cov[g, 0, 1], prior_cov[g, 1, 0], prior_cov[g, 1, 1]
        det = a * d - b * c
        i00, i01, i10, i11 = d / det, -b / det, -c / det, a / det
        lam0[g, 0, 0], lam0[g, 0, 1], lam0[g, 1, 0], lam0[g, 1, 1] = i00, i01, i10, i11
        eta0[g, 0] = 0.0 + i00 * prior_mean[g, 0] + i01 * prior_mean[g, 1]
        eta0[g, 1] = 0.0 + i10 * prior_mean[g, 0] + i11 * prior_mean[g, 1]
    for t in range(G, lam0.shape[0]):  # entry by entry: a slice assignment compiles numba's string code
        for i in range(2):
            eta0[t, i] = h_eta[i]
            for j in range(2):
                lam0[t, i, j] = h_lam[i, j]


def _compact(z, G, T):  # pragma: no cover - compiled
    """``z`` with the new tables (``>= G``) renumbered ``G, G + 1, ...`` in increasing order."""
    used = np.zeros(T, dtype=np.bool_)
    for l in range(z.size):
        used[z[l]] = True
    remap = np.arange(T)
    k = G
    for t in range(G, T):
        if used[t]:
            remap[t] = k
            k += 1
    out = np.empty(z.size, dtype=np.int64)
    for l in range(z.size):
        out[l] = remap[z[l]]
    return out


_table_priors = jit(_table_priors, kernels_only=True)
_compact = jit(_compact)


#: :func:`sample_partition`'s kernels: the full scan of every table per move (the reference),
#: the incremental urn state without the gate, and the gated kernel (the default;
#: :mod:`tracker.bnp.group_partition`).  All three draw the same sample bit for bit.
PARTITION_KERNELS = ("scan", "urn", "gated")


def sample_partition(rng: np.random.Generator, blocks: list[Block], v_star: np.ndarray, alpha: float, d: float,
                     init: np.ndarray, sweeps: int, flat_share: bool = False,
                     occupied: bool = False, kernel: str = "gated", stats: np.ndarray | None = None
                     ) -> tuple[np.ndarray, Shares]:
    """Collapsed Gibbs over object -> cluster assignments (eq. (Gibbs), theta integrated out).

    theta is the product of independent ``blocks`` (velocity first; optionally the centroid);
    transitioned clusters have cardinality ``v_star`` (G,); ``init`` (L,): start table
    (< G transitioned, -1 new).  Each object's conditional is the urn weight
    (:func:`urn_log_weights`) times the conjugate predictive of each block.  Returns the last
    sample (table indices, ``>= G`` for new clusters, compacted) and the last sweep's
    conditionals with the first block's leave-one-out theta given the other current members
    (prior H_2, or flat if ``flat_share``: the paper's kappa_0 = 0; :class:`Shares`).
    ``occupied``: the urn's reading of eqs. (17)-(19) (:func:`urn_log_weights`).  ``kernel``:
    one of :data:`PARTITION_KERNELS` (the same numbers; "gated" is the fast one).  ``stats``: an
    int64 array (2,) that receives the number of moves and of tables scored (added to; the "urn"
    and "gated" kernels), or None.
    """
    if kernel not in PARTITION_KERNELS:
        raise ValueError(f"sample_partition: unknown kernel {kernel!r} "
                         f"(expected one of {', '.join(PARTITION_KERNELS)})")
    arrays = [BlockArrays(np.ascontiguousarray(b.v, dtype=float), np.asarray(b.R, dtype=float), b.prior_cov,
                          b.prior_mean, *prior_information(b.h_cov, b.h_mean)) for b in blocks]  # views allowed
    h_lam, h_eta = prior_information(None if flat_share else blocks[0].h_cov, blocks[0].h_mean)
    u = rng.random((sweeps, blocks[0].v.shape[0]))
    counts = np.zeros(2, dtype=np.int64) if stats is None else stats
    v_star = np.asarray(v_star, dtype=float)
    v, R, lam0, eta0, z, seated = _sample_setup(arrays[0], arrays[1] if len(blocks) > 1 else arrays[0], len(blocks),
                                                v_star, np.asarray(init, dtype=np.int64))
    sw = Sweeps(v, R, lam0, eta0, h_lam, h_eta, seated, z, u)
    shares = _sweep(PARTITION_KERNELS.index(kernel), sw, Urn(float(alpha), float(d), bool(occupied)), counts)
    return _compact(z, v_star.size, seated.size), Shares(*shares)


def _sweep(mode, sw, urn, stats):
    """:func:`sample_partition`'s sweeps over ``sw.z`` with the kernel ``mode`` (the index of
    :data:`PARTITION_KERNELS`; ``sw``, ``urn``: :class:`~tracker.bnp.group_bundles.Sweeps`,
    :class:`~tracker.bnp.group_bundles.Urn`): ``mode`` 0, the reference, :func:`_partition_kernel`
    then :func:`_collect_shares` (compiled only when used); 1, 2:
    :func:`tracker.bnp.group_partition.gated_kernel` without, with the gate, counting into
    ``stats``.  Returns the last sweep's shares (obj, w, mu, cov).  Calls from Python, not one
    kernel calling the others: numba optimises a kernel's callees again inside each compiled
    caller, so a wrapper kernel costs a first run seconds of compilation for microseconds per
    frame."""
    if mode == 0:
        L, T = sw.z.size, sw.v_star.size
        rec_p, rec_mu, rec_cov = np.zeros((L, T)), np.zeros((L, T, 2)), np.zeros((L, T, 2, 2))
        _partition_kernel(sw, urn, rec_p, rec_mu, rec_cov)
        return _collect_shares(rec_p, rec_mu, rec_cov, 1e-4)
    return gated_kernel(sw, urn, mode == 2, 1e-4, stats)


def _sample_setup(b0, b1, n_blocks, v_star, init):  # pragma: no cover - compiled
    """The sweeps' inputs from the blocks' arrays ``b0``, ``b1``
    (:class:`~tracker.bnp.group_bundles.BlockArrays`; ``b1`` unused when ``n_blocks`` is 1): the
    blocks' members stacked ``(P, L, 2)``, ``(P, L, 2, 2)``; the tables' priors
    (:func:`_table_priors`); the start (``init``, -1: a new table of its own); the tables' seated
    counts (``v_star``, then zeros)."""
    L, G = b0.v.shape[0], v_star.size
    T = G + L
    v = np.empty((n_blocks, L, 2))
    R = np.empty((n_blocks, L, 2, 2))
    lam0, eta0 = np.empty((n_blocks, T, 2, 2)), np.empty((n_blocks, T, 2))
    for p in range(n_blocks):
        vb, Rb = (b0.v, b0.R) if p == 0 else (b1.v, b1.R)
        for l in range(L):
            for i in range(2):
                v[p, l, i] = vb[l, i]
                for j in range(2):
                    R[p, l, i, j] = Rb[l, i, j]
        if p == 0:
            _table_priors(b0.prior_cov, b0.prior_mean, b0.h_lam, b0.h_eta, lam0[0], eta0[0])
        else:
            _table_priors(b1.prior_cov, b1.prior_mean, b1.h_lam, b1.h_eta, lam0[1], eta0[1])
    z = np.empty(L, dtype=np.int64)
    for l in range(L):
        z[l] = init[l] if init[l] >= 0 else G + l
    seated = np.zeros(T)
    for t in range(G):  # not seated[:G] = v_star: a slice assignment compiles numba's string code
        seated[t] = v_star[t]
    return v, R, lam0, eta0, z, seated


_sample_setup = jit(_sample_setup)
