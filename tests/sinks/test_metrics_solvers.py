"""The scorer's own distance matrix and assignment (``sinks.metrics``) give what scipy's
``cdist`` and ``linear_sum_assignment`` give: the same doubles (bit for bit) and the same
pairs, ties included, on wide, tall and square problems; without numba or with ``JIT`` off
the assignment is scipy's own."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from bnptrack.sinks import metrics
from bnptrack.tracker import _numerics

if _numerics.JIT:
    import numba  # noqa: F401  (the scorer uses the compiled solver once numba is imported)


@pytest.mark.parametrize("dim", [1, 2, 3, 4, 8, 9, 17])
def test_euclidean_is_cdist_bit_for_bit(dim: int) -> None:
    rng = np.random.default_rng(dim)
    for _ in range(60):
        m, n = rng.integers(0, 25, 2)
        scale = 10.0 ** rng.uniform(-3, 5)
        X = rng.normal(size=(m, dim)) * scale
        Y = rng.normal(size=(n, dim)) * scale + rng.normal() * scale
        a, b = metrics._euclidean(X, Y), cdist(X, Y)
        assert a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def _problems(rng: np.random.Generator, count: int):
    for t in range(count):
        m, n = (int(v) for v in rng.integers(1, 11, 2))
        if t % 3 == 0:
            yield rng.uniform(0.0, 100.0, (m, n))
        elif t % 3 == 1:  # many ties
            yield rng.integers(0, 3, (m, n)).astype(float)
        else:  # OSPA costs: distances cut off at c = 100, squared (ties at the cut-off)
            yield np.minimum(rng.uniform(0.0, 200.0, (m, n)), 100.0) ** 2


def test_assignment_is_scipys_ties_included() -> None:
    for cost in _problems(np.random.default_rng(3), 3000):
        rows, cols = metrics._assignment(cost)
        ref_rows, ref_cols = linear_sum_assignment(cost)
        assert np.array_equal(rows, ref_rows) and np.array_equal(cols, ref_cols), cost


def test_assignment_hand_checked() -> None:
    cost = np.array([[4.0, 1.0, 3.0], [2.0, 0.0, 5.0]])  # rows 0, 1 -> columns 1, 0 (total 3)
    rows, cols = metrics._assignment(cost)
    assert rows.tolist() == [0, 1] and cols.tolist() == [1, 0]
    rows, cols = metrics._assignment(cost.T)  # tall: pairs listed by row
    assert rows.tolist() == [0, 1] and cols.tolist() == [1, 0]


def test_without_jit_the_assignment_is_scipys(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    def spy(cost: np.ndarray):
        calls.append(cost.shape)
        return linear_sum_assignment(cost)

    monkeypatch.setattr(metrics, "optimal_assignment", spy)
    cost = np.array([[1.0, 2.0], [2.0, 1.0]])
    metrics._assignment(cost)
    assert calls == ([] if _numerics.JIT else [(2, 2)])
    monkeypatch.setattr(metrics, "JIT", False)
    assert [a.tolist() for a in metrics._assignment(cost)] == [[0, 1], [0, 1]]
    assert calls[-1] == (2, 2)
