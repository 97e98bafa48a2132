"""The kernels' stable argsort (``tracker.numerics.argsort_stable``) gives numpy's stable
permutation: equal keys in their order, NaNs last, on floats and integers, across the
insertion-sorted runs and the merges."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.numerics import SORT_RUN, argsort_stable


def test_a_hand_worked_case():
    keys = np.array([3.0, np.nan, 1.0, 1.0, -np.inf, np.nan, 2.0, -0.0, 0.0])
    # -inf, the two 1.0 in order, 2.0, 3.0; -0.0 and 0.0 are equal (in order); NaNs last
    assert argsort_stable(keys).tolist() == [4, 7, 8, 2, 3, 6, 0, 1, 5]
    assert argsort_stable(np.array([2, 1, 2, 1], dtype=np.int64)).tolist() == [1, 3, 0, 2]
    assert argsort_stable(np.zeros(0)).tolist() == []


@pytest.mark.parametrize("n", [1, SORT_RUN - 1, SORT_RUN, SORT_RUN + 1, 2 * SORT_RUN + 3, 97, 1000, 4099])
def test_numpy_stable_order_on_ties_and_nans(n):
    rng = np.random.default_rng(n)
    for _ in range(5):
        ints = rng.integers(-4, 4, n).astype(np.int64)
        floats = rng.choice(np.array([np.nan, -np.inf, np.inf, -0.0, 0.0, 1.5, -2.25]), n)
        smooth = rng.normal(size=n).round(1)
        for keys in (ints, floats, smooth, -smooth):
            got = argsort_stable(keys)
            assert got.dtype == np.int64
            np.testing.assert_array_equal(got, np.argsort(keys, kind="stable"))
