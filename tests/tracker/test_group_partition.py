"""The gated object -> cluster Gibbs kernel (tracker/bnp/group_partition.py) against the full scan
(groups.py's ``_partition_kernel`` + ``_collect_shares``, kept as ``sample_partition(kernel="scan")``):
the same sample and shares bit for bit, with fewer tables scored where the bound excludes them."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp.group_grid import MARGIN, _heap_pop, _heap_push, median
from bnptrack.tracker.bnp.group_partition import lmax2
from bnptrack.tracker.bnp.group_sample import PARTITION_KERNELS, Block, sample_partition
from bnptrack.tracker.numerics import JIT, jit


def _blocks(seed: int, L: int, G: int, spread: float, centroid: bool = True, wide: bool = False):
    """L members scattered over ``spread`` m, G transitioned clusters; ``wide``: one cluster's
    centroid prior 100x wider than the rest (it goes to the gate's wide list)."""
    rng = np.random.default_rng(seed)
    pos, vel = rng.uniform(0, spread, (L, 2)), rng.normal(0, 8, (L, 2))
    Rv = np.eye(2) * 20 * rng.uniform(0.5, 3, L)[:, None, None]
    Rp = np.eye(2) * 900 * rng.uniform(0.5, 3, L)[:, None, None]
    Rp[:, 0, 1] = Rp[:, 1, 0] = 100.0 * rng.uniform(-1, 1, L)
    gm, gp = rng.normal(0, 8, (G, 2)), rng.uniform(0, spread, (G, 2))
    gc, gpc = np.tile(np.eye(2) * 6, (G, 1, 1)), np.tile(np.eye(2) * 500, (G, 1, 1))
    if wide and G:
        gpc[0] *= 1e4
    b0 = Block(vel, Rv, gm, gc, np.zeros(2), 400 * np.eye(2))
    b1 = Block(pos, Rp, gp, gpc, np.full(2, spread / 2), spread**2 / 12 * np.eye(2))
    v_star = rng.integers(1, 4, G).astype(float)
    init = np.where(rng.random(L) < 0.7, rng.integers(0, max(G, 1), L), -1) if G else -np.ones(L, dtype=np.int64)
    return ([b0, b1] if centroid else [b0]), v_star, init


def _run(kernel: str, blocks, v_star, init, alpha, d, occupied, seed, stats=None):
    return sample_partition(np.random.default_rng(seed), blocks, v_star, alpha, d, init, 6, True, occupied,
                            kernel=kernel, stats=stats)


def _same(a, b) -> None:
    np.testing.assert_array_equal(a[0], b[0], strict=True)
    for f in ("obj", "w", "mu", "cov"):
        np.testing.assert_array_equal(getattr(a[1], f), getattr(b[1], f), strict=True)


@pytest.mark.parametrize("seed,L,G,spread", [(1, 1, 0, 100.0), (2, 12, 4, 200.0), (3, 60, 25, 3000.0),
                                             (4, 300, 120, 30000.0), (5, 40, 0, 50000.0)])
@pytest.mark.parametrize("alpha,d,occupied", [(0.5, 0.0, True), (2.0, 0.3, True), (1.5, 0.2, False)])
def test_every_kernel_draws_the_full_scans_sample(seed, L, G, spread, alpha, d, occupied) -> None:
    blocks, v_star, init = _blocks(seed, L, G, spread)
    ref = _run("scan", blocks, v_star, init, alpha, d, occupied, seed)
    for kernel in PARTITION_KERNELS[1:]:
        _same(_run(kernel, blocks, v_star, init, alpha, d, occupied, seed), ref)
    if L > 10:
        assert np.unique(ref[0]).size > 1  # the sample moves objects between tables


@pytest.mark.parametrize("centroid,wide", [(False, False), (True, True)])
def test_one_block_and_a_wide_table_draw_the_full_scans_sample(centroid, wide) -> None:
    """Velocity only (the grid indexes the velocity block) and a cluster whose centroid prior is
    too wide for the grid (always scored)."""
    blocks, v_star, init = _blocks(7, 80, 30, 20000.0, centroid=centroid, wide=wide)
    ref = _run("scan", blocks, v_star, init, 0.8, 0.1, True, 7)
    _same(_run("gated", blocks, v_star, init, 0.8, 0.1, True, 7), ref)


def test_a_far_table_is_skipped_and_the_draw_equals_the_full_scans() -> None:
    """Two pairs of objects 100 km apart, each pair on its own transitioned cluster: every move of
    the gated kernel scores only its own pair's tables and the new table, never the far cluster;
    the sample and shares equal the full scan's."""
    vel = np.array([[5.0, 0.0], [5.2, 0.1], [5.0, 0.0], [5.1, -0.1]])
    pos = np.array([[0.0, 0.0], [30.0, 10.0], [1e5, 0.0], [1e5 + 20.0, -15.0]])
    Rv, Rp = np.tile(np.eye(2) * 10.0, (4, 1, 1)), np.tile(np.eye(2) * 500.0, (4, 1, 1))
    b0 = Block(vel, Rv, np.array([[5.0, 0.0], [5.0, 0.0]]), np.tile(np.eye(2) * 4.0, (2, 1, 1)), np.zeros(2),
               400 * np.eye(2))
    b1 = Block(pos, Rp, np.array([[10.0, 0.0], [1e5, 0.0]]), np.tile(np.eye(2) * 400.0, (2, 1, 1)),
               np.array([5e4, 0.0]), 1e9 * np.eye(2))
    init, v_star = np.array([0, 0, 1, 1]), np.array([2.0, 2.0])
    stats = np.zeros(2, dtype=np.int64)
    got = _run("gated", [b0, b1], v_star, init, 1.0, 0.0, True, 3, stats)
    _same(got, _run("scan", [b0, b1], v_star, init, 1.0, 0.0, True, 3))
    np.testing.assert_array_equal(got[0], [0, 0, 1, 1])
    assert stats[0] == 6 * 4
    assert stats[1] <= 2 * stats[0]  # its own cluster and the new table; the far cluster never
    full = np.zeros(2, dtype=np.int64)
    _run("urn", [b0, b1], v_star, init, 1.0, 0.0, True, 3, full)
    assert full[1] == 3 * full[0]  # without the gate: both clusters and the new table


def test_tables_beyond_the_margin_weigh_under_a_hundredth_of_a_rounding_unit() -> None:
    """5,000 tables each more than MARGIN nats below an option weigh together less than a
    hundredth of a double's rounding unit (2^-53) of that option; 36 nats would not."""
    assert 5000 * np.exp(-MARGIN) < 0.01 * np.finfo(float).eps / 2
    assert 5000 * np.exp(-36.0) > np.finfo(float).eps / 2


def test_heap_returns_the_lowest_slot_first() -> None:
    rng = np.random.default_rng(0)
    xs = rng.permutation(200)[:120]
    heap, size = np.empty(200, dtype=np.int64), 0
    for x in xs:
        size = _heap_push(heap, size, x)
    out = []
    while size:
        out.append(int(heap[0]))
        size = _heap_pop(heap, size)
    assert out == sorted(xs.tolist())


def _np_median(a):  # pragma: no cover - compiled
    """numba's ``np.median`` (compiled once, then loaded from the kernel cache)."""
    return np.median(a)


_np_median = jit(_np_median)


@pytest.mark.skipif(not JIT, reason="compares with numba's own np.median")
def test_median_is_numbas_np_median_bit_for_bit() -> None:
    """The grid's median kernel against numba's compiled ``np.median`` (the same quickselect):
    odd and even counts, ties, infinities and NaNs (whose result depends on the steps taken)."""
    numba_median = _np_median
    rng = np.random.default_rng(7)
    cases = [np.zeros(0), np.array([3.0]), np.array([2.0, 1.0]), np.array([1.0, 1.0, 1.0, 1.0])]
    for n in (3, 4, 9, 10, 57, 200):
        cases.append(rng.normal(size=n))
        cases.append(rng.integers(0, 4, n).astype(float))  # ties
        x = rng.normal(size=n)
        x[rng.integers(0, n, 2)] = [np.inf, np.nan]
        cases.append(x)
        cases.append(np.sort(rng.normal(size=n))[::-1].copy())
    for x in cases:
        got, want = median(x), numba_median(x)
        assert np.isnan(got) and np.isnan(want) or got == want, (x, got, want)
    assert median(np.array([5.0, 1.0, 3.0, 2.0])) == 2.5  # hand-computed: (2 + 3) / 2


def test_lmax2_is_the_largest_eigenvalue() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        A = rng.normal(size=(2, 2))
        A = A @ A.T
        assert lmax2(A) == pytest.approx(np.linalg.eigvalsh(A).max(), rel=1e-12)


def test_an_unknown_kernel_is_refused() -> None:
    blocks, v_star, init = _blocks(1, 3, 0, 100.0)
    with pytest.raises(ValueError, match="unknown kernel 'fast'"):
        _run("fast", blocks, v_star, init, 1.0, 0.0, True, 1)


# -- group_merge.greedy_groups: O(pairs) against the dense (n, n) version it replaced --------------

def _greedy_groups_dense(ii, jj, r, order):
    """A dense (n, n) table of the pairs: the simple reference the gated code is checked against."""
    n = r.size
    near = np.zeros((n, n), dtype=bool)
    near[ii, jj] = near[jj, ii] = True
    paired = np.zeros(n, dtype=bool)
    paired[ii] = paired[jj] = True
    free = np.ones(n, dtype=bool)
    ptr, members = [0], []
    for i in order:
        if not paired[i] or not free[i]:
            continue
        group, total = [i], r[i]
        for j in order:
            if near[i, j] and free[j] and total + r[j] <= 1.0 and all(near[j, m] for m in group):
                group.append(j)
                total += r[j]
        free[group] = False
        if len(group) > 1:
            members += group
            ptr.append(len(members))
    return np.array(ptr, dtype=np.int64), np.array(members, dtype=np.int64)


@pytest.mark.parametrize("seed,n,n_pairs", [(1, 5, 6), (2, 40, 120), (3, 300, 900), (4, 300, 3000)])
def test_greedy_groups_equal_the_dense_version(seed, n, n_pairs) -> None:
    from bnptrack.tracker.bnp.group_merge import greedy_groups

    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, n, n_pairs), rng.integers(0, n, n_pairs)
    keep = a < b
    ii, jj = a[keep], b[keep]  # duplicates kept: the table ignores them, so must the CSR
    r = rng.choice([0.1, 0.2, 0.25, 0.3, 0.5], n)
    order = np.argsort(-r, kind="stable")
    got, want = greedy_groups(ii, jj, r, order), _greedy_groups_dense(ii, jj, r, order)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert want[0].size > 1  # a group formed


def test_a_table_the_grid_admits_but_the_exact_form_excludes_is_not_scored() -> None:
    """The second test before scoring: two objects with elongated position covariances
    (900 m^2 along x, 2500^2 m^2 along y); a second cluster 3 km away along x is inside the grid's
    eigenvalue bound (|d|^2 / (lambda_max(C) + lambda_max(R)) is about 1.4 nats) but some 5,000 nats
    below by the exact quadratic form: never scored, and the sample and shares equal the full scan's."""
    vel = np.array([[5.0, 0.0], [5.1, 0.1]])
    pos = np.array([[0.0, 0.0], [20.0, 0.0]])
    Rv = np.tile(np.eye(2) * 10.0, (2, 1, 1))
    Rp = np.tile(np.diag([900.0, 2500.0**2]), (2, 1, 1))
    b0 = Block(vel, Rv, np.array([[5.0, 0.0], [5.0, 0.0]]), np.tile(np.eye(2) * 4.0, (2, 1, 1)), np.zeros(2),
               400 * np.eye(2))
    b1 = Block(pos, Rp, np.array([[10.0, 0.0], [3000.0, 0.0]]), np.tile(np.eye(2) * 400.0, (2, 1, 1)),
               np.array([1500.0, 0.0]), 1e9 * np.eye(2))
    init, v_star = np.array([0, 0]), np.array([2.0, 1.0])
    stats = np.zeros(2, dtype=np.int64)
    got = _run("gated", [b0, b1], v_star, init, 1.0, 0.0, True, 3, stats)
    _same(got, _run("scan", [b0, b1], v_star, init, 1.0, 0.0, True, 3))
    np.testing.assert_array_equal(got[0], [0, 0])
    assert stats[0] == 6 * 2
    assert stats[1] == 2 * stats[0]  # its own cluster and the new table: the far cluster is never scored
    full = np.zeros(2, dtype=np.int64)
    _run("urn", [b0, b1], v_star, init, 1.0, 0.0, True, 3, full)
    assert full[1] == 3 * full[0]  # without the gate all three
