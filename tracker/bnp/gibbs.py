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

import sys
from collections.abc import Callable
from types import ModuleType

import numpy as np

from bnptrack.tracker import numerics
from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp import gibbs_diagnostics, gibbs_setup, gibbs_sweeps, swap_moves
from bnptrack.tracker.bnp.gibbs_diagnostics import _log_joint_kernel, _split_rhat_kernel, log_joint, split_rhat
from bnptrack.tracker.bnp.gibbs_problem import GibbsProblem, GibbsResult, SparsePairs
from bnptrack.tracker.bnp.gibbs_setup import _setup_kernel, initial_assignment, swap_pairs
from bnptrack.tracker.bnp.gibbs_sweeps import _sweeps
from bnptrack.tracker.bnp.swap_moves import CLUTTER, MAX_BYTES, NEW, PAIR_MEMBERS, exchange_tables

__all__ = ["CLUTTER", "NEW", "PAIR_MEMBERS", "SparsePairs", "GibbsProblem", "GibbsResult", "initial_assignment",
           "swap_pairs", "run_gibbs", "split_rhat", "log_joint", "interpreted_kernels", "KERNEL_MODULES"]


def _chains_kernel(w_first, w_lik, w_clutter, w_new, log_lg, starts, init, has_init, rng, pair_a, pair_b, ptr, idx,
                   log_first, log_clutter, log_new, pop, par, extended, N, sweeps, burn_in, chains):
    """The second compiled pass of :func:`run_gibbs`: every chain's sweeps on uniforms drawn
    from ``rng`` in one stream (chain ``k``: ``sweeps x M`` for the sites, then ``P`` for each
    sweep's exchanges, drawn as each exchange pass starts, or one per scored proposal above
    :data:`tracker.bnp.swap_moves.PREDRAWN_PAIRS` pairs), the averaged tallies,
    :func:`split_rhat` and (point objects) :func:`log_joint` of chain 0's last state.  ``init`` is chain 0's start when ``has_init``."""
    M = ptr.shape[0] - 1
    nnz = idx.shape[0]
    K = nnz + 2 * M
    tally_pair, tally_cn = np.zeros(nnz), np.zeros((2, M))
    hs, hss = np.zeros((2 * chains, K)), np.zeros((2 * chains, K))
    opt = max(N, 1)
    opt_l, opt_w, opt_j = np.zeros(opt, np.int64), np.zeros(opt), np.zeros(opt, np.int64)
    first = np.empty(M, dtype=np.int64)
    tables = exchange_tables(ptr, idx, N, pair_a, pair_b, w_first, MAX_BYTES, np.int64(PAIR_MEMBERS))
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
                            pair_a, pair_b, burn_in, 2 * k, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, tables)
        if k == 0:
            for m in range(M):
                first[m] = c[m]
    kept = max(sweeps - burn_in, 1) * chains
    rhat = _split_rhat_kernel(hs, hss, (sweeps - burn_in) // 2)
    lj = np.nan if extended else _log_joint_kernel(first, ptr, idx, log_first, log_clutter, log_new, log_lg,
                                                   par[4] > 0.0, N)
    return tally_pair / kept, tally_cn[0] / kept, tally_cn[1] / kept, first, lj, rhat, accepted


_chains_kernel = jit(_chains_kernel)


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
    chain is the one-chain sampler without exchanges draw for draw (it draws no extra uniforms)."""
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


#: The modules whose kernels :func:`run_gibbs` calls (this one, its setup, sweeps and
#: diagnostics, and the exchange moves).
KERNEL_MODULES = (gibbs_setup, gibbs_sweeps, gibbs_diagnostics, swap_moves, sys.modules[__name__])


def interpreted_kernels() -> list[tuple[ModuleType, str, Callable]]:
    """Every name in :data:`KERNEL_MODULES` bound to a kernel, with the kernel's Python function
    (:func:`tracker.numerics.kernel_bindings`): setting each (``monkeypatch.setattr(module, name,
    fn)``) makes :func:`run_gibbs` run every kernel interpreted, for the compiled-vs-interpreted
    test.  Empty when nothing is compiled (``BNPTRACK_NO_JIT=1``)."""
    return numerics.kernel_bindings(KERNEL_MODULES)
