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

The sweeps run on a sparse (gated) candidate list per measurement, compiled with numba
(``BNPTRACK_NO_JIT=1`` runs the same function interpreted), using uniforms pre-drawn from the
caller's ``numpy.random.Generator`` so the result depends only on the generator's state.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

try:  # a prebuilt wheel; the kernel also runs interpreted (BNPTRACK_NO_JIT=1)
    from numba import njit as _njit
except ImportError:  # pragma: no cover
    _njit = None

CLUTTER = -1
NEW = -2


@dataclass(frozen=True)
class GibbsProblem:
    """Inputs of one frame's assignment sampler (log domain, no validation: internal).

    ``log_first[l, m]``: log weight of measurement ``m`` taking free cluster ``l``
    (D2/P2 row above, ``-inf`` when gated out or dead); ``log_lik[l, m]``: log predictive
    density (used by D1 in extended mode); ``log_clutter[m]``; ``log_new[m] = log u_H(z_m)``.
    """

    log_first: np.ndarray
    log_lik: np.ndarray
    log_clutter: np.ndarray
    log_new: np.ndarray
    popularity: np.ndarray
    alpha: float
    d: float
    d_bar: float
    mass: float
    """Transitioned urn mass ``V``; ``alpha + V`` is the Poisson rate of object measurements."""
    extended: bool = False


@dataclass(frozen=True)
class GibbsResult:
    """Posterior summaries from the kept sweeps (Rao-Blackwellised: the average of each
    visit's full conditional, which resolves small probabilities that draw counts cannot).

    ``p_cluster[l, m] = Pr(c_m = l)``, ``p_clutter[m]``, ``p_new[m]``; ``last`` is the final
    assignment vector (cluster index, ``CLUTTER`` or ``NEW``); ``log_joint`` its unnormalised
    log posterior (up to a constant); ``n_kept`` the number of kept sweeps.
    """

    p_cluster: np.ndarray
    p_clutter: np.ndarray
    p_new: np.ndarray
    last: np.ndarray
    log_joint: float
    n_kept: int



def initial_assignment(problem: GibbsProblem) -> np.ndarray:
    """Greedy start: measurements in order of their best score take their best free cluster
    when it beats both clutter and a new cluster (a cheap, valid state to start from)."""
    N, M = problem.log_first.shape
    c = np.full(M, CLUTTER, dtype=np.int64)
    if N == 0 or M == 0:
        return c
    taken = np.zeros(N, dtype=bool)
    alt = np.maximum(problem.log_clutter,
                     math.log(problem.alpha + problem.d * problem.d_bar) + problem.log_new)
    best = problem.log_first.max(axis=0)
    for m in np.argsort(-best, kind="stable").tolist():
        if best[m] <= alt[m]:
            break  # later measurements score lower still
        col = np.where(taken, -np.inf, problem.log_first[:, m])
        l = int(np.argmax(col))
        if col[l] > alt[m]:
            c[m] = l
            taken[l] = not problem.extended
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
    N, M = problem.log_first.shape
    mt, lt = np.nonzero(np.isfinite(problem.log_first.T))  # sorted by measurement
    lf = problem.log_first[lt, mt]
    ll = problem.log_lik[lt, mt]
    shift = np.maximum(problem.log_clutter, problem.log_new)
    if mt.size:
        np.maximum.at(shift, mt, lf)
        if problem.extended:
            np.maximum.at(shift, mt, ll)
    shift = np.where(np.isfinite(shift), shift, 0.0)
    ptr = np.zeros(M + 1, dtype=np.int64)
    np.cumsum(np.bincount(mt, minlength=M), out=ptr[1:])
    with np.errstate(under="ignore"):
        return _Candidates(
            ptr, lt.astype(np.int64), np.exp(lf - shift[mt]),
            np.exp(ll - shift[mt]) if problem.extended else np.zeros(mt.size),
            np.exp(problem.log_clutter - shift), np.exp(problem.log_new - shift),
        )


def _sweep_kernel(c, cnt, k_new, m_obj, total_mass, alpha, d, d_bar, extended, w_clutter, w_newbase,
                  ptr, idx, w_first, w_lik, pop, u, burn_in, tally_cluster, tally_clutter, tally_new,
                  opt_l, opt_w):
    """The systematic-scan sweeps on plain arrays (compiled with numba when available).

    Mutates ``c``, ``cnt`` and the tallies in place; the tallies are Rao-Blackwellised
    (each visit adds its full conditional).
    """
    sweeps, M = u.shape
    for s in range(sweeps):
        for m in range(M):
            cur = c[m]
            if cur >= 0:
                cnt[cur] -= 1
                m_obj -= 1
            elif cur == NEW:
                k_new -= 1
                m_obj -= 1
            g = total_mass / (total_mass + m_obj)
            wc = w_clutter[m]
            wn = g * w_newbase[m] * (alpha + d * (d_bar + k_new))
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
                    n_opt += 1
                    total += w
            x = u[s, m] * total
            if x < wc:
                choice = CLUTTER
            elif x < wc + wn:
                choice = NEW
            else:
                x -= wc + wn
                choice = opt_l[n_opt - 1] if n_opt > 0 else NEW  # round-off guard
                for i in range(n_opt):
                    if x < opt_w[i]:
                        choice = opt_l[i]
                        break
                    x -= opt_w[i]
            if s >= burn_in:
                inv = 1.0 / total
                tally_clutter[m] += wc * inv
                tally_new[m] += wn * inv
                for i in range(n_opt):
                    tally_cluster[opt_l[i], m] += opt_w[i] * inv
            c[m] = choice
            if choice >= 0:
                cnt[choice] += 1
                m_obj += 1
            elif choice == NEW:
                k_new += 1
                m_obj += 1


if _njit is not None and os.environ.get("BNPTRACK_NO_JIT") != "1":
    _sweeps = _njit(cache=True, nogil=True)(_sweep_kernel)
else:  # pragma: no cover - numba missing or disabled: same code, interpreted
    _sweeps = _sweep_kernel


def run_gibbs(
    problem: GibbsProblem,
    rng: np.random.Generator,
    sweeps: int,
    burn_in: int,
    init: np.ndarray | None = None,
) -> GibbsResult:
    """Run ``sweeps`` systematic-scan sweeps; average the last ``sweeps - burn_in``."""
    N, M = problem.log_first.shape
    c = (initial_assignment(problem) if init is None else np.asarray(init)).astype(np.int64)
    cnt = np.bincount(c[c >= 0], minlength=N).astype(np.int64)
    u = rng.random((sweeps, M))
    cand = _candidates(problem)
    tally_cluster = np.zeros((N, M))
    tally_clutter = np.zeros(M)
    tally_new = np.zeros(M)
    _sweeps(c, cnt, int(np.sum(c == NEW)), int(np.sum(c != CLUTTER)), problem.alpha + problem.mass,
            float(problem.alpha), float(problem.d), float(problem.d_bar), bool(problem.extended),
            cand.w_clutter, cand.w_new, cand.ptr, cand.idx, cand.w_first, cand.w_lik,
            np.asarray(problem.popularity, dtype=float), u, int(burn_in),
            tally_cluster, tally_clutter, tally_new, np.zeros(max(N, 1), np.int64), np.zeros(max(N, 1)))
    kept = max(sweeps - burn_in, 1)
    return GibbsResult(tally_cluster / kept, tally_clutter / kept, tally_new / kept, c,
                       log_joint(problem, c), kept)


def log_joint(problem: GibbsProblem, c: np.ndarray) -> float:
    r"""Unnormalised log posterior of an assignment vector (point or extended objects).

    The product of the conditional weights in any order (the joint is exchangeable):
    clutter terms, the urn normaliser :math:`\prod_{i<M_o} (\alpha+V)/(\alpha+V+i)`,
    first/subsequent members of transitioned clusters and the new-cluster weights.
    """
    out = 0.0
    k_new = 0
    m_obj = 0
    total_mass = problem.alpha + problem.mass
    counts: dict[int, int] = {}
    for m, ch in enumerate(np.asarray(c).tolist()):
        if ch == CLUTTER:
            out += problem.log_clutter[m]
            continue
        out += math.log(total_mass / (total_mass + m_obj))
        m_obj += 1
        if ch == NEW:
            out += math.log(problem.alpha + problem.d * (problem.d_bar + k_new)) + problem.log_new[m]
            k_new += 1
        else:
            n = counts.get(ch, 0)
            if n == 0:
                out += problem.log_first[ch, m]
            elif problem.extended:
                out += math.log(n + problem.popularity[ch] - problem.d) + problem.log_lik[ch, m]
            else:
                return -math.inf
            counts[ch] = n + 1
    return out
