"""The compiled passes of the DDP-EMM / DPY-STP step (tracker/bnp/_*kernels.py, gibbs*.py's drivers)
against the numpy code they replaced (kept here as the reference), bit for bit, on seed-pinned
random inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from bnptrack.tracker._lsap import lsap
from bnptrack.tracker.bnp import _birth_kernels as kb
from bnptrack.tracker.bnp import _estimate_kernels as ke
from bnptrack.tracker.bnp import _merge_kernels as km
from bnptrack.tracker.bnp import _update_kernels as ku
from bnptrack.tracker.bnp import _kernels as k
from bnptrack.tracker.bnp import gibbs as g
from bnptrack.tracker.bnp import gibbs_setup, gibbs_sweeps, swap_moves
from bnptrack.tracker.bnp.assignment import best_permutation_pairs
from bnptrack.tracker.bnp.clusters import _POS_VEL, _birth_frame, _Clusters, merge_duplicates
from bnptrack.tracker.cardinality import existence_cardinality

_EPS = 1e-12


def _same(a, b) -> None:
    """Equal bit for bit (nan where nan; signed zeros equal)."""
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b), strict=True)


# -- numpy references of the compiled passes ----------------------------------------------------

def _merge_reference(c: _Clusters, max_d2: float) -> _Clusters:
    n = len(c.labels)
    r = c.existence
    ii, jj = np.triu_indices(n, k=1)
    both = r[ii] + r[jj] <= 1.0
    ii, jj = ii[both], jj[both]
    if ii.size == 0:
        return c
    diff = c.mean[ii][:, _POS_VEL] - c.mean[jj][:, _POS_VEL]
    S = (c.cov[ii] + c.cov[jj])[:, _POS_VEL][:, :, _POS_VEL]
    d2 = np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])
    near = d2 <= max_d2
    nb: dict[int, set[int]] = {}
    for i, j in zip(ii[near].tolist(), jj[near].tolist()):
        nb.setdefault(i, set()).add(j)
        nb.setdefault(j, set()).add(i)
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(-r, kind="stable")] = np.arange(n)
    free, groups = np.ones(n, dtype=bool), []
    for i in sorted(nb, key=rank.__getitem__):
        if not free[i]:
            continue
        group, total = [i], r[i]
        for j in sorted(nb[i], key=rank.__getitem__):
            if free[j] and total + r[j] <= 1.0:
                group.append(j)
                total += r[j]
        free[group] = False
        if len(group) > 1:
            groups.append(group)
    if not groups:
        return c
    mean, cov, rr, labels = c.mean.copy(), c.cov.copy(), c.existence.copy(), list(c.labels)
    leaders = np.array([gr[0] for gr in groups])
    members = np.concatenate([np.asarray(gr) for gr in groups])
    gk = np.repeat(leaders, [len(gr) for gr in groups])
    w = c.existence[members]
    rr[leaders] = np.bincount(gk, weights=w, minlength=n)[leaders]
    w = w / rr[gk]
    mean[leaders] = 0.0
    np.add.at(mean, gk, w[:, None] * c.mean[members])
    dev = c.mean[members] - mean[gk]
    cov[leaders] = 0.0
    np.add.at(cov, gk, w[:, None, None] * (c.cov[members] + dev[:, :, None] * dev[:, None, :]))
    for gr in groups:
        labels[gr[0]] = min((c.labels[i] for i in gr), key=_birth_frame)
    keep = np.setdiff1d(np.arange(n), np.concatenate([np.asarray(gr[1:]) for gr in groups]))
    return _Clusters(tuple(labels[i] for i in keep.tolist()), mean[keep], cov[keep], np.minimum(rr[keep], 1.0),
                     c.popularity[keep])


def _run_gibbs_reference(problem, rng, sweeps, burn_in, swaps=True, chains=1):
    N, M = problem.shape
    cand = gibbs_setup._candidates(problem)
    pair_a, pair_b = g.swap_pairs(problem) if swaps and N else (np.zeros(0, np.int64), np.zeros(0, np.int64))
    K = cand.idx.size + 2 * M
    tally_pair, tally_cn = np.zeros(cand.idx.size), np.zeros((2, M))
    hs, hss = np.zeros((2 * chains, K)), np.zeros((2 * chains, K))
    par = np.array([problem.alpha + problem.mass, problem.alpha, problem.d, problem.d_bar,
                    1.0 if problem.urn_normaliser else 0.0])
    scratch = (np.zeros(max(N, 1), np.int64), np.zeros(max(N, 1)), np.zeros(max(N, 1), np.int64))
    accepted, first = 0, None
    for ch in range(chains):
        c = g.initial_assignment(problem, reverse=ch % 2 == 1).astype(np.int64)
        cnt = np.bincount(c[c >= 0], minlength=N).astype(np.int64)
        st = np.array([np.sum(c == g.NEW), np.sum(c != g.CLUTTER)], dtype=np.int64)
        u = rng.random((sweeps, M))  # then each exchange pass draws one uniform per pair from rng
        accepted += gibbs_sweeps._sweeps(c, cnt, st, par, bool(problem.extended), cand.w_clutter, cand.w_new,
                                         cand.ptr, cand.idx, cand.w_first, cand.w_lik,
                                         np.asarray(problem.popularity, float), u, rng, pair_a, pair_b, burn_in,
                                         2 * ch, tally_pair, tally_cn, hs, hss, *scratch,
                                         swap_moves.exchange_tables(cand.ptr, cand.idx, N, pair_a, pair_b,
                                                                    cand.w_first, swap_moves.MAX_BYTES,
                                                                    swap_moves.PAIR_MEMBERS))
        first = c if first is None else first
    kept = max(sweeps - burn_in, 1) * chains
    return (tally_pair / kept, tally_cn[0] / kept, tally_cn[1] / kept, first, g.log_joint(problem, first),
            g.split_rhat(hs, hss, (sweeps - burn_in) // 2), accepted)


def _best_permutation_reference(n, ti, mi, p):
    p_det = np.bincount(ti, weights=p, minlength=n)
    live = (p > 0.0) & (p_det[ti] > 1e-9)
    ti, mi, p = ti[live], mi[live], p[live]
    if ti.size == 0:
        return ti, mi, p
    order = np.lexsort((mi, -p, ti))
    first = order[np.r_[True, np.diff(ti[order]) != 0]]
    clusters, choice = ti[first], mi[first].copy()
    if np.unique(choice).size < choice.size:
        pos = np.searchsorted(clusters, ti)
        cols, c_idx = np.unique(mi, return_inverse=True)
        L, C = clusters.size, cols.size
        cost = np.full((L, C + L), 1e6)
        cost[pos, c_idx] = np.minimum(-np.log(p), 1e6)
        cost[pos, C + pos] = -np.log(np.maximum(1.0 - p_det[ti], 1e-300))
        rr, cc = linear_sum_assignment(cost)
        hit = cc < C
        choice[rr[hit]] = cols[cc[hit]]
    return clusters, choice, p_det[clusters]


# -- tests ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [0, 1, 5, 8, 9, 16, 17, 127, 128, 129, 136, 255, 256, 1000, 4099])
def test_np_sum_is_numpys_pairwise_sum(n):
    rng = np.random.default_rng(n)
    a = rng.normal(size=n + 3) * 10.0 ** rng.uniform(-8, 8, n + 3)
    assert k.np_sum(a, 3, n) == np.sum(a[3:])
    assert k.np_sum(a, 0, n) == np.sum(a[:n])


def _random_clusters(rng, n):
    """Clusters in a 300 m square, many of them duplicates of another (a few metres off)."""
    mean = np.zeros((n, 5))
    mean[:, [0, 2]] = rng.uniform(0, 300, (n, 2))
    mean[:, [1, 3]] = rng.normal(0, 10, (n, 2))
    dup = rng.random(n) < 0.5
    src = rng.integers(0, n, n)
    mean[dup] = mean[src[dup]] + rng.normal(0, 3, (dup.sum(), 5))
    A = rng.normal(size=(n, 5, 5))
    cov = A @ A.transpose(0, 2, 1) * rng.uniform(1, 60, (n, 1, 1)) + np.eye(5)
    labels = tuple(f"{rng.integers(0, 30)}.{i}" for i in range(n))
    return _Clusters(labels, mean, cov, rng.uniform(0.01, 0.9, n), rng.uniform(1, 3, n))


@pytest.mark.parametrize("seed", range(8))
def test_merge_duplicates_equals_the_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    c = _random_clusters(rng, int(rng.integers(2, 60)))
    got, want = merge_duplicates(c, 9.0), _merge_reference(c, 9.0)
    assert got.labels == want.labels and len(got.labels) < len(c.labels)
    for a in ("mean", "cov", "existence", "popularity"):
        _same(getattr(got, a), getattr(want, a))


@pytest.mark.parametrize("n", [230, 40])
def test_merge_duplicates_equals_the_reference_with_undecided_pairs(n):
    """Above 200 clusters (KD-tree candidates, all decided by ``np.linalg.solve``) and with a
    pair exactly at the threshold (left to ``np.linalg.solve`` by the kernel): the same merge."""
    rng = np.random.default_rng(n)
    c = _random_clusters(rng, n)
    c.mean[1] = c.mean[0]
    c.mean[1, 0] += 30.0
    c.cov[:2] = np.diag([50.0, 50.0, 50.0, 50.0, 1e-4])
    c.existence[:2] = 0.3, 0.4  # d^2 = 30^2 / 100 = 9: at the threshold
    if n <= 200:
        assert km.merge_pass(c.mean, c.cov, c.existence, 9.0, 1e-3)[-1] is False
    got, want = merge_duplicates(c, 9.0), _merge_reference(c, 9.0)
    assert got.labels == want.labels and len(got.labels) < n
    for a in ("mean", "cov", "existence", "popularity"):
        _same(getattr(got, a), getattr(want, a))


def test_merge_candidates_decide_as_the_exact_test():
    """Every pair within the distance is a candidate; the candidates decided here (Cholesky,
    away from the threshold) are exactly near; only a few are left to ``np.linalg.solve``."""
    rng = np.random.default_rng(5)
    c = _random_clusters(rng, 80)
    ii, jj = np.triu_indices(80, k=1)
    diff = c.mean[ii][:, _POS_VEL] - c.mean[jj][:, _POS_VEL]
    S = (c.cov[ii] + c.cov[jj])[:, _POS_VEL][:, :, _POS_VEL]
    d2 = np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])
    ok = (d2 <= 9.0) & (c.existence[ii] + c.existence[jj] <= 1.0)
    need = set(zip(ii[ok].tolist(), jj[ok].tolist()))
    a, b, undecided = km.merge_candidates(c.mean, c.cov, c.existence, 9.0, 1e-3)
    got = set(zip(a.tolist(), b.tolist()))
    decided = set(zip(a[~undecided].tolist(), b[~undecided].tolist()))
    assert need and need <= got and decided <= need and undecided.sum() < 0.2 * len(got)


def test_merge_candidates_leave_close_calls_to_the_exact_test():
    """A pair at the threshold (d^2 = 9 up to rounding) and one with an asymmetric covariance
    are undecided; a pair at d^2 = 4.5 is decided near."""
    def pair(dx, skew=0.0):
        cov = np.tile(np.diag([50.0, 50.0, 50.0, 50.0, 1e-4]), (2, 1, 1))
        cov[0, 0, 2] += skew
        mean = np.zeros((2, 5))
        mean[1, 0] = dx
        return km.merge_candidates(mean, cov, np.array([0.3, 0.4]), 9.0, 1e-3)[2].tolist()

    assert pair(30.0) == [True]  # 30^2 / 100 = 9
    assert pair(math.sqrt(450.0)) == [False]
    assert pair(math.sqrt(450.0), skew=1e-9) == [True]
    assert pair(40.0) == []  # d^2 = 16: out


def _random_problem(rng, N, M, extended=False, d=0.0):
    dense = np.where(rng.random((N, M)) < 0.35, rng.normal(-3, 2, (N, M)), -np.inf)
    return g.GibbsProblem(log_first=dense + 0.5, log_lik=dense, log_clutter=rng.normal(-2, 1, M),
                          log_new=np.log(rng.uniform(0.01, 0.5, M)), popularity=rng.uniform(1, 2, N),
                          alpha=float(rng.uniform(0.05, 1)), d=d, d_bar=float(rng.uniform(0, 3)),
                          mass=float(rng.uniform(0, 5)), extended=extended)


@pytest.mark.parametrize("seed,extended,d,chains", [(0, False, 0.0, 2), (1, False, 0.3, 2), (2, True, 0.2, 2),
                                                    (3, False, 0.0, 1), (4, False, 0.0, 3)])
def test_run_gibbs_equals_the_numpy_driver(seed, extended, d, chains):
    """The compiled set-up and chains draw the same uniforms and give the same tallies, last
    state, log joint, R-hat and acceptance count as the numpy set-up around the same sweeps."""
    rng = np.random.default_rng(seed)
    prob = _random_problem(rng, int(rng.integers(3, 12)), int(rng.integers(4, 20)), extended, d)
    got = g.run_gibbs(prob, np.random.default_rng(seed + 100), 30, 5, chains=chains)
    want = _run_gibbs_reference(prob, np.random.default_rng(seed + 100), 30, 5, chains=chains)
    for a, b in zip((got.p_pairs, got.p_clutter, got.p_new, got.last), want[:4]):
        _same(a, b)
    assert (got.log_joint, got.rhat_max, got.swaps_accepted) == (want[4], want[5], want[6])
    assert got.swaps_accepted > 0


@pytest.mark.parametrize("seed", range(10))
def test_best_permutation_equals_scipy_assignment(seed):
    """Random marginals with shared measurements: the compiled JPDA* (scipy's augmenting path
    ported) picks what ``linear_sum_assignment`` picks, ties included (rounded marginals)."""
    rng = np.random.default_rng(seed)
    N, M = int(rng.integers(2, 15)), int(rng.integers(2, 10))
    P = np.where(rng.random((N, M)) < 0.5, np.round(rng.random((N, M)), 1), 0.0)
    P /= np.maximum(P.sum(axis=1, keepdims=True) * rng.uniform(1.0, 1.6, (N, 1)), 1e-300)
    ti, mi = np.nonzero(P > 0)
    p = P[ti, mi]
    got, want = best_permutation_pairs(N, ti, mi, p), _best_permutation_reference(N, ti, mi, p)
    for a, b in zip(got, want):
        _same(a, b)


@pytest.mark.parametrize("seed", range(10))
def test_lsap_equals_scipy_with_ties(seed):
    rng = np.random.default_rng(seed)
    nr = int(rng.integers(1, 8))
    cost = rng.integers(0, 4, (nr, nr + int(rng.integers(0, 5)))).astype(float)
    _same(lsap(cost), linear_sum_assignment(cost)[1])


def test_existence_update_and_moment_match_equal_numpy():
    rng = np.random.default_rng(7)
    N, M = 9, 12
    prob = _random_problem(rng, N, M)
    res = g.run_gibbs(prob, np.random.default_rng(1), 30, 5, chains=2)
    pd, q, pop = rng.uniform(0.5, 0.99, N), rng.uniform(0, 1, N), rng.uniform(1, 2, N)
    ti, mi, p, w_miss, r, pop_new = ku.existence_update(res.pairs.ptr, res.pairs.idx, res.p_pairs, N, pd, q, pop,
                                                       0.3, _EPS)
    order = np.lexsort((res.pairs.rows, res.pairs.idx))
    _same(ti, res.pairs.idx[order]), _same(mi, res.pairs.rows[order]), _same(p, res.p_pairs[order])
    p_det = np.clip(np.bincount(ti, weights=p, minlength=N), 0.0, 1.0)
    miss_alive = q * (1.0 - pd)
    want_w = (1.0 - p_det) * (miss_alive / np.maximum(miss_alive + 1.0 - q, _EPS))
    want_r = np.clip(p_det + want_w, 0.0, 1.0)
    _same(w_miss, want_w), _same(r, want_r)
    _same(pop_new, np.maximum(0.3 * pop + 0.7 * (p_det / np.maximum(want_r, _EPS)), 1.0))
    # moment match over the carried pairs, numpy's order
    carry = p > 0
    t, pc = ti[carry], p[carry]
    m_pred, A = rng.normal(0, 100, (N, 5)), rng.normal(size=(N, 5, 5))
    P_pred, P_upd = A @ A.transpose(0, 2, 1), 0.5 * A @ A.transpose(0, 2, 1)
    mu = rng.normal(0, 100, (t.size, 5))
    mean, cov = ku.moment_match(w_miss, r, t, pc, m_pred, P_pred, mu, P_upd, _EPS)
    inv_r = 1.0 / np.maximum(r, _EPS)
    w0, wp = w_miss * inv_r, pc * inv_r[t]
    ref = w0[:, None] * m_pred
    np.add.at(ref, t, wp[:, None] * mu)
    dev0, dev = m_pred - ref, mu - ref[t]
    c = w0[:, None, None] * (P_pred + dev0[:, :, None] * dev0[:, None, :])
    c += np.bincount(t, weights=wp, minlength=N)[:, None, None] * P_upd
    np.add.at(c, t, wp[:, None, None] * dev[:, :, None] * dev[:, None, :])
    _same(mean, ref), _same(cov, 0.5 * (c + np.swapaxes(c, 1, 2)))


@pytest.mark.parametrize("B,M", [(0, 3), (1, 1), (4, 1), (4, 6), (7, 13)])
def test_birth_moments_equal_einsum(B, M):
    rng = np.random.default_rng(B * 10 + M)
    w = rng.dirichlet(np.ones(B + 1), M).T if B else np.zeros((0, M))
    mu_b, A = rng.normal(0, 100, (B, M, 5)), rng.normal(size=(B, 5, 5))
    P_upd = A @ A.transpose(0, 2, 1)
    pos, C = rng.normal(0, 1000, (M, 2)), rng.normal(size=(M, 2, 2))
    pcov = C @ C.transpose(0, 2, 1) * 100
    mean, cov = kb.birth_moments(w, mu_b, P_upd, pos, pcov, 400.0, 0.003)
    mean_u, cov_u = np.zeros((M, 5)), np.zeros((M, 5, 5))
    mean_u[:, 0], mean_u[:, 2] = pos[:, 0], pos[:, 1]
    cov_u[:, 0, 0], cov_u[:, 0, 2], cov_u[:, 2, 0], cov_u[:, 2, 2] = pcov[:, 0, 0], pcov[:, 0, 1], pcov[:, 1, 0], pcov[:, 1, 1]
    cov_u[:, 1, 1] = cov_u[:, 3, 3] = 400.0
    cov_u[:, 4, 4] = 0.003
    if B == 0:
        _same(mean, mean_u), _same(cov, cov_u)
        return
    mu = np.concatenate([mu_b, mean_u[None]])
    P = np.concatenate([np.broadcast_to(P_upd[:, None], (B, M, 5, 5)), cov_u[None]])
    ref = np.einsum("bm,bmi->mi", w, mu)
    dv = mu - ref[None]
    c = np.einsum("bm,bmij->mij", w, P) + np.einsum("bm,bmi,bmj->mij", w, dv, dv)
    _same(mean, ref), _same(cov, 0.5 * (c + np.swapaxes(c, 1, 2)))


@pytest.mark.parametrize("seed", range(6))
def test_cardinality_pmf_equals_existence_cardinality(seed):
    rng = np.random.default_rng(seed)
    r = np.r_[rng.random(int(rng.integers(0, 60))) ** 3, np.ones(seed % 3), np.zeros(seed % 2), np.full(seed * 20, 1e-9)]
    rng.shuffle(r)
    pmf, ok = ke.cardinality_pmf(r, 1e-9)
    assert ok
    _same(pmf, existence_cardinality(r))
    assert not ke.cardinality_pmf(np.array([0.5, np.nan]), 1e-9)[1]


def test_estimate_assignments_hand_values():
    """Three measurements, clusters 0 (reported) and 1 (not): m0 takes cluster 0 (0.6 > none
    0.4); m1's newborn (0.5) beats cluster 0's 0.3 and none (0.2); m2's best reported option
    (0.2) is below none (1 - 0.2 = 0.8)."""
    ptr = np.array([0, 2, 3, 5])
    idx = np.array([0, 1, 0, 0, 1])
    p = np.array([0.6, 0.3, 0.3, 0.2, 0.7])
    choice, prob = ke.estimate_assignments(ptr, idx, p, np.array([True, False]), np.array([0.0, 0.5, 0.1]),
                                          np.array([1]))
    assert choice.tolist() == [0, -2, -1]
    assert prob.tolist() == [0.6, 0.5, 1.0 - 0.2]


def test_problem_pairs_equal_numpy():
    rng = np.random.default_rng(3)
    N, M = 7, 9
    pd, q, pop = rng.uniform(0.2, 1.0, N), np.r_[0.0, rng.uniform(0, 1.2, N - 1)], rng.uniform(1, 2, N)
    args, qc, zero = ku.problem_log_args(pd, q, pop, 0.1, _EPS)
    assert zero.tolist() == [True] + [False] * (4 * N - 1)  # q[0] = 0
    mi, ti = np.nonzero(rng.random((M, N)) < 0.4)
    ll = rng.normal(-5, 2, ti.size)
    ptr, idx, lf, llk, mass, d_bar = ku.problem_pairs(np.log(args), zero, qc, pop, ti, mi, ll, M)
    pdc, qr = np.clip(pd, 0.0, 1.0 - 1e-9), np.clip(q, 0.0, 1.0)
    miss = np.maximum(qr * (1.0 - pdc) + 1.0 - qr, _EPS)
    with np.errstate(divide="ignore"):
        log_det = np.log(qr) + np.log(pdc) - np.log(miss) + np.log(pop - 0.1)
    want = g.SparsePairs.from_pairs(N, M, ti, mi, log_det[ti] + ll, ll)
    _same(ptr, want.ptr), _same(idx, want.idx), _same(lf, want.log_first), _same(llk, want.log_lik)
    assert (mass, d_bar) == (np.sum(qr * pop), qr.sum()) and math.isfinite(mass)


def test_exchange_pairs_hand_values_with_a_bounded_cluster():
    """Cluster 0 gates measurements 0-3 (log_first -1, -3, -2, -4): bounded to 2 members it
    pairs only 0 and 2; cluster 1 pairs 3 and 4, cluster 2 pairs 1 and 2."""
    from bnptrack.tracker.bnp.swap_moves import exchange_pairs

    first = np.full((3, 5), -np.inf)
    first[0, :4] = [-1.0, -3.0, -2.0, -4.0]
    first[1, 3:] = [-1.0, -1.0]
    first[2, 1:3] = [-5.0, -5.0]
    problem = g.GibbsProblem(log_first=first, log_lik=first, log_clutter=np.zeros(5), log_new=np.zeros(5),
                             popularity=np.ones(3), alpha=1.0, d=0.0, d_bar=0.0, mass=1.0)
    pr = problem.pairs
    for cap, want in ((2, [(0, 2), (1, 2), (3, 4)]),
                      (4, [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3), (3, 4)])):
        a, b = exchange_pairs(pr.ptr, pr.idx, pr.log_first, 3, cap)
        assert list(zip(a.tolist(), b.tolist())) == want
        ra, rb = g.swap_pairs(problem, cap)
        assert list(zip(ra.tolist(), rb.tolist())) == want


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exchange_pairs_equal_the_numpy_pairs(seed):
    """The compiled exchange list equals :func:`swap_pairs` on random gates, bounded or not."""
    from bnptrack.tracker.bnp.swap_moves import exchange_pairs

    rng = np.random.default_rng(seed)
    N, M = 12, 60
    first = np.where(rng.random((N, M)) < 0.4, rng.normal(-3.0, 1.0, (N, M)).round(1), -np.inf)
    problem = g.GibbsProblem(log_first=first, log_lik=first, log_clutter=np.zeros(M), log_new=np.zeros(M),
                             popularity=np.ones(N), alpha=1.0, d=0.0, d_bar=0.0, mass=1.0)
    pr = problem.pairs
    for cap in (3, 10, 1000):
        a, b = exchange_pairs(pr.ptr, pr.idx, pr.log_first, N, cap)
        ra, rb = g.swap_pairs(problem, cap)
        assert a.size > 0
        np.testing.assert_array_equal(a, ra)
        np.testing.assert_array_equal(b, rb)


@pytest.mark.parametrize("seed", [0, 1])
def test_large_best_permutation_equals_scipy_on_the_whole_problem(seed):
    """Above ``SCIPY_PAIRS`` (per component, pairs costlier than their cluster's "missed"
    dropped first) the JPDA* choice equals scipy's assignment of the whole dense problem."""
    from bnptrack.tracker.filtering import SCIPY_PAIRS

    rng = np.random.default_rng(seed)
    N, M = 220, 160
    assert N * M > SCIPY_PAIRS
    near = np.abs(np.arange(N)[:, None] * M / N - np.arange(M)[None, :]) < 6  # banded: many components touch
    P = np.where(near & (rng.random((N, M)) < 0.6), rng.random((N, M)), 0.0)
    P /= np.maximum(P.sum(axis=1, keepdims=True) * rng.uniform(1.0, 1.5, (N, 1)), 1e-300)
    ti, mi = np.nonzero(P > 0)
    p = P[ti, mi]
    got, want = best_permutation_pairs(N, ti, mi, p), _best_permutation_reference(N, ti, mi, p)
    assert np.sum(got[1] != np.array([mi[ti == t][np.argmax(p[ti == t])] for t in got[0]])) > 0  # conflicts solved
    for a, b in zip(got, want):
        _same(a, b)


def test_moment_match_combined_hand_values():
    """One cluster, existence r = 1: "missed" 0.2 at the predicted mean 0, two updates at 10 and
    20 with probabilities 0.6 and 0.2 (1-D, variances P_pred 100, P_upd 4).  Mean 0.6*10 + 0.2*20
    = 10.  The detections as one component (weight 0.8, mean 12.5, variance 4): variance
    0.2 (100 + 10^2) + 0.8 (4 + 2.5^2) = 48.2; the full mixture adds their spread about 12.5,
    0.6 * 2.5^2 + 0.2 * 7.5^2 = 15: 63.2."""
    args = (np.array([0.2]), np.array([1.0]), np.array([0, 0]), np.array([0.6, 0.2]), np.zeros((1, 1)),
            np.full((1, 1, 1), 100.0), np.array([[10.0], [20.0]]), np.full((1, 1, 1), 4.0), _EPS)
    mean, cov = ku.moment_match_combined(*args)
    assert np.allclose(mean, [[10.0]]) and np.allclose(cov, [[[48.2]]])
    mean, cov = ku.moment_match(*args)
    assert np.allclose(mean, [[10.0]]) and np.allclose(cov, [[[63.2]]])
