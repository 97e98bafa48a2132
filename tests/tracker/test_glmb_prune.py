"""prune_and_cap by partition (Monte Carlo throughput): the same kept set as a
stable sort by weight, ties at the cap included, and hand-checked cases."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import logsumexp
from bnptrack.tracker.glmb.hypotheses import prune_and_cap


def _by_stable_sort(log_w: np.ndarray, threshold: float, cap: int) -> np.ndarray:
    """The previous implementation (reference)."""
    w = np.exp(log_w - logsumexp(log_w))
    keep = np.flatnonzero(w > threshold)
    if keep.size == 0:
        keep = np.array([int(np.argmax(log_w))])
    if keep.size > cap:
        keep = keep[np.argsort(-log_w[keep], kind="stable")[:cap]]
    return np.sort(keep)


def test_same_set_as_the_stable_sort_with_ties_and_pruned_entries():
    rng = np.random.default_rng(5)
    capped = 0
    for _ in range(3000):
        n, cap = int(rng.integers(1, 60)), int(rng.integers(1, 40))
        log_w = np.round(rng.normal(0.0, 3.0, n), int(rng.integers(0, 3)))  # rounding: many ties
        log_w[rng.random(n) < 0.2] = -80.0  # below the threshold
        got, ref = prune_and_cap(log_w, 1e-15, cap), _by_stable_sort(log_w, 1e-15, cap)
        assert np.array_equal(got, ref) and got.dtype == ref.dtype
        capped += ref.size == cap
    assert capped > 500


def test_hand_cases():
    # cap 2 of weights (1, 3, 3, 2): the two 3s; cap 1: the first 3 (the lower index)
    lw = np.log(np.array([1.0, 3.0, 3.0, 2.0]))
    assert prune_and_cap(lw, 1e-15, 2).tolist() == [1, 2]
    assert prune_and_cap(lw, 1e-15, 1).tolist() == [1]
    # threshold 0.2 of (0.1, 0.3, 0.6): the last two; all under the threshold: the best one
    assert prune_and_cap(np.log([0.1, 0.3, 0.6]), 0.2, 5).tolist() == [1, 2]
    assert prune_and_cap(np.log([0.3, 0.3, 0.4]), 0.9, 5).tolist() == [2]
