"""The gate table, the gates by cluster and the exchange lists of the sampler's exchange moves
(tracker/bnp/swap_moves.py): hand-computed bits and lists, and exchange passes through the lists,
walking the gates, through the table and scanning every pair all equal, move for move."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp import swap_moves as g
from bnptrack.tracker.bnp.swap_moves import PREDRAWN_PAIRS, exchange_lists, exchange_tables, gate_bits, gated
from bnptrack.tracker.bnp.swap_moves import gates_by_cluster
from bnptrack.tracker.bnp.swap_moves import pass_uniforms, swap_scan


def test_gate_bits_hand_values():
    """Measurement 0 gates clusters 0 and 9, measurement 1 cluster 3, measurement 2 none (N = 10:
    two bytes a row; cluster 9 is bit 1 of byte 1)."""
    ptr, idx = np.array([0, 2, 3, 3], dtype=np.int64), np.array([0, 9, 3], dtype=np.int64)
    bits = gate_bits(ptr, idx, 10, 1 << 20)
    np.testing.assert_array_equal(bits, np.array([[1, 2], [8, 0], [0, 0]], dtype=np.uint8))
    hits = [(m, l) for m in range(3) for l in range(10) if gated(bits, m, l)]
    assert hits == [(0, 0), (0, 9), (1, 3)]


def test_gate_bits_not_built_above_the_limit_or_without_clusters():
    ptr, idx = np.array([0, 2, 3, 3], dtype=np.int64), np.array([0, 9, 3], dtype=np.int64)
    assert gate_bits(ptr, idx, 10, 5).shape == (0, 0)  # 3 x 2 bytes > 5
    assert gate_bits(np.zeros(4, dtype=np.int64), np.zeros(0, dtype=np.int64), 0, 1 << 20).shape == (0, 0)


def test_exchange_lists_hand_values():
    """Gates m0 {0, 1}, m1 {0}, m2 {1}: pairs (0, 1) through cluster 0 and (0, 2) through cluster
    1.  m0's entry for cluster 0 lists pair 0 (b = 1, whose entry for cluster 0 is CSR place 2),
    its entry for cluster 1 pair 1 (b = 2, place 3); m1 and m2 have no later partner."""
    ptr, idx = np.array([0, 2, 3, 4], dtype=np.int64), np.array([0, 1, 0, 1], dtype=np.int64)
    pa, pb = np.array([0, 0], dtype=np.int64), np.array([1, 2], dtype=np.int64)
    row, lptr, ent = exchange_lists(ptr, idx, 2, pa, pb, 1 << 20)
    np.testing.assert_array_equal(row, [0, 2, 2, 2])
    np.testing.assert_array_equal(lptr, [0, 1, 2, 2, 2])
    np.testing.assert_array_equal(ent, [[0, 1, 2], [1, 2, 3]])


def test_exchange_lists_keep_only_listed_pairs_and_respect_the_limit():
    """Three measurements gating cluster 0, but only pair (0, 2) in the exchange list (as when a
    crowded gate pairs only its likeliest members): m0's entry lists b = 2 alone; above the
    limit no list is built."""
    ptr, idx = np.array([0, 1, 2, 3], dtype=np.int64), np.zeros(3, dtype=np.int64)
    pa, pb = np.array([0], dtype=np.int64), np.array([2], dtype=np.int64)
    row, lptr, ent = exchange_lists(ptr, idx, 1, pa, pb, 1 << 20)
    np.testing.assert_array_equal(row, [0, 1, 1, 1])
    np.testing.assert_array_equal(lptr, [0, 1, 1, 1])
    np.testing.assert_array_equal(ent, [[0, 2, 2]])
    assert exchange_lists(ptr, idx, 1, pa, pb, 0)[1].size == 0


def _random_pass_inputs(rng, M, N, extended):
    """CSR gates of 0-5 clusters per measurement (ascending), weights with some exact zeros, a
    state mixing clutter, new, gated and (impossible) ungated clusters, every pair ``a < b``."""
    rows = [np.sort(rng.choice(N, int(rng.integers(0, 6)), replace=False)) for _ in range(M)]
    ptr = np.r_[0, np.cumsum([r.size for r in rows])].astype(np.int64)
    idx = np.concatenate(rows).astype(np.int64)
    w_first = rng.exponential(1.0, idx.size) * (rng.random(idx.size) > 0.1)
    c = rng.choice(np.r_[g.CLUTTER, g.NEW, np.arange(N)], M).astype(np.int64)
    cnt = np.bincount(c[c >= 0], minlength=N).astype(np.int64)
    a, b = np.triu_indices(M, k=1)
    return (c, cnt, extended, a.astype(np.int64), b.astype(np.int64), rng.exponential(1.0, M),
            rng.exponential(1.0, M), ptr, idx, w_first)


@pytest.mark.parametrize("seed,extended,subset,predrawn", [(0, False, False, True), (1, False, True, True),
                                                           (2, True, False, True), (3, False, False, True),
                                                           (5, True, True, True), (0, False, False, False),
                                                           (5, True, True, False), (6, False, True, False)])
def test_swap_pass_equals_the_scan(seed, extended, subset, predrawn):
    """The pass through the exchange lists, the pass walking the gates by cluster, the scan with
    the gate table and the scan without it make the same moves (``subset``: a random half of
    the pairs listed, so no gate is known to pair all its measurements: ``max_members`` 0).
    Not ``predrawn``: each draws a uniform per scored proposal from its own copy of one
    generator, so equal moves also mean that they score the same proposals in the same order."""
    rng = np.random.default_rng(seed)
    M, N = 40, 25
    c, cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first = _random_pass_inputs(rng, M, N, extended)
    if subset:
        keep = rng.random(pa.size) < 0.5
        pa, pb = pa[keep], pb[keep]
    members = 0 if subset else M
    tables = exchange_tables(ptr, idx, N, pa, pb, w_first, 1 << 20, members)
    assert tables[1].size == idx.size + 1  # the lists were built
    walk = exchange_tables(ptr, idx, N, pa, pb, w_first, 0, members)
    assert walk[1].size == 0  # no lists: the gates are walked
    bits, none = gate_bits(ptr, idx, N, 1 << 20), np.zeros((0, 0), dtype=np.uint8)
    cs = [c.copy() for _ in range(4)]
    owns = [np.array([g.own_weight(m, c[m], w_cl, w_new, ptr, idx, w_first) for m in range(M)]) for _ in range(4)]
    total = 0
    for k in range(5):
        u = rng.random(pa.size) if predrawn else np.zeros(0)
        rs = [np.random.default_rng([seed, k]) for _ in range(4)]
        n = [g.swap_pass(cs[0], cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first, u, tables, owns[0], rs[0]),
             g.swap_pass(cs[1], cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first, u, walk, owns[1], rs[1]),
             swap_scan(cs[2], cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first, u, bits, owns[2], rs[2]),
             swap_scan(cs[3], cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first, u, none, owns[3], rs[3])]
        assert n[0] == n[1] == n[2] == n[3]
        for i in (1, 2, 3):
            np.testing.assert_array_equal(cs[0], cs[i])
        assert len({r.random() for r in rs}) == 1  # as many uniforms drawn
        want = [g.own_weight(m, cs[0][m], w_cl, w_new, ptr, idx, w_first) for m in range(M)]
        np.testing.assert_array_equal(owns[0], want)  # the kept factors are the scanned ones
        total += n[0]
    assert total > 0  # exchanges happened, so the comparison saw moves


def test_gates_by_cluster_hand_values():
    """Gates m0 {0, 1}, m1 {0}, m2 {1}: cluster 0 is gated by m0 (CSR place 0) and m1 (place 2),
    cluster 1 by m0 (place 1) and m2 (place 3)."""
    ptr, idx = np.array([0, 2, 3, 4], dtype=np.int64), np.array([0, 1, 0, 1], dtype=np.int64)
    first, meas_of, pos_of = gates_by_cluster(ptr, idx, 2)
    np.testing.assert_array_equal(first, [0, 2, 4])
    np.testing.assert_array_equal(meas_of, [0, 1, 0, 2])
    np.testing.assert_array_equal(pos_of, [0, 2, 1, 3])


def test_exchange_tables_walk_above_the_predrawn_limit():
    """Above ``PREDRAWN_PAIRS`` pairs no list is built (the pass walks the gates); ``capped``
    marks the gates of more than ``max_members`` measurements."""
    ptr, idx = np.array([0, 2, 3, 4], dtype=np.int64), np.array([0, 1, 0, 0], dtype=np.int64)
    pa, pb = np.array([0, 0, 1], dtype=np.int64), np.array([1, 2, 2], dtype=np.int64)
    w = np.ones(4)
    row, lptr, ent, lw, first, meas_of, gw, capped, gpos, pos_of = exchange_tables(ptr, idx, 2, pa, pb, w, 1 << 20, 2)
    assert lptr.size == idx.size + 1
    np.testing.assert_array_equal(capped, [True, False])  # cluster 0 is gated by three
    np.testing.assert_array_equal(pos_of, [0, 2, 3, 1])  # cluster 0: m0, m1, m2; cluster 1: m0
    np.testing.assert_array_equal(gpos, [0, 3, 1, 2])  # each CSR pair's place in its cluster's gate
    np.testing.assert_array_equal(row, [0, 2, 3, 3])
    big = PREDRAWN_PAIRS + 1
    pa2, pb2 = np.zeros(big, dtype=np.int64), np.ones(big, dtype=np.int64)
    tables = exchange_tables(ptr, idx, 2, pa2, pb2, w, 1 << 20, 2)
    assert tables[1].size == 0 and tables[2].shape == (0, 3)
    np.testing.assert_array_equal(tables[0], [0, big, big, big])


def test_pass_uniforms_one_per_pair_up_to_the_limit():
    """Up to ``PREDRAWN_PAIRS`` pairs the pass's uniforms are the generator's next ones; above,
    none are drawn."""
    u = pass_uniforms(np.random.default_rng(7), 5)
    np.testing.assert_array_equal(u, np.random.default_rng(7).random(5))
    assert pass_uniforms(np.random.default_rng(7), PREDRAWN_PAIRS).size == PREDRAWN_PAIRS
    rng = np.random.default_rng(7)
    assert pass_uniforms(rng, PREDRAWN_PAIRS + 1).size == 0
    assert rng.random() == np.random.default_rng(7).random()  # nothing drawn
