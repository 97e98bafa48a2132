"""The gate table of the sampler's exchange moves (tracker/bnp/swap_moves.py): hand-computed bits,
and exchange passes with the table equal to those without it, move for move."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp import swap_moves as g
from bnptrack.tracker.bnp.swap_moves import gate_bits, gated


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


@pytest.mark.parametrize("seed,extended", [(0, False), (1, False), (2, True), (3, False)])
def test_swap_pass_with_the_table_equals_the_scan(seed, extended):
    rng = np.random.default_rng(seed)
    M, N = 40, 25
    c, cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first = _random_pass_inputs(rng, M, N, extended)
    bits, none = gate_bits(ptr, idx, N, 1 << 20), np.zeros((0, 0), dtype=np.uint8)
    c1, c2 = c.copy(), c.copy()
    own1, own2 = (np.array([g.own_weight(m, c[m], w_cl, w_new, ptr, idx, w_first) for m in range(M)]) for _ in "12")
    total = 0
    for _ in range(5):
        u = rng.random(pa.size)
        n1 = g.swap_pass(c1, cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first, u, bits, own1)
        n2 = g.swap_pass(c2, cnt, ext, pa, pb, w_cl, w_new, ptr, idx, w_first, u, none, own2)
        assert n1 == n2
        np.testing.assert_array_equal(c1, c2)
        want = [g.own_weight(m, c1[m], w_cl, w_new, ptr, idx, w_first) for m in range(M)]
        np.testing.assert_array_equal(own1, want)  # the kept factors are the scanned ones
        total += n1
    assert total > 0  # exchanges happened, so the comparison saw moves
