"""What the assignment sampler (:func:`tracker.bnp.gibbs.run_gibbs`) prepares before its sweeps:
the greedy starts (:func:`initial_assignment`), the scaled weights of the gated pairs
(:func:`_candidates`), the exchange pairs (:func:`swap_pairs`), and the compiled pass that
computes all of them at once (:func:`_setup_kernel`); the numpy functions are the reference the
kernels reproduce bit for bit."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bnptrack.tracker.numerics import argsort_stable, jit
from bnptrack.tracker.bnp.gibbs_problem import GibbsProblem
from bnptrack.tracker.bnp.swap_moves import CLUTTER, PAIR_MEMBERS
from bnptrack.tracker.bnp.swap_moves import exchange_pairs as _exchange_pairs


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
    not beat its alternatives (the start of the one-chain sampler without exchanges, kept draw
    for draw)."""
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
    """The first compiled pass of :func:`tracker.bnp.gibbs.run_gibbs`, the numpy code's
    arithmetic: the arguments of :func:`_candidates`' ``exp`` (``[log_first, log_lik if
    extended, log_clutter, log_new]`` minus each measurement's shift, one vector), the arguments
    of :func:`tracker.bnp.gibbs_diagnostics.log_joint`'s ``log`` (``(alpha + V) / (alpha + V +
    i)`` and ``alpha + d (d_bar + i)``, ``i < M``), the forward and the reversed greedy starts
    (:func:`initial_assignment`) and the exchange pairs (:func:`swap_pairs`)."""
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
        order = argsort_stable(-best)
        for k in range(2):  # forward, reversed; k == 0, not a literal True/False: one compile of _greedy
            by = order if k == 0 else order[::-1].copy()
            start = _greedy(ptr, idx, log_first, N, alt, best, by, extended, k == 0)
            for m in range(M):  # not starts[k] = ...: a slice assignment compiles numba's string code
                starts[k, m] = start[m]
    if not swaps or N == 0:
        return ex, lg, starts, np.zeros(0, np.int64), np.zeros(0, np.int64)
    pair_a, pair_b = _exchange_pairs(ptr, idx, log_first, N, np.int64(PAIR_MEMBERS))  # not a Literal[int]
    return ex, lg, starts, pair_a, pair_b


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


# the helpers are replaced by their compiled versions, which the compiled passes call
_greedy = jit(_greedy)  # noqa: F811
_group_pairs = jit(_group_pairs)  # noqa: F811
_npmax = jit(_npmax, inline=True)
_setup_kernel = jit(_setup_kernel)
