"""The sparse (gated) paths of DDP-EMM against their dense references, and the memory guard.

Each sparse piece must give what its dense reference gives: the gated pairs and
their log-likelihoods bit for bit, the per-component JPDA* assignment the global one, the
KD-tree pre-filter of duplicate merging every pair within the merge distance, the vectorised
log joint the sequential one.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from bnptrack.tracker.bnp import BnpConfig, make_tracker
from bnptrack.tracker.bnp import filter as bnp_filter
from bnptrack.tracker.bnp.assignment import best_permutation
from bnptrack.tracker.bnp.clusters import _Clusters, _near_pairs, ball_hits, exclusive_near_pairs
from bnptrack.tracker import filtering as kf
from bnptrack.tracker.bnp.gibbs import CLUTTER, NEW, GibbsProblem, log_joint
from bnptrack.tracker.models.measurement import BearingRange, RangeOnly
from bnptrack.tracker.models.params import load_params


def _tracks(rng, n, bearing_centre=0.0):
    rad = rng.uniform(100.0, 1900.0, n)
    brg = bearing_centre + rng.uniform(-0.3, 0.3, n)
    m = np.column_stack([rad * np.sin(brg), rng.normal(0, 10, n), rad * np.cos(brg), rng.normal(0, 10, n),
                         np.zeros(n)])
    P = np.tile(np.diag([400.0, 100.0, 400.0, 100.0, 1e-4]), (n, 1, 1)) * rng.uniform(0.2, 30.0, n)[:, None, None]
    return m, P


@pytest.mark.parametrize("meas, centre", [(BearingRange(), 0.0), (BearingRange(), np.pi), (RangeOnly(), 0.0)])
def test_gated_pairs_equal_the_dense_gate_bit_for_bit(meas, centre):
    """Tracks straddling the +-pi bearing cut (centre pi) are matched across it as well."""
    rng = np.random.default_rng(3)
    m, P = _tracks(rng, 60, centre)
    innov = kf.ukf_innovation(meas, m, P)
    Z = np.vstack([meas.sample(rng, m), meas.sample(rng, m[rng.permutation(60)[:30]])])
    dense = kf.log_likelihood_matrix(meas, innov, Z, 0.9999)
    mt, lt = np.nonzero(np.isfinite(dense.T))
    ti, mi, ll = kf.gated_log_likelihood(meas, innov, Z, 0.9999)
    assert mt.size > 60  # the gates hold many pairs (tracks and measurements overlap)
    np.testing.assert_array_equal(mi, mt)
    np.testing.assert_array_equal(ti, lt)
    np.testing.assert_array_equal(ll, dense[lt, mt])
    if centre == np.pi:  # some accepted pairs really are across the cut
        assert np.any(np.abs(innov.z_pred[ti, 0] - Z[mi, 0]) > np.pi)


def _dense_best_permutation(p_lm):
    """The pre-sparse implementation: one LSA over all clusters x (measurements + missed)."""
    N, M = p_lm.shape
    p_det = p_lm.sum(axis=1)
    live = np.flatnonzero(p_det > 1e-9)
    out = np.zeros_like(p_lm)
    L = live.size
    cost = np.full((L, M + L), 1e6)
    with np.errstate(divide="ignore"):
        cost[:, :M] = np.minimum(-np.log(p_lm[live]), 1e6)
        cost[np.arange(L), M + np.arange(L)] = -np.log(np.maximum(1.0 - p_det[live], 1e-300))
    rows, cols = linear_sum_assignment(cost)
    chosen = np.where(cols < M, cols, np.argmax(p_lm[live[rows]], axis=1))
    out[live[rows], chosen] = p_det[live[rows]]
    return out


@pytest.mark.parametrize("seed", range(6))
def test_best_permutation_per_component_equals_the_global_assignment(seed):
    """Random block-sparse marginals (several components, some with conflicts): the same result."""
    rng = np.random.default_rng(seed)
    N, M = 40, 60
    p = np.zeros((N, M))
    for _ in range(8):  # blocks of 1-6 clusters sharing 1-5 measurements
        rows = rng.choice(N, rng.integers(1, 7), replace=False)
        cols = rng.choice(M, rng.integers(1, 6), replace=False)
        block = rng.random((rows.size, cols.size)) * (rng.random((rows.size, cols.size)) < 0.7)
        p[np.ix_(rows, cols)] = block
    p /= np.maximum(p.sum(axis=1, keepdims=True), 1.0) * rng.uniform(1.0, 1.5, (N, 1))
    got, want = best_permutation(p), _dense_best_permutation(p)
    assert ((want > 0).sum(axis=1) > 1).sum() == 0 and (want > 0).sum() > 10
    np.testing.assert_array_equal(got > 0, want > 0)  # the same measurement for every cluster
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=0)  # row sums: summation order only


def test_near_pairs_hold_every_pair_within_the_merge_distance():
    rng = np.random.default_rng(5)
    n = 300
    mean = np.column_stack([rng.uniform(0, 3000, n), rng.normal(0, 5, n), rng.uniform(0, 3000, n),
                            rng.normal(0, 5, n), np.zeros(n)])
    scale = rng.choice([1.0, 30.0, 3000.0], n, p=[0.6, 0.37, 0.03])  # small, medium, a few huge
    cov = np.tile(np.diag([100.0, 25.0, 100.0, 25.0, 1e-4]), (n, 1, 1)) * scale[:, None, None]
    c = _Clusters(tuple(str(i) for i in range(n)), mean, cov, np.full(n, 0.3), np.ones(n))
    ii, jj = np.triu_indices(n, k=1)
    d = mean[ii][:, [0, 1, 2, 3]] - mean[jj][:, [0, 1, 2, 3]]
    S = (cov[ii] + cov[jj])[:, [0, 1, 2, 3]][:, :, [0, 1, 2, 3]]
    d2 = np.einsum("pk,pk->p", d, np.linalg.solve(S, d[..., None])[..., 0])
    want = set(zip(ii[d2 <= 9.0].tolist(), jj[d2 <= 9.0].tolist()))
    lo, hi = _near_pairs(c, 9.0)
    got = set(zip(lo.tolist(), hi.tolist()))
    assert len(want) > 20 and want <= got
    assert len(got) < ii.size / 10  # and it is a pre-filter, not all pairs


def test_vectorised_log_joint_equals_the_sequential_sum():
    rng = np.random.default_rng(2)
    N, M = 4, 6
    ll = rng.normal(-5, 1, (N, M))
    ll[rng.random((N, M)) < 0.3] = -np.inf
    prob = GibbsProblem(ll + 0.3, ll, rng.normal(-7, 1, M), rng.normal(-6, 1, M), np.ones(N), 0.4, 0.1, 2.5, 3.0)
    from dataclasses import replace

    seq = replace(prob, extended=True)  # one measurement per cluster: the extended formula is the same joint
    checked = 0
    for _ in range(300):
        c = rng.choice([CLUTTER, NEW, 0, 1, 2, 3], M)
        if len(set(c[c >= 0].tolist())) < (c >= 0).sum():
            assert log_joint(prob, c) == -np.inf
            continue
        a, b = log_joint(prob, c), log_joint(seq, c)
        assert (a == b == -np.inf) or np.isclose(a, b, rtol=1e-12)
        checked += np.isfinite(a)
    assert checked > 20


def test_max_clusters_guard_warns_once_and_reports(caplog):
    """The cap is a memory guard (default 100000); when it bites, the step says so."""
    assert BnpConfig().max_clusters == 100_000
    params = load_params("vo2017")
    tr = make_tracker("ddp-mb", params, BnpConfig(max_clusters=3))
    from bnptrack.tracker.state import tracker_frame_rng
    from bnptrack.tracker.types import Frame

    z = np.column_stack([np.linspace(-1.0, 1.0, 8), np.linspace(300.0, 1800.0, 8)])
    bnp_filter._capped_warned.clear()
    st = tr.initial_state()
    with caplog.at_level(logging.WARNING, logger="bnptrack.tracker.bnp.filter"):
        for k in range(3):
            st, est = tr.step(st, Frame(k, k * 10**9, "s", "bearing_range", z), tracker_frame_rng(1, k))
            assert st.n_clusters <= 3
    assert est.diagnostics["clusters_capped"] > 0
    assert sum("max_clusters (3) reached" in r.message for r in caplog.records) == 1


def _kdtree_near_pairs(c: _Clusters, max_d2: float) -> tuple[np.ndarray, np.ndarray]:
    """``_near_pairs`` by a KD-tree's ball queries (the reference for the grid, above 200 clusters)."""
    from itertools import chain

    from scipy.spatial import cKDTree

    pos = c.mean[:, [0, 2]]
    a, b, d = c.cov[:, 0, 0], c.cov[:, 2, 2], c.cov[:, 0, 2]
    lam = 0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + d * d)
    ok = np.flatnonzero(np.isfinite(pos).all(axis=1) & np.isfinite(lam))
    radius = np.sqrt(2.0 * max_d2 * lam[ok]) * (1.0 + 1e-9)
    hits = cKDTree(pos[ok]).query_ball_point(pos[ok], radius, return_sorted=False)
    lens = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))
    i = ok[np.repeat(np.arange(ok.size), lens)]
    j = ok[np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=int(lens.sum()))]
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    n = len(c.labels)
    key = np.unique(lo[lo < hi] * n + hi[lo < hi])
    lo, hi = key // n, key % n
    d2p = np.sum((pos[lo] - pos[hi]) ** 2, axis=1)
    near = d2p <= max_d2 * (lam[lo] + lam[hi]) * (1.0 + 1e-9)
    return lo[near], hi[near]


@pytest.mark.parametrize("seed,n,spread", [(1, 201, 500.0), (2, 800, 20000.0), (3, 2000, 40000.0), (4, 400, 0.0)])
def test_near_pairs_grid_equals_the_kdtree_pairs(seed, n, spread):
    """The grid (``ball_hits``) returns the KD-tree's pairs, in the same order: clusters of
    every size of covariance (a few huge, one with a NaN mean, one not positive definite), some on
    top of each other."""
    rng = np.random.default_rng(seed)
    mean = np.column_stack([rng.uniform(0, spread, n), rng.normal(0, 5, n), rng.uniform(0, spread, n),
                            rng.normal(0, 5, n), np.zeros(n)])
    mean[5:9, [0, 2]] = mean[4, [0, 2]]
    mean[10, 0] = np.nan
    scale = rng.choice([1.0, 30.0, 3000.0, 1e6], n, p=[0.6, 0.35, 0.045, 0.005])
    cov = np.tile(np.diag([100.0, 25.0, 100.0, 25.0, 1e-4]), (n, 1, 1)) * scale[:, None, None]
    cov[:, 0, 2] = cov[:, 2, 0] = 60.0 * rng.uniform(-1, 1, n) * scale
    cov[11, 0, 0] = -50.0
    c = _Clusters(tuple(str(i) for i in range(n)), mean, cov, np.full(n, 0.3), np.ones(n))
    with np.errstate(invalid="ignore"):
        want = _kdtree_near_pairs(c, 9.0)
        got = _near_pairs(c, 9.0)
    assert want[0].size > 20
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w, strict=True)


@pytest.mark.parametrize("seed,n,spread", [(1, 201, 500.0), (2, 800, 20000.0), (3, 2000, 40000.0), (4, 400, 0.0)])
def test_exclusive_near_pairs_are_the_near_pairs_whose_existences_sum_to_at_most_1(seed, n, spread):
    """With ``exclusive`` (``exclusive_near_pairs``), ``_near_pairs`` returns exactly the
    unrestricted pairs whose existences sum to at most 1, in the same order: clusters of every size
    of covariance, a NaN mean and a NaN existence, a covariance not positive definite, some on top
    of each other, existences on both sides of 0.5 (and at it)."""
    rng = np.random.default_rng(seed)
    mean = np.column_stack([rng.uniform(0, spread, n), rng.normal(0, 5, n), rng.uniform(0, spread, n),
                            rng.normal(0, 5, n), np.zeros(n)])
    mean[5:9, [0, 2]] = mean[4, [0, 2]]
    mean[10, 0] = np.nan
    scale = rng.choice([1.0, 30.0, 3000.0, 1e6], n, p=[0.6, 0.35, 0.045, 0.005])
    cov = np.tile(np.diag([100.0, 25.0, 100.0, 25.0, 1e-4]), (n, 1, 1)) * scale[:, None, None]
    cov[:, 0, 2] = cov[:, 2, 0] = 60.0 * rng.uniform(-1, 1, n) * scale
    cov[11, 0, 0] = -50.0
    r = rng.choice([0.2, 0.5, 0.6, 0.9], n, p=[0.3, 0.05, 0.1, 0.55])
    r[12] = np.nan
    c = _Clusters(tuple(str(i) for i in range(n)), mean, cov, r, np.ones(n))
    with np.errstate(invalid="ignore"):
        lo, hi = _near_pairs(c, 9.0)
        got = _near_pairs(c, 9.0, exclusive=True)
        keep = r[lo] + r[hi] <= 1.0
    assert keep.sum() > 20 and (~keep).sum() > 20
    for g, w in zip(got, (lo[keep], hi[keep])):
        np.testing.assert_array_equal(g, w, strict=True)


def test_ball_hits_hold_every_point_of_each_ball():
    """Each point's hits are the points within its radius (brute force), the point itself never."""
    rng = np.random.default_rng(7)
    pos = rng.uniform(0, 1000, (300, 2))
    radius = rng.choice([5.0, 50.0, 400.0], 300, p=[0.5, 0.45, 0.05])
    a, b = ball_hits(pos, radius)
    got = set(zip(a.tolist(), b.tolist()))
    d2 = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(axis=2)
    want = {(i, j) for i, j in zip(*np.nonzero(d2 <= radius[:, None] ** 2)) if i != j}
    assert len(want) > 300 and got == want


@pytest.mark.parametrize("seed", range(4))
def test_jpda_block_on_its_edges_equals_the_dense_matrix(seed, monkeypatch):
    """A JPDA* block solved on its edges (above ``SPARSE_ENTRIES``) chooses what the dense cost
    matrix chooses: random blocks of 60 clusters x 80 measurements, 6 edges per cluster, some
    clusters whose missed column beats every edge."""
    from bnptrack.tracker.bnp import assignment

    rng = np.random.default_rng(seed)
    L, C = 60, 80
    r_idx = np.repeat(np.arange(L), 6)
    c_idx = np.concatenate([rng.choice(C, 6, replace=False) for _ in range(L)])
    p = rng.uniform(0.02, 0.6, r_idx.size)
    p_det = rng.uniform(0.3, 0.99, L)[r_idx]
    pos, meas = r_idx.copy(), c_idx + 1000
    start = np.full(L, -1, dtype=np.int64)
    got, want = start.copy(), start.copy()
    monkeypatch.setattr(assignment, "SPARSE_ENTRIES", 0)
    assignment._solve_block(r_idx, c_idx, pos, meas, p, p_det, got, linear_sum_assignment)
    monkeypatch.setattr(assignment, "SPARSE_ENTRIES", 1 << 30)
    assignment._solve_block(r_idx, c_idx, pos, meas, p, p_det, want, linear_sum_assignment)
    assert 10 < (want >= 0).sum() < L  # some clusters take a measurement, some are missed
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_exclusive_near_pairs_are_the_ball_hits_that_pass_the_test_once_each(seed):
    """Each pair of ``ball_hits`` whose existences sum to at most 1 (either direction) that passes ``_near_pairs``' test,
    found once: equal variances on top of each other (ties), a variance whose ball overflows (its
    pairs found from the other side), variances that are not positive."""
    rng = np.random.default_rng(seed)
    n = 300
    pos = rng.uniform(0, 3000, (n, 2))
    pos[10:14] = pos[9]
    lam = rng.choice([100.0, 2500.0, 90000.0], n, p=[0.6, 0.35, 0.05])
    lam[9:14] = 400.0
    lam[20] = 1e306  # radius^2 overflows: no ball
    lam[21] = -5.0  # not positive: no ball
    r = rng.choice([0.2, 0.5, 0.9], n, p=[0.4, 0.1, 0.5])
    r[20] = r[21] = 0.1
    r[9:14] = 0.3
    max_d2 = 9.0
    with np.errstate(invalid="ignore", over="ignore"):
        radius = np.sqrt(2.0 * max_d2 * lam) * (1.0 + 1e-9)
        a, b = ball_hits(pos, radius)
        a, b = a[r[a] + r[b] <= 1.0], b[r[a] + r[b] <= 1.0]  # the pairs whose existences sum to at most 1
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = np.unique(lo * n + hi)
        lo, hi = key // n, key % n
        near = np.sum((pos[lo] - pos[hi]) ** 2, axis=1) <= max_d2 * (lam[lo] + lam[hi]) * (1.0 + 1e-9)
        got_a, got_b = exclusive_near_pairs(pos, radius, r, lam, max_d2)
    got = got_a * n + got_b
    assert np.all(got_a < got_b) and np.unique(got).size == got.size  # each pair once
    np.testing.assert_array_equal(np.sort(got), key[near])
    assert near.sum() > 50 and np.any((lo == 20) & near) and np.any((lo >= 9) & (hi <= 13) & near)
