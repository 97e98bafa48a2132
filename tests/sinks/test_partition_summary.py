"""Summaries of sampled partitions: the posterior similarity matrix, Binder's loss and its
minimiser, split R-hat (hand values)."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sinks.partitions import binder_loss, binder_point, n_blocks, similarity_matrix, split_rhat


def test_similarity_matrix_hand_value():
    draws = np.array([[0, 0, 1], [0, 1, 1], [5, 5, 5], [2, 0, 1]])
    psm = similarity_matrix(draws)
    # pairs (0,1): draws 1 and 3 -> 2/4; (0,2): draw 3 -> 1/4; (1,2): draws 2, 3 -> 2/4
    np.testing.assert_allclose(psm, [[1, 0.5, 0.25], [0.5, 1, 0.5], [0.25, 0.5, 1]])


def test_binder_loss_hand_value():
    psm = np.array([[1, 0.9, 0.2], [0.9, 1, 0.4], [0.2, 0.4, 1]])
    # {0,1},{2}: (1 - 0.9) + 0.2 + 0.4 = 0.7; all together: 0.1 + 0.8 + 0.6 = 1.5
    assert binder_loss(np.array([0, 0, 1]), psm) == pytest.approx(0.7)
    assert binder_loss(np.array([3, 3, 3]), psm) == pytest.approx(1.5)


def test_binder_point_improves_on_every_candidate():
    # the PSM of {0,1,2},{3,4} with item 2 uncertain (p 0.6 with 0 and 1); candidates all wrong
    psm = np.eye(5)
    psm[0, 1] = psm[1, 0] = 0.95
    psm[[0, 1], 2] = psm[2, [0, 1]] = 0.6
    psm[3, 4] = psm[4, 3] = 0.9
    candidates = np.array([[0, 1, 2, 3, 4], [0, 0, 0, 0, 0]])
    z = binder_point(psm, candidates)
    np.testing.assert_array_equal(z, [0, 0, 0, 1, 1])
    assert binder_loss(z, psm) < min(binder_loss(c, psm) for c in candidates)


def test_binder_point_of_draws_that_agree_is_that_partition():
    draws = np.array([[4, 4, 7, 7, 9]] * 6)
    np.testing.assert_array_equal(binder_point(similarity_matrix(draws), draws), [0, 0, 1, 1, 2])


def test_n_blocks():
    np.testing.assert_array_equal(n_blocks(np.array([[[0, 0, 1], [2, 3, 4]]])), [[2, 3]])


def test_split_rhat_hand_value():
    x = np.array([[1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0]])
    # halves [1,2],[3,4],[1,2],[3,4]: means 1.5, 3.5, 1.5, 3.5; W = 0.5; B = 2 * var(means) = 2 * 4/3
    W, B, n = 0.5, 2 * (4.0 / 3.0), 2
    assert split_rhat(x) == pytest.approx(np.sqrt(((n - 1) / n * W + B / n) / W))


def test_split_rhat_of_constant_chains():
    assert split_rhat(np.full((2, 6), 3.0)) == 1.0
    assert split_rhat(np.array([[3.0] * 6, [4.0] * 6])) == float("inf")
    with pytest.raises(ValueError, match="split_rhat"):
        split_rhat(np.ones((2, 3)))
