r"""Collapsed Gibbs sampler over measurement-to-object assignments for one frame.

The target is the frame-:math:`k` posterior of DDP-EMM / DPY-STP with point objects in clutter
(``docs/trackers.md`` derives it).  Each measurement :math:`m` has an assignment
:math:`c_m \in \{\text{clutter}, 1..N \text{ (transitioned clusters)}, \text{new}\}`; the
survival indicators :math:`\lambda_l` of clusters without a measurement are summed out.  The
full conditional of :math:`c_m` given all other assignments is

.. math::

    \Pr(c_m = \text{clutter}) &\propto \lambda_c\, \kappa(z_m) \\
    \Pr(c_m = l) &\propto g_m\, \frac{q_l P_{D,l}}{q_l (1-P_{D,l}) + 1 - q_l}\,
        (v_l - d)\, \ell_l(z_m)
        \quad (\text{case D2/P2: } l \text{ not chosen by another measurement}) \\
    \Pr(c_m = l) &\propto g_m\, (n_l^{-m} + v_l - d)\, \ell_l(z_m)
        \quad (\text{case D1/P1, extended objects only}) \\
    \Pr(c_m = \text{new}) &\propto g_m\, (\alpha + d\,(\bar D + K^{-m}_\text{new}))\, u_H(z_m)
        \quad (\text{case D3/P3}) \\
    g_m &= \frac{\alpha + V}{\alpha + V + M_o^{-m}}

with :math:`q_l = P_S r_l` the predicted existence, :math:`v_l` the popularity,
:math:`V = \sum_l q_l v_l` the expected transitioned mass, :math:`M_o^{-m}` the number of
other measurements assigned to objects (the urn's normaliser :math:`g_k`, eq. (1)),
:math:`\ell_l` the EKF/UKF predictive density, :math:`u_H` the base distribution's predictive
density of a measurement, :math:`\bar D = \sum_l q_l` and :math:`K^{-m}_\text{new}` the number
of new clusters opened by the other measurements.  For point objects a cluster holds at most
one measurement per frame (D1 has probability zero), which truncates the joint to a symmetric
set; the conditionals above restricted to the allowed values are exactly its full conditionals.

Single-site moves cannot exchange two measurements that compete for one cluster (the holder
must first pass through clutter or a new cluster), so each sweep is followed by a
Metropolis-Hastings exchange of the assignments of every pair of measurements whose gates
share a cluster (:func:`tracker.bnp.swap_moves.swap_pass`; it keeps every count of the urn, so the acceptance ratio
is the ratio of the two measurements' own factors).  A cluster whose gate holds more than
:data:`tracker.bnp.swap_moves.PAIR_MEMBERS` measurements pairs only its most likely ones
(:func:`tracker.bnp.swap_moves.exchange_pairs`): the list is fixed for the frame, so every
exchange stays its own inverse and the target is unchanged; only the moves offered differ.  Several chains from different greedy
starts give the split-chain R-hat of the marginals (:func:`split_rhat`).

The sweeps run on a sparse (gated) candidate list per measurement, compiled with numba
(``BNPTRACK_NO_JIT=1`` runs the same functions interpreted), using uniforms pre-drawn from the
caller's ``numpy.random.Generator`` so the result depends only on the generator's state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp._kernels import np_sum
from bnptrack.tracker.bnp.swap_moves import CLUTTER, MAX_BYTES, NEW, PAIR_MEMBERS, gate_bits
from bnptrack.tracker.bnp.swap_moves import exchange_pairs as _exchange_pairs
from bnptrack.tracker.bnp.swap_moves import KERNELS_PY as SWAP_KERNELS_PY
from bnptrack.tracker.bnp.swap_moves import own_weight as _own_weight
from bnptrack.tracker.bnp.swap_moves import swap_pass as _swap_pass


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


def initial_assignment(problem: GibbsProblem, reverse: bool = False) -> np.ndarray:
    """Greedy start: measurements in order of their best score take their best free cluster
    when it beats both clutter and a new cluster (a cheap, valid state to start from).

    ``reverse`` visits the measurements in the opposite order (lowest best score first, ties
    reversed too): where two measurements compete for one cluster, the other one takes it, an
    over-dispersed second start for the between-chain R-hat."""
    N, M = problem.shape
    if N == 0 or M == 0:
        return np.full(M, CLUTTER, dtype=np.int64)
    pr = problem.pairs
    alt = np.maximum(problem.log_clutter,
                     math.log(problem.alpha + problem.d * problem.d_bar) + problem.log_new)
    best = np.full(M, -np.inf)
    has = np.flatnonzero(np.diff(pr.ptr) > 0)
    if has.size:
        best[has] = np.maximum.reduceat(pr.log_first, pr.ptr[has])
    order = np.argsort(-best, kind="stable")
    if reverse:
        order = order[::-1].copy()
    return _greedy(pr.ptr, pr.idx, pr.log_first, N, alt, best, order, bool(problem.extended), not reverse)


def _greedy(ptr, idx, log_first, N, alt, best, order, extended, stop_early):
    """The greedy pass of :func:`initial_assignment` on the sparse pairs (compiled with numba).
    ``stop_early``: in decreasing order, stop at the first measurement whose best score does
    not beat its alternatives (the session-3 start, kept draw for draw)."""
    M = ptr.shape[0] - 1
    c = np.full(M, CLUTTER, dtype=np.int64)
    taken = np.zeros(N, dtype=np.bool_)
    for m in order:
        if best[m] <= alt[m]:
            if stop_early:
                break
            continue
        top, l_top = -np.inf, -1
        for j in range(ptr[m], ptr[m + 1]):
            l = idx[j]
            if not taken[l] and log_first[j] > top:
                top, l_top = log_first[j], l
        if l_top >= 0 and top > alt[m]:
            c[m] = l_top
            taken[l_top] = not extended
    return c


@dataclass(frozen=True)
class _Candidates:
    """Sparse (CSR by measurement) view of the allowed clusters, weights scaled per measurement."""

    ptr: np.ndarray  # (M+1,) int64
    idx: np.ndarray  # (nnz,) cluster indices
    w_first: np.ndarray  # (nnz,) exp(log_first - shift)
    w_lik: np.ndarray  # (nnz,) exp(log_lik - shift)  (extended mode)
    w_clutter: np.ndarray  # (M,)
    w_new: np.ndarray  # (M,) exp(log_new - shift), before the urn weight


def _candidates(problem: GibbsProblem) -> _Candidates:
    pr = problem.pairs
    mt, lf, ll = pr.rows, pr.log_first, pr.log_lik
    shift = np.maximum(problem.log_clutter, problem.log_new)
    if mt.size:
        np.maximum.at(shift, mt, lf)
        if problem.extended:
            np.maximum.at(shift, mt, ll)
    shift = np.where(np.isfinite(shift), shift, 0.0)
    with np.errstate(under="ignore"):
        return _Candidates(
            pr.ptr, pr.idx, np.exp(lf - shift[mt]),
            np.exp(ll - shift[mt]) if problem.extended else np.zeros(mt.size),
            np.exp(problem.log_clutter - shift), np.exp(problem.log_new - shift),
        )


def _site_pass(c, cnt, st, par, extended, w_clutter, w_newbase, ptr, idx, w_first, w_lik, pop, u_row,
               keep, half, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, own):
    """One systematic-scan sweep of single-site full-conditional draws (mutates ``c``, ``cnt``,
    ``st = [K_new, M_o]`` and, when ``keep``, the Rao-Blackwellised tallies: each visit adds
    its full conditional to ``tally_pair`` (by pair)/``tally_cn``, and to the split-half sums
    ``hs[half]``/``hss[half]`` (squares) used by the R-hat diagnostic when ``half >= 0``) and
    ``own`` (each measurement's :func:`tracker.bnp.swap_moves.own_weight` at its value, for the
    exchange pass)."""
    total_mass, alpha, d, d_bar, use_g = par[0], par[1], par[2], par[3], par[4] > 0.0
    M = c.shape[0]
    nnz = idx.shape[0]
    for m in range(M):
        cur = c[m]
        if cur >= 0:
            cnt[cur] -= 1
        if cur != CLUTTER:
            st[1] -= 1
        if cur == NEW:
            st[0] -= 1
        g = total_mass / (total_mass + st[1]) if use_g else 1.0
        wc = w_clutter[m]
        wn = g * w_newbase[m] * (alpha + d * (d_bar + st[0]))
        total = wc + wn
        n_opt = 0
        for j in range(ptr[m], ptr[m + 1]):
            l = idx[j]
            n = cnt[l]
            if n == 0:
                w = g * w_first[j]
            elif extended:
                w = g * w_lik[j] * (n + pop[l] - d)
            else:
                continue
            if w > 0.0:
                opt_l[n_opt] = l
                opt_w[n_opt] = w
                opt_j[n_opt] = j
                n_opt += 1
                total += w
        x = u_row[m] * total
        if x < wc:
            choice = CLUTTER
            own[m] = wc
        elif x < wc + wn:
            choice = NEW
            own[m] = w_newbase[m]
        else:
            x -= wc + wn
            pick = n_opt - 1  # round-off guard (no option: new)
            for i in range(n_opt):
                if x < opt_w[i]:
                    pick = i
                    break
                x -= opt_w[i]
            if pick >= 0:
                choice = opt_l[pick]
                own[m] = w_first[opt_j[pick]]
            else:
                choice = NEW
                own[m] = w_newbase[m]
        if keep:
            inv = 1.0 / total
            tally_cn[0, m] += wc * inv
            tally_cn[1, m] += wn * inv
            for i in range(n_opt):
                tally_pair[opt_j[i]] += opt_w[i] * inv
            if half >= 0:
                _half_add(hs, hss, half, nnz + m, wc * inv)
                _half_add(hs, hss, half, nnz + M + m, wn * inv)
                for i in range(n_opt):
                    _half_add(hs, hss, half, opt_j[i], opt_w[i] * inv)
        c[m] = choice
        if choice >= 0:
            cnt[choice] += 1
        if choice != CLUTTER:
            st[1] += 1
        if choice == NEW:
            st[0] += 1


def _half_add(hs, hss, h, k, v):
    hs[h, k] += v
    hss[h, k] += v * v


def _sweep_kernel(c, cnt, st, par, extended, w_clutter, w_newbase, ptr, idx, w_first, w_lik, pop, u, rng,
                  pair_a, pair_b, burn_in, h0, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, bits):
    """All sweeps of one chain: a single-site pass on ``u[s]``, then the exchange pass (when
    pairs are given) on one uniform per pair drawn from ``rng`` as the pass starts (so the
    uniforms of one pass are in memory at a time, not those of every sweep).

    Sweep ``s >= burn_in`` is kept; the kept sweeps' first and last ``n // 2`` are the
    split-chain halves ``h0`` and ``h0 + 1`` of the R-hat sums (the middle one is dropped when
    ``n`` is odd)."""
    sweeps = u.shape[0]
    kept = sweeps - burn_in
    half_len = kept // 2
    accepted = 0
    own = np.empty(c.shape[0])
    for m in range(c.shape[0]):
        own[m] = _own_weight(m, c[m], w_clutter, w_newbase, ptr, idx, w_first)
    for s in range(sweeps):
        i = s - burn_in
        half = h0 if 0 <= i < half_len else (h0 + 1 if i >= kept - half_len else -1)
        _site_pass(c, cnt, st, par, extended, w_clutter, w_newbase, ptr, idx, w_first, w_lik, pop, u[s],
                   i >= 0, half, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, own)
        if pair_a.shape[0] > 0:
            accepted += _swap_pass(c, cnt, extended, pair_a, pair_b, w_clutter, w_newbase, ptr, idx, w_first,
                                   rng.random(pair_a.shape[0]), bits, own)
    return accepted


def _group_pairs(meas_of, starts, sizes, M, n_keys):
    """Keys ``a * M + b`` of every pair ``a < b`` within each group (compiled with numba)."""
    out = np.empty(n_keys, dtype=np.int64)
    k = 0
    for g in range(starts.shape[0]):
        s, n = starts[g], sizes[g]
        for i in range(n):
            for j in range(i + 1, n):
                out[k] = meas_of[s + i] * M + meas_of[s + j]
                k += 1
    return out


def _npmax(a, b):
    """``np.maximum`` of two floats: nan if either is."""
    return a if a >= b or a != a else b


def _setup_kernel(ptr, idx, log_first, log_lik, log_clutter, log_new, N, extended, alpha, d, d_bar, total_mass,
                  swaps):
    """The first compiled pass of :func:`run_gibbs`, the numpy code's arithmetic: the arguments
    of :func:`_candidates`' ``exp`` (``[log_first, log_lik if extended, log_clutter, log_new]``
    minus each measurement's shift, one vector), the arguments of :func:`log_joint`'s ``log``
    (``(alpha + V) / (alpha + V + i)`` and ``alpha + d (d_bar + i)``, ``i < M``), the forward
    and the reversed greedy starts (:func:`initial_assignment`) and the exchange pairs
    (:func:`swap_pairs`)."""
    M = ptr.shape[0] - 1
    nnz = idx.shape[0]
    shift = np.empty(M)
    for m in range(M):
        shift[m] = _npmax(log_clutter[m], log_new[m])
    for m in range(M):
        for j in range(ptr[m], ptr[m + 1]):
            shift[m] = _npmax(shift[m], log_first[j])
    if extended:
        for m in range(M):
            for j in range(ptr[m], ptr[m + 1]):
                shift[m] = _npmax(shift[m], log_lik[j])
    for m in range(M):
        if not np.isfinite(shift[m]):
            shift[m] = 0.0
    n_lik = nnz if extended else 0
    ex = np.empty(nnz + n_lik + 2 * M)
    lg = np.empty(2 * M)
    for m in range(M):
        for j in range(ptr[m], ptr[m + 1]):
            ex[j] = log_first[j] - shift[m]
            if extended:
                ex[nnz + j] = log_lik[j] - shift[m]
        ex[nnz + n_lik + m] = log_clutter[m] - shift[m]
        ex[nnz + n_lik + M + m] = log_new[m] - shift[m]
        lg[m] = total_mass / (total_mass + m)
        lg[M + m] = alpha + d * (d_bar + m)
    starts = np.full((2, M), CLUTTER, dtype=np.int64)
    if N > 0 and M > 0:
        la = math.log(alpha + d * d_bar)
        alt = np.empty(M)
        best = np.full(M, -np.inf)
        for m in range(M):
            alt[m] = _npmax(log_clutter[m], la + log_new[m])
            for j in range(ptr[m], ptr[m + 1]):
                best[m] = log_first[j] if j == ptr[m] else _npmax(best[m], log_first[j])
        order = np.argsort(-best, kind="mergesort")
        for k in range(2):  # forward, reversed; k == 0, not a literal True/False: one compile of _greedy
            by = order if k == 0 else order[::-1].copy()
            start = _greedy(ptr, idx, log_first, N, alt, best, by, extended, k == 0)
            for m in range(M):  # not starts[k] = ...: a slice assignment compiles numba's string code
                starts[k, m] = start[m]
    if not swaps or N == 0:
        return ex, lg, starts, np.zeros(0, np.int64), np.zeros(0, np.int64)
    pair_a, pair_b = _exchange_pairs(ptr, idx, log_first, N, np.int64(PAIR_MEMBERS))  # not a Literal[int]
    return ex, lg, starts, pair_a, pair_b


def _chains_kernel(w_first, w_lik, w_clutter, w_new, log_lg, starts, init, has_init, rng, pair_a, pair_b, ptr, idx,
                   log_first, log_clutter, log_new, pop, par, extended, N, sweeps, burn_in, chains):
    """The second compiled pass of :func:`run_gibbs`: every chain's sweeps on uniforms drawn
    from ``rng`` in one stream (chain ``k``: ``sweeps x M`` for the sites, then ``P`` for each
    sweep's exchanges, drawn as each exchange pass starts), the averaged tallies, :func:`split_rhat` and (point objects) :func:`log_joint` of chain
    0's last state.  ``init`` is chain 0's start when ``has_init``."""
    M = ptr.shape[0] - 1
    nnz = idx.shape[0]
    K = nnz + 2 * M
    P = pair_a.shape[0]
    tally_pair, tally_cn = np.zeros(nnz), np.zeros((2, M))
    hs, hss = np.zeros((2 * chains, K)), np.zeros((2 * chains, K))
    opt = max(N, 1)
    opt_l, opt_w, opt_j = np.zeros(opt, np.int64), np.zeros(opt), np.zeros(opt, np.int64)
    first = np.empty(M, dtype=np.int64)
    bits = gate_bits(ptr, idx, N, MAX_BYTES) if P > 0 else np.zeros((0, 0), dtype=np.uint8)
    accepted = 0
    for k in range(chains):
        c = init.copy() if k == 0 and has_init else starts[k % 2].copy()
        cnt = np.zeros(N, dtype=np.int64)
        st = np.zeros(2, dtype=np.int64)
        for m in range(M):
            if c[m] >= 0:
                cnt[c[m]] += 1
            if c[m] == NEW:
                st[0] += 1
            if c[m] != CLUTTER:
                st[1] += 1
        u = rng.random((sweeps, M))
        accepted += _sweeps(c, cnt, st, par, extended, w_clutter, w_new, ptr, idx, w_first, w_lik, pop, u, rng,
                            pair_a, pair_b, burn_in, 2 * k, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, bits)
        if k == 0:
            for m in range(M):
                first[m] = c[m]
    kept = max(sweeps - burn_in, 1) * chains
    rhat = _split_rhat_kernel(hs, hss, (sweeps - burn_in) // 2)
    lj = np.nan if extended else _log_joint_kernel(first, ptr, idx, log_first, log_clutter, log_new, log_lg,
                                                   par[4] > 0.0, N)
    return tally_pair / kept, tally_cn[0] / kept, tally_cn[1] / kept, first, lj, rhat, accepted


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


_KERNELS_PY = (_site_pass, _half_add, _sweep_kernel, _greedy, _group_pairs, _npmax, _setup_kernel,
               _chains_kernel, _log_joint_kernel, _split_rhat_kernel)
# the helpers are replaced by their compiled versions, which the compiled driver calls
_greedy = jit(_greedy)  # noqa: F811
_half_add = jit(_half_add, inline=True)
_site_pass = jit(_site_pass)
_sweeps = jit(_sweep_kernel)
_group_pairs = jit(_group_pairs)  # noqa: F811
_npmax = jit(_npmax, inline=True)
_setup_kernel = jit(_setup_kernel)
_chains_kernel = jit(_chains_kernel)
_log_joint_kernel = jit(_log_joint_kernel)
_split_rhat_kernel = jit(_split_rhat_kernel)


def interpreted_kernels() -> dict[str, object]:
    """The module globals that make :func:`run_gibbs` run every kernel interpreted (for the
    compiled-vs-interpreted test and benchmark: ``monkeypatch.setattr(gibbs, k, v)``)."""
    names = ("_site_pass", "_half_add", "_sweeps", "_greedy", "_group_pairs", "_npmax",
             "_setup_kernel", "_chains_kernel", "_log_joint_kernel", "_split_rhat_kernel")
    swaps = SWAP_KERNELS_PY  # tracker.bnp.swap_moves' kernels, by the names this module binds
    return {**dict(zip(names, _KERNELS_PY)), "gate_bits": swaps["gate_bits"], "_own_weight": swaps["own_weight"],
            "_swap_pass": swaps["swap_pass"],
            "_exchange_pairs": swaps["exchange_pairs"]}


def swap_pairs(problem: GibbsProblem, max_members: int = PAIR_MEMBERS) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``a < b`` of measurements that share a cluster, sorted by ``(a, b)`` (built
    cluster by cluster from the sparse pairs).  A cluster whose gate holds more than
    ``max_members`` measurements pairs only its ``max_members`` most likely ones (highest
    ``log_first``, ties: the lower index)."""
    pr = problem.pairs
    M = pr.n_meas
    by_cluster = np.lexsort((pr.rows, pr.idx))  # measurements ascending within a cluster
    starts = np.r_[0, np.flatnonzero(np.diff(pr.idx[by_cluster])) + 1] if by_cluster.size else np.zeros(0, np.int64)
    sizes = np.diff(np.r_[starts, by_cluster.size]).astype(np.int64)
    groups = [by_cluster[s0:s0 + n] for s0, n in zip(starts.tolist(), sizes.tolist())]
    groups = [g if g.size <= max_members else np.sort(g[np.lexsort((pr.rows[g], -pr.log_first[g]))[:max_members]])
              for g in groups]
    sizes = np.array([g.size for g in groups], dtype=np.int64)
    n_keys = int(np.sum(sizes * (sizes - 1) // 2))
    if n_keys == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    meas_of = pr.rows[np.concatenate(groups)]
    starts = np.r_[0, np.cumsum(sizes)[:-1]].astype(np.int64)
    key = np.unique(_group_pairs(meas_of, starts, sizes, M, n_keys))
    return (key // M).astype(np.int64), (key % M).astype(np.int64)


def run_gibbs(
    problem: GibbsProblem,
    rng: np.random.Generator,
    sweeps: int,
    burn_in: int,
    init: np.ndarray | None = None,
    swaps: bool = True,
    chains: int = 1,
) -> GibbsResult:
    """Run ``chains`` chains of ``sweeps`` sweeps each (single-site pass, then the exchange
    pass unless ``swaps`` is false); average the last ``sweeps - burn_in`` of every chain.

    Chain 0 starts from ``init`` (default: the greedy start), odd chains from the reversed
    greedy start.  ``last``/``log_joint`` are chain 0's final state.  ``swaps=False`` with one
    chain is the session-3 sampler draw for draw (it draws no extra uniforms)."""
    N, M = problem.shape
    pr = problem.pairs
    ext = bool(problem.extended)
    log_clutter = np.asarray(problem.log_clutter, dtype=float)
    log_new = np.asarray(problem.log_new, dtype=float)
    alpha, d, d_bar = float(problem.alpha), float(problem.d), float(problem.d_bar)
    ex, lg, starts, pair_a, pair_b = _setup_kernel(pr.ptr, pr.idx, pr.log_first, pr.log_lik, log_clutter, log_new,
                                                   N, ext, alpha, d, d_bar, alpha + problem.mass, bool(swaps))
    w = np.exp(ex)  # underflow to 0 is numpy's default (ignored)
    nnz, n_lik = pr.idx.size, pr.idx.size if ext else 0
    w_lik = w[nnz:2 * nnz] if ext else np.zeros(nnz)
    par = np.array([alpha + problem.mass, alpha, d, d_bar, 1.0 if problem.urn_normaliser else 0.0], dtype=float)
    has_init = init is not None
    start0 = np.asarray(init).astype(np.int64) if has_init else np.zeros(0, np.int64)
    p_pairs, p_clutter, p_new, first, lj, rhat, accepted = _chains_kernel(
        w[:nnz], w_lik, w[nnz + n_lik:nnz + n_lik + M], w[nnz + n_lik + M:], np.log(lg), starts, start0, has_init,
        rng, pair_a, pair_b, pr.ptr, pr.idx, pr.log_first, log_clutter, log_new,
        np.asarray(problem.popularity, dtype=float), par, ext, N, int(sweeps), int(burn_in), int(chains))
    kept = max(sweeps - burn_in, 1) * chains
    return GibbsResult(problem.pairs, p_pairs, p_clutter, p_new, first, log_joint(problem, first) if ext else float(lj),
                       kept, float(rhat), int(accepted), int(pair_a.size * sweeps * chains))


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
