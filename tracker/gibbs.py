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

The kernel loops over measurements in plain Python on precomputed weights (the number of
candidates per measurement is small after gating), using uniforms pre-drawn from the caller's
``numpy.random.Generator`` so the result depends only on the generator's state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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
    """Greedy start: each measurement to its best free cluster if that beats clutter and new."""
    N, M = problem.log_first.shape
    c = np.full(M, CLUTTER, dtype=int)
    taken = np.zeros(N, dtype=bool)
    if N == 0 or M == 0:
        return c
    order = np.argsort(-problem.log_first.max(axis=0))
    for m in order:
        col = np.where(taken, -np.inf, problem.log_first[:, m])
        l = int(np.argmax(col))
        alt = max(problem.log_clutter[m], math.log(problem.alpha + problem.d * problem.d_bar) + problem.log_new[m])
        if col[l] > alt:
            c[m] = l
            if not problem.extended:
                taken[l] = True
    return c


def _candidates(problem: GibbsProblem):
    """Per measurement: shift, clutter weight, new base weight, and (cluster, w_first, w_lik)."""
    N, M = problem.log_first.shape
    out = []
    for m in range(M):
        idx = np.flatnonzero(np.isfinite(problem.log_first[:, m])) if N else np.zeros(0, int)
        logs = [problem.log_clutter[m], problem.log_new[m]]
        logs.extend(problem.log_first[idx, m])
        if problem.extended:
            logs.extend(problem.log_lik[idx, m])
        shift = max(logs)
        wf = np.exp(problem.log_first[idx, m] - shift).tolist()
        wl = np.exp(problem.log_lik[idx, m] - shift).tolist() if problem.extended else [0.0] * idx.size
        out.append(
            (math.exp(problem.log_clutter[m] - shift), math.exp(problem.log_new[m] - shift),
             list(zip(idx.tolist(), wf, wl)))
        )
    return out


def run_gibbs(
    problem: GibbsProblem,
    rng: np.random.Generator,
    sweeps: int,
    burn_in: int,
    init: np.ndarray | None = None,
) -> GibbsResult:
    """Run ``sweeps`` systematic-scan sweeps; average the last ``sweeps - burn_in``."""
    N, M = problem.log_first.shape
    c = initial_assignment(problem) if init is None else init.copy()
    counts = np.zeros(N, dtype=int)
    for m in range(M):
        if c[m] >= 0:
            counts[c[m]] += 1
    k_new = int(np.sum(c == NEW))
    m_obj = int(np.sum(c != CLUTTER))
    total_mass = problem.alpha + problem.mass
    cands = _candidates(problem)
    pop = problem.popularity.tolist()
    alpha, d, d_bar, ext = problem.alpha, problem.d, problem.d_bar, problem.extended
    u_all = rng.random((sweeps, M))
    tally_cluster = np.zeros((N, M))
    tally_clutter = np.zeros(M)
    tally_new = np.zeros(M)
    cl = c.tolist()
    cnt = counts.tolist()

    for s in range(sweeps):
        u_row = u_all[s]
        for m in range(M):
            cur = cl[m]
            if cur >= 0:
                cnt[cur] -= 1
                m_obj -= 1
            elif cur == NEW:
                k_new -= 1
                m_obj -= 1
            w_clutter, w_newbase, cand = cands[m]
            g = total_mass / (total_mass + m_obj)
            w_new = g * w_newbase * (alpha + d * (d_bar + k_new))
            opts = []
            total = w_clutter + w_new
            for l, wf, wl in cand:
                n = cnt[l]
                if n == 0:
                    w = g * wf
                elif ext:
                    w = g * wl * (n + pop[l] - d)
                else:
                    continue
                if w > 0.0:
                    opts.append((l, w))
                    total += w
            u = u_row[m] * total
            if u < w_clutter:
                choice = CLUTTER
            elif u < w_clutter + w_new:
                choice = NEW
            else:
                u -= w_clutter + w_new
                choice = opts[-1][0] if opts else NEW  # round-off guard
                for l, w in opts:
                    if u < w:
                        choice = l
                        break
                    u -= w
            if s >= burn_in:  # Rao-Blackwellised tallies: the conditional, not the draw
                inv = 1.0 / total
                tally_clutter[m] += w_clutter * inv
                tally_new[m] += w_new * inv
                for l, w in opts:
                    tally_cluster[l, m] += w * inv
            cl[m] = choice
            if choice >= 0:
                cnt[choice] += 1
                m_obj += 1
            elif choice == NEW:
                k_new += 1
                m_obj += 1
    kept = max(sweeps - burn_in, 1)
    last = np.array(cl, dtype=int)
    return GibbsResult(
        tally_cluster / kept, tally_clutter / kept, tally_new / kept, last,
        log_joint(problem, last), kept,
    )


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
