"""The dependent Polya urn (EPPF, partition law) and the frame Gibbs sampler (exactness, Geweke)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats
from scipy.special import gammaln

from bnptrack.tracker.bnp.gibbs import CLUTTER, NEW, GibbsProblem, log_joint, run_gibbs
from bnptrack.tracker.bnp.urn import (
    frame_loglik_grid,
    gibbs_partition_sweep,
    log_eppf,
    sample_crp_partition,
)


def set_partitions(n):
    """All set partitions of range(n) as canonical label vectors."""
    def rec(i, labels, k):
        if i == n:
            yield tuple(labels)
            return
        for j in range(k + 1):
            yield from rec(i + 1, labels + [j], max(k, j + 1))
    yield from rec(0, [], 0)


def sizes_of(labels):
    return np.bincount(np.asarray(labels))


def canonical(labels):
    seen = {}
    return tuple(seen.setdefault(x, len(seen)) for x in labels)


# --- EPPF --------------------------------------------------------------------------------


def test_crp_eppf_hand_values():
    # n = 3, alpha = 1: one table has prob 2!/(1*2*3) = 1/3; all singletons 1/(1*2*3) = 1/6
    assert math.exp(log_eppf([3], 1.0)) == pytest.approx(1 / 3)
    assert math.exp(log_eppf([1, 1, 1], 1.0)) == pytest.approx(1 / 6)
    # Pitman-Yor n = 2: same table (1 - d)/(alpha + 1)
    assert math.exp(log_eppf([2], 0.5, d=0.3)) == pytest.approx(0.7 / 1.5)


@pytest.mark.parametrize("alpha,d", [(1.0, 0.0), (0.7, 0.0), (1.5, 0.4), (0.2, 0.7)])
def test_eppf_sums_to_one_over_partitions(alpha, d):
    total = sum(math.exp(log_eppf(sizes_of(p), alpha, d)) for p in set_partitions(5))
    assert total == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("d", [0.0, 0.3])
def test_pre_seated_eppf_sums_to_one(d):
    """With pre-seated tables (popularity v), customers join one of them or new tables."""
    v = np.array([1.0, 2.5])
    n = 4
    total = 0.0
    # label -1, -2 = the two pre-seated tables; >= 0 new tables
    for assign in itertools.product([-1, -2, 0, 1, 2, 3], repeat=n):
        new = [a for a in assign if a >= 0]
        if new and canonical(new) != tuple(new):
            continue  # count each partition of the new tables once
        seated = np.array([sum(a == -1 for a in assign), sum(a == -2 for a in assign)])
        new_sizes = np.bincount(new) if new else np.zeros(0, int)
        total += math.exp(log_eppf(new_sizes, 0.8, d, seated, v))
    assert total == pytest.approx(1.0, abs=1e-12)


def exact_table_count_law(n, alpha, d):
    law = np.zeros(n + 1)
    for p in set_partitions(n):
        law[max(p) + 1] += math.exp(log_eppf(sizes_of(p), alpha, d))
    return law


def test_sequential_urn_draws_as_the_generators_choice_draws():
    """Each customer's table is ``rng.choice(K + 1, p=w / w.sum())``, draw for draw."""
    rng, ref = np.random.default_rng(4), np.random.default_rng(4)
    for _ in range(50):
        labels = sample_crp_partition(rng, 8, 1.5, 0.4)
        counts: list[float] = []
        for i in range(8):
            w = np.array([c - 0.4 for c in counts] + [1.5 + 0.4 * len(counts)])
            j = int(ref.choice(w.size, p=w / w.sum()))
            counts[j:j + 1] = [counts[j] + 1.0] if j < len(counts) else [1.0]
            assert labels[i] == j
    assert rng.random() == ref.random()


# 6,000 draws per case: the fast subset checks the Dirichlet process; the Pitman-Yor case is slow
@pytest.mark.parametrize("alpha,d", [(1.0, 0.0), pytest.param(2.0, 0.5, marks=pytest.mark.slow)])
def test_sequential_urn_reproduces_eppf(alpha, d):
    """Draws of the sequential urn (D1-D3 / P1-P3 weights) follow the EPPF's table-count law."""
    n, draws = 6, 6000
    rng = np.random.default_rng(11)
    counts = np.bincount([sample_crp_partition(rng, n, alpha, d).max() + 1 for _ in range(draws)], minlength=n + 1)
    law = exact_table_count_law(n, alpha, d)
    chi = stats.chisquare(counts[1:], law[1:] * draws)
    assert chi.pvalue > 1e-3


@pytest.mark.slow
def test_partition_gibbs_leaves_eppf_invariant():
    """Prior-only Gibbs over partitions with the urn's conditionals samples the PY EPPF."""
    n, alpha, d = 5, 1.2, 0.3
    rng = np.random.default_rng(5)
    labels = np.zeros(n, dtype=int)
    freq: dict[tuple, int] = {}
    sweeps = 6000
    for _ in range(sweeps):
        labels = gibbs_partition_sweep(rng, labels, alpha, d)
        key = canonical(labels)
        freq[key] = freq.get(key, 0) + 1
    parts = list(set_partitions(n))
    expected = np.array([math.exp(log_eppf(sizes_of(p), alpha, d)) for p in parts]) * sweeps
    observed = np.array([freq.get(p, 0) for p in parts])
    # group into table-count classes (enough counts per cell); Markov chain -> loose threshold
    obs_k = np.bincount([max(p) + 1 for p in parts], weights=observed)[1:]
    exp_k = np.bincount([max(p) + 1 for p in parts], weights=expected)[1:]
    assert np.allclose(obs_k / sweeps, exp_k / sweeps, atol=0.03)


def test_frame_loglik_grid_is_poisson_times_eppf():
    """frame_loglik_grid = log Poisson(M_o; alpha+V) + log M_o! + log EPPF (pre-seated urn)."""
    v = np.array([1.0, 2.0, 1.5])
    counts = np.array([1, 0, 2])
    alpha, d = 0.7, 0.25
    n_new = 2
    m_obj = counts.sum() + n_new
    got = frame_loglik_grid(np.array([alpha]), np.array([d]), mass=v.sum(), d_bar=3.0, n_object=int(m_obj),
                            n_new=n_new, seated_popularity=v, seated_counts=counts)[0]
    ref = (stats.poisson(alpha + v.sum()).logpmf(m_obj) + gammaln(m_obj + 1)
           + log_eppf(np.ones(n_new, int), alpha, d, counts, v))
    assert got == pytest.approx(ref, rel=1e-12)


# --- the frame Gibbs sampler --------------------------------------------------------------


def toy_problem(z, prior_first, mu, sigma, alpha, d, lam_c, extended=False, mass=1.7, d_bar=1.4, pop=None):
    """1-D toy: clutter and new ~ U(0,1), cluster l ~ N(mu_l, sigma)."""
    z = np.asarray(z, dtype=float)
    inside = np.where((z >= 0) & (z <= 1), 0.0, -np.inf)
    ll = stats.norm(np.asarray(mu)[:, None], sigma).logpdf(z[None, :])
    return GibbsProblem(
        log_first=np.log(prior_first)[:, None] + ll, log_lik=ll,
        log_clutter=np.log(lam_c) + inside, log_new=inside,
        popularity=np.ones(len(mu)) if pop is None else np.asarray(pop, float),
        alpha=alpha, d=d, d_bar=d_bar, mass=mass, extended=extended)


def enumerate_posterior(problem):
    N, M = problem.shape
    configs, logp = [], []
    for c in itertools.product([CLUTTER, NEW, *range(N)], repeat=M):
        lj = log_joint(problem, np.array(c))
        if np.isfinite(lj):
            configs.append(c)
            logp.append(lj)
    logp = np.array(logp)
    p = np.exp(logp - logp.max())
    return configs, p / p.sum()


@pytest.mark.parametrize("d,extended", [(0.0, False), (0.35, False), (0.2, True)])
def test_gibbs_marginals_match_exact_enumeration(d, extended):
    z = [0.30, 0.34, 0.62, 0.9]
    prob = toy_problem(z, prior_first=[3.0, 0.8], mu=[0.31, 0.6], sigma=0.05, alpha=0.6, d=d, lam_c=2.0,
                       extended=extended, pop=[1.0, 2.0])
    configs, p = enumerate_posterior(prob)
    N, M = prob.shape
    exact_cluster = np.zeros((N, M))
    exact_clutter = np.zeros(M)
    exact_new = np.zeros(M)
    for c, pc in zip(configs, p):
        for m, ch in enumerate(c):
            if ch == CLUTTER:
                exact_clutter[m] += pc
            elif ch == NEW:
                exact_new[m] += pc
            else:
                exact_cluster[ch, m] += pc
    # two measurements compete for cluster 0: single-site moves swap them slowly, so run long
    res = run_gibbs(prob, np.random.default_rng(3), sweeps=30000, burn_in=100)
    np.testing.assert_allclose(res.p_clutter, exact_clutter, atol=0.015)
    np.testing.assert_allclose(res.p_new, exact_new, atol=0.015)
    np.testing.assert_allclose(res.p_cluster, exact_cluster, atol=0.015)
    if not extended:  # point objects: no cluster ever holds two measurements
        assert np.all(res.p_cluster.sum(axis=1) <= 1.0 + 1e-9)


@pytest.mark.slow  # 4,000 sweeps of the interpreted kernels; the fast subset keeps the compiled ones' (above)
def test_exchange_uniforms_drawn_per_proposal_keep_the_exact_marginals(monkeypatch):
    """Exchange passes drawing one uniform per scored proposal (lists above
    ``swap_moves.PREDRAWN_PAIRS``, here every list: the limit set to 0, the kernels
    interpreted so that it is read) give the enumerated marginals."""
    import bnptrack.tracker.bnp.gibbs as g
    from bnptrack.tracker.bnp import swap_moves

    prob = toy_problem([0.30, 0.34, 0.62, 0.9], prior_first=[3.0, 0.8], mu=[0.31, 0.6], sigma=0.05, alpha=0.6,
                       d=0.35, lam_c=2.0, pop=[1.0, 2.0])
    configs, p = enumerate_posterior(prob)
    exact_cluster = np.zeros(prob.shape)
    for c, pc in zip(configs, p):
        for m, ch in enumerate(c):
            if ch >= 0:
                exact_cluster[ch, m] += pc
    for module, name, fn in g.interpreted_kernels():
        monkeypatch.setattr(module, name, fn)
    monkeypatch.setattr(swap_moves, "PREDRAWN_PAIRS", 0)
    res = run_gibbs(prob, np.random.default_rng(3), sweeps=4000, burn_in=100, chains=2)
    assert res.swaps_accepted > 100
    np.testing.assert_allclose(res.p_cluster, exact_cluster, atol=0.02)


@pytest.mark.slow
def test_geweke_getting_it_right():
    """Marginal-conditional vs successive-conditional simulation of (c, z) agree (Geweke 2004)."""
    mu, sigma, prior_first, alpha, d, lam_c = [0.3, 0.7], 0.08, [2.0, 1.0], 0.5, 0.2, 1.5
    M = 3
    base = toy_problem(np.full(M, 0.5), prior_first, mu, sigma, alpha, d, lam_c)
    # exact prior over c: log_joint with the likelihood terms removed
    prior_problem = GibbsProblem(np.log(prior_first)[:, None] * np.ones((1, M)), np.zeros((2, M)),
                                 np.full(M, np.log(lam_c)), np.zeros(M), base.popularity, alpha, d,
                                 base.d_bar, base.mass)
    configs, p_prior = enumerate_posterior(prior_problem)
    rng = np.random.default_rng(2024)

    def draw_z(c):
        return np.array([rng.uniform() if ch < 0 else rng.normal(mu[ch], sigma) for ch in c])

    def stat(c):
        c = np.asarray(c)
        return np.array([np.sum(c == CLUTTER), np.sum(c == NEW), np.sum(c == 0), np.sum(c == 1)])

    n = 6000
    mc = np.array([stat(configs[i]) for i in rng.choice(len(configs), size=n, p=p_prior)])
    c = np.array(configs[0])
    sc = []
    for _ in range(n):
        z = draw_z(c)
        prob = toy_problem(z, prior_first, mu, sigma, alpha, d, lam_c)
        c = run_gibbs(prob, rng, sweeps=1, burn_in=0, init=c).last
        sc.append(stat(c))
    sc = np.array(sc)
    # successive draws are autocorrelated: compare means with a generous batch-means error
    for j in range(mc.shape[1]):
        batch = sc[:, j].reshape(60, -1).mean(axis=1)
        se = np.hypot(mc[:, j].std() / np.sqrt(n), batch.std() / np.sqrt(batch.size))
        assert abs(mc[:, j].mean() - sc[:, j].mean()) < 4 * se + 1e-3, (j, mc[:, j].mean(), sc[:, j].mean())


def test_gibbs_is_deterministic_given_generator():
    prob = toy_problem([0.3, 0.5, 0.61], [1.0, 1.0], [0.3, 0.6], 0.05, 0.5, 0.0, 2.0)
    a = run_gibbs(prob, np.random.default_rng(9), 50, 10)
    b = run_gibbs(prob, np.random.default_rng(9), 50, 10)
    np.testing.assert_array_equal(a.p_cluster, b.p_cluster)
    np.testing.assert_array_equal(a.last, b.last)


def test_compiled_kernel_equals_interpreted(monkeypatch):
    """The numba-compiled sweeps and the same functions run by the interpreter agree exactly:
    every kernel name of every module the sampler's kernels live in (also the names they import
    from one another) is rebound to its Python function."""
    import bnptrack.tracker.bnp.gibbs as g
    from bnptrack.tracker import numerics

    prob = toy_problem([0.3, 0.5, 0.61, 0.33, 0.95], [1.0, 2.0], [0.3, 0.6], 0.05, 0.5, 0.25, 2.0,
                       extended=True, pop=[1.0, 3.0])
    compiled = run_gibbs(prob, np.random.default_rng(1), 200, 20)
    bindings = g.interpreted_kernels()
    if numerics.JIT:
        names = {(module.__name__.rpartition(".")[2], name) for module, name, _ in bindings}
        assert {("gibbs", "_chains_kernel"), ("gibbs", "_sweeps"), ("gibbs_sweeps", "_site_pass"),
                ("gibbs_sweeps", "_swap_pass"), ("gibbs_setup", "_exchange_pairs"), ("gibbs_setup", "_greedy"),
                ("gibbs_diagnostics", "np_sum"), ("swap_moves", "_members")} <= names
    for module, name, fn in bindings:
        monkeypatch.setattr(module, name, fn)
    assert g.interpreted_kernels() == []  # no kernel is left bound in the sampler's modules
    interpreted = run_gibbs(prob, np.random.default_rng(1), 200, 20)
    np.testing.assert_array_equal(compiled.last, interpreted.last)
    np.testing.assert_allclose(compiled.p_cluster, interpreted.p_cluster, rtol=1e-12, atol=0)
    np.testing.assert_allclose(compiled.p_new, interpreted.p_new, rtol=1e-12, atol=0)


def test_grid_mean_hand_values():
    """Posterior means of (alpha, d) on a 2 x 2 grid with weights 1, 1, 2, 4 (hand-computed)."""
    from bnptrack.tracker.bnp.urn import grid_mean

    log_post = np.log(np.array([[1.0, 1.0], [2.0, 4.0]])) + 7.0  # an offset must not matter
    a, d = grid_mean(log_post, np.array([0.1, 1.0]), np.array([0.0, 0.5]))
    assert a == pytest.approx((2 * 0.1 + 6 * 1.0) / 8)
    assert d == pytest.approx((5 * 0.5) / 8)


# --- mixing: pair exchanges, two chains, split R-hat -----------------------------------------


def contested_toy():
    """Two measurements at 0.29 and 0.33 compete for one cluster at 0.31 (exact 0.4707)."""
    return toy_problem([0.29, 0.33], [3.0], [0.31], 0.05, 0.6, 0.0, 2.0)


def test_split_rhat_matches_bda3_formula():
    """split_rhat from sums and sums of squares equals BDA3 eq. 11.4 on the raw half-chains."""
    from bnptrack.tracker.bnp.gibbs import split_rhat

    rng = np.random.default_rng(8)
    n = 7
    x = rng.random((4, n, 3)) * np.array([1.0, 0.2, 0.0])  # third quantity constant: ignored
    x[2:, :, 0] += 0.3  # chain 2 sits higher on the first quantity
    hs, hss = x.sum(axis=1), (x**2).sum(axis=1)
    means = x.mean(axis=1)
    W = x[:, :, :2].var(axis=1, ddof=1).mean(axis=0)
    B = n * means[:, :2].var(axis=0, ddof=1)
    ref = np.sqrt(((n - 1) / n * W + B / n) / W).max()
    assert split_rhat(hs, hss, n) == pytest.approx(ref, rel=1e-12)
    assert ref > 1.2
    assert split_rhat(np.zeros((2, 3)), np.zeros((2, 3)), 5) == 1.0  # nothing varies
    assert split_rhat(hs, hss, 1) == 1.0  # undefined: reported as 1


def test_pair_exchanges_cut_the_toy_run_to_run_sd():
    """30 sweeps on the contested toy (benchmarks/gibbs_mixing.py measures 200 runs: SD 0.25
    single-site, 0.02 with exchanges and two chains)."""
    prob = contested_toy()
    old = [run_gibbs(prob, np.random.default_rng(i), 30, 5, swaps=False).p_cluster[0, 0] for i in range(60)]
    new = [run_gibbs(prob, np.random.default_rng(i), 30, 5, chains=2).p_cluster[0, 0] for i in range(60)]
    assert np.std(old) > 0.15
    assert np.std(new) < 0.05 and abs(np.mean(new) - 0.4707) < 0.02


def test_two_chains_expose_a_stuck_sampler():
    """Single-site moves from the two greedy starts mostly never meet on the contested toy
    (benchmarks/gibbs_mixing.py: R-hat > 1.1 in 76.5 % of 200 runs); with exchanges the chains
    mix (0 %)."""
    from bnptrack.tracker.bnp.gibbs import initial_assignment

    prob = contested_toy()
    # the reversed greedy start gives the contested cluster to the other measurement
    assert initial_assignment(prob)[0] != initial_assignment(prob, reverse=True)[0]
    stuck = [run_gibbs(prob, np.random.default_rng(i), 30, 5, swaps=False, chains=2) for i in range(40)]
    mixed = [run_gibbs(prob, np.random.default_rng(i), 30, 5, chains=2) for i in range(40)]
    assert np.mean([r.rhat_max > 1.1 for r in stuck]) > 0.5
    assert np.median([r.rhat_max for r in stuck]) > 1.2
    assert all(r.swaps_proposed == 0 for r in stuck)
    assert np.mean([r.rhat_max > 1.1 for r in mixed]) < 0.05
    assert all(r.swaps_proposed == 60 and r.swaps_accepted > 10 for r in mixed)
