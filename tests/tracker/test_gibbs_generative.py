r"""The tracker's Gibbs weights against a forward simulation of the stated generative model.

``tests/tracker/test_urn_gibbs.py`` checks the sampler against ``log_joint`` (enumeration, Geweke), so
it cannot see a wrong weight in ``BnpTracker._problem``, which turns a tracker state into the
``GibbsProblem``.  Here the reference is a simulator of ``docs/trackers.md`` "One frame",
step 2, written from the model statement and sharing no code with the sampler (``tracker/bnp/gibbs*.py``):

* each cluster ``l`` exists (``q_l``) and, if it does, is detected (``P_D``);
* ``M_o ~ Poisson(alpha + V)`` object-originated measurements, ``V = sum_l q_l v_l``, are
  seated in measurement order by the dependent (Pitman-Yor) urn with pre-seated clusters of
  mass ``v_l``: cluster ``l`` with weight ``v_l - d + n_l``, a new cluster with
  ``alpha + d (D_bar + K_new)``, an opened new cluster with ``n - d``;
* ``M_c ~ Poisson(lambda_c)`` clutter; which of the ``M = M_c + M_o`` measurements are
  clutter is a uniformly random subset;
* point objects: a draw in which a cluster (old or new) takes two measurements, or in which
  the clusters that took a measurement are not exactly the detected ones, is rejected;
* measurement densities: clutter ``kappa`` = uniform on ``[0, range_max]``; cluster ``l``
  ``N(z; z_hat_l, S_l)`` (its UKF predictive); a new cluster ``u_H`` (the base distribution's
  predictive, ``BaseDistribution.log_predictive``: the one term taken from the tracker).

The posterior of the assignments given the observed ``z`` is estimated by importance
weighting prior draws with ``M`` equal to the observed count by the likelihood of ``z``; it is
compared with the exact marginals of the tracker-built ``GibbsProblem`` (enumeration) and with
``run_gibbs`` on it.  The urn is a proper probability law only when ``D_bar = sum_l q_l``
equals the number of clusters and ``V`` their total mass, i.e. ``q_l = 1``; that is the case
tested (``P_S = 1``, existence 1).  For ``q_l < 1`` the tracker uses the expected urn mass
``V = sum q_l v_l`` in place of the random mass of the surviving clusters, an approximation
this test does not cover.  A control asserts that the comparison is sharp enough to reject a
construction without the missed-detection normalisation of the D2 weight.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import msgspec
import numpy as np
import pytest
from scipy import stats

from bnptrack.tracker.bnp import TRACKER_PRESETS, BnpState, make_tracker
from bnptrack.tracker.bnp.gibbs import CLUTTER, NEW, log_joint, run_gibbs
from bnptrack.tracker.models.params import load_params

PD, LAM_C, RANGE_MAX = 0.8, 1.5, 2000.0


def forward_draws(rng, n, pd, v, alpha, d, lam_c, m_obs):
    """Assignment vectors ``(K, m_obs)`` of the accepted draws among ``n`` prior simulations
    (vectorised over simulations, sequential over the urn's customers).  Only the simulations
    with ``M = M_c + M_o = m_obs`` are drawn: their number is Binomial(``n``, Pr(M = m_obs)),
    ``M ~ Poisson(alpha + V + lambda_c)``, and given ``M`` the object-originated count is
    ``M_o ~ Binomial(M, (alpha + V) / (alpha + V + lambda_c))`` (two independent Poisson counts
    given their sum)."""
    N = len(v)
    V = float(np.sum(v))  # q = 1
    rate = alpha + V + lam_c
    n = rng.binomial(n, stats.poisson.pmf(m_obs, rate))
    n_o = rng.binomial(m_obs, (alpha + V) / rate, n)
    detected = rng.random((n, N)) < pd
    taken = np.zeros((n, N))
    k_new = np.zeros(n)
    ok = np.ones(n, dtype=bool)
    seats = np.full((n, m_obs), CLUTTER)
    for i in range(m_obs):
        # urn weights: clusters v_l - d + n_l, a new cluster alpha + d (N + K), the K opened ones (1 - d) each
        w = np.column_stack([v - d + taken, alpha + d * (N + k_new), k_new * (1.0 - d)])
        total = w.sum(axis=1)
        seated = i < n_o
        assert np.allclose(total[seated & ok], alpha + V + i)  # the docs' normaliser alpha + V + M_o
        j = np.sum(np.cumsum(w, axis=1) < rng.random(n)[:, None] * total[:, None], axis=1)
        j = np.minimum(j, N + 1)
        row = np.flatnonzero(seated & (j < N))
        ok[row] &= taken[row, j[row]] == 0  # point objects: one measurement per cluster
        taken[row, j[row]] += 1
        ok &= ~(seated & (j == N + 1))  # ... and per new cluster
        k_new += seated & (j == N)
        seats[:, i] = np.where(j < N, j, NEW)
    ok &= np.all((taken > 0) == detected, axis=1)  # the clusters that took one are the detected ones
    # which measurements are object-originated: a uniformly random subset, seated in order
    rank = np.argsort(np.argsort(rng.random((n, m_obs)), axis=1), axis=1)
    is_obj = rank < n_o[:, None]
    order = np.cumsum(is_obj, axis=1) - 1
    c = np.where(is_obj, np.take_along_axis(seats, np.maximum(order, 0), axis=1), CLUTTER)
    return c[ok]


def marginals(configs, weights, N, M):
    p = np.zeros((N + 2, M))  # rows: clusters, clutter, new
    for c, w in zip(configs, weights):
        for m, ch in enumerate(c):
            p[ch if ch >= 0 else (N if ch == CLUTTER else N + 1), m] += w
    return p / np.sum(weights)


def setup(d):
    params = msgspec.structs.replace(load_params("vo2017"), p_survival=1.0, p_detect=PD, range_clutter_rate=LAM_C,
                                     range_max=RANGE_MAX, birth=[])
    tr = make_tracker("dpyp-mb" if d else "ddp-mb", params, msgspec.structs.replace(TRACKER_PRESETS["ddp-mb"], d=d))
    mean = np.array([[0.0, 0.0, 800.0, 0.0, 0.0], [0.0, 0.0, 835.0, 0.0, 0.0]])
    cov = np.tile(np.diag([100.0, 4.0, 100.0, 4.0, 1e-6]), (2, 1, 1))
    state = BnpState(0, 0, ("a", "b"), mean, cov, np.ones(2), np.array([1.0, 2.5]), 0.4, d)
    meas, clutter = params.measurement("range"), params.clutter("range")
    pred = tr._predict(state, 1, "range")
    innov = tr._innovation(meas, pred)
    z_hat, sd = innov.z_pred[:, 0], np.sqrt(innov.S[:, 0, 0])
    Z = np.array([z_hat[0] + 1.2 * sd[0], z_hat[0] - 1.6 * sd[0], z_hat[1] + 2.4 * sd[1], 1500.0])[:, None]
    problem = tr._problem(state, pred, innov, meas, clutter, Z)
    # the stated densities, computed here (u_H from the tracker's base distribution)
    dens = np.vstack([stats.norm(z_hat[:, None], sd[:, None]).pdf(Z[:, 0][None]),
                      np.full((1, Z.shape[0]), 1.0 / RANGE_MAX),
                      np.exp(tr.base.log_predictive(meas, clutter, Z))[None]])
    return state, pred, problem, dens


def likelihood(c, dens, N):
    return np.prod([dens[ch if ch >= 0 else (N if ch == CLUTTER else N + 1), m] for m, ch in enumerate(c)])


def exact(problem):
    N, M = problem.shape
    cfg = list(itertools.product([CLUTTER, NEW, *range(N)], repeat=M))
    lj = np.array([log_joint(problem, np.array(c)) for c in cfg])
    return marginals(cfg, np.exp(lj - lj.max()), N, M)


# 4,000,000 forward draws per case: the fast subset checks the Dirichlet process (d = 0), the
# Pitman-Yor case is marked slow
@pytest.mark.parametrize("d", [0.0, pytest.param(0.3, marks=pytest.mark.slow)])
def test_tracker_weights_match_forward_simulation(d):
    state, pred, problem, dens = setup(d)
    assert np.allclose(pred.q, 1.0) and np.allclose(pred.p_detect, PD)  # the tested case: q = 1
    N, M = problem.shape
    rng = np.random.default_rng(20261201)
    # 4,000,000 prior draws in blocks of 500,000 (arrays that stay in cache; same law)
    configs = np.concatenate([forward_draws(rng, 500_000, PD, state.popularity, state.alpha, d, LAM_C, M)
                              for _ in range(8)])
    uniq, counts = np.unique(configs, axis=0, return_counts=True)
    w = counts * np.array([likelihood(c, dens, N) for c in uniq])
    ess = w.sum() ** 2 / np.sum(w**2 / counts)  # each draw of a pattern carries weight w / count
    sim = marginals([tuple(c) for c in uniq], w, N, M)
    se = np.sqrt(sim * (1 - sim) / ess)
    tol = 5 * se + 0.01
    ex = exact(problem)
    assert ess > 2000
    assert np.all(np.abs(ex - sim) < tol), (ex.round(3), sim.round(3), tol.round(3))
    res = run_gibbs(problem, np.random.default_rng(4), 4000, 50, chains=2)
    gibbs = np.vstack([res.p_cluster, res.p_clutter, res.p_new])
    assert np.all(np.abs(gibbs - sim) < tol + 0.01)
    # control: without the missed-detection normalisation (q P_D instead of q P_D / (1 - q P_D))
    miss = np.log(1.0 - pred.q * pred.p_detect)
    # (the tracker builds the sparse form; the dense one is rebuilt here for the control)
    bad = exact(replace(problem, log_first=problem.dense_first() + miss[:, None],
                        log_lik=problem.pairs.dense(problem.pairs.log_lik)))
    assert np.max(np.abs(bad - sim) - 5 * se) > 0.02
