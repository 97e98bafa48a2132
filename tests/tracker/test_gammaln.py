"""``tracker.numerics.gammaln`` against ``scipy.special.gammaln``: the same doubles (compared
bit for bit) over the whole positive range, the same shapes, and scipy's own values where it
falls back (``x <= 0``, NaN, infinities, beyond Cephes' MAXLGM)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import gammaln as scipy_gammaln

from bnptrack.tracker import numerics
from bnptrack.tracker.numerics import gammaln


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


@pytest.mark.parametrize("low, high", [(1e-300, 1e-6), (1e-6, 2.0), (1.999, 3.001), (0.0, 13.0), (12.9, 13.1),
                                       (13.0, 1000.0), (990.0, 1010.0), (1e3, 1e9)])
def test_equal_to_scipy_bit_for_bit(low: float, high: float) -> None:
    x = np.random.default_rng(7).uniform(low, high, 200_000)
    x = x[x > 0]
    assert _same_bits(gammaln(x), scipy_gammaln(x))


def test_equal_on_every_scale_and_at_the_branch_points() -> None:
    x = np.exp(np.random.default_rng(8).uniform(-700.0, 700.0, 200_000))
    assert _same_bits(gammaln(x), scipy_gammaln(x))
    edges = np.array([5e-324, 1.0, 2.0, 3.0, 13.0, np.nextafter(13.0, 0), 1000.0, 1e8, np.nextafter(1e8, 2e8),
                      2.556348e305])
    assert _same_bits(gammaln(edges), scipy_gammaln(edges))
    assert gammaln(np.array([1.0, 2.0])).tolist() == [0.0, 0.0]  # log 0! and log 1!
    assert gammaln(np.array([5.0]))[0] == pytest.approx(np.log(24.0), rel=1e-15)


def test_shapes_and_scalars_follow_scipy() -> None:
    grid = np.linspace(0.5, 40.0, 12).reshape(3, 4)
    assert _same_bits(gammaln(grid), scipy_gammaln(grid))
    assert _same_bits(gammaln(grid.T), scipy_gammaln(grid.T))  # not contiguous
    scalar = gammaln(np.asarray(2.5))
    assert isinstance(scalar, np.float64) and scalar == scipy_gammaln(2.5)
    assert gammaln(np.empty((0, 3))).shape == (0, 3)


def test_other_arguments_are_scipys() -> None:
    x = np.array([0.0, -0.5, -1.0, -40.5, np.nan, np.inf, -np.inf, 3e305, 2.0])
    with np.errstate(all="ignore"):
        assert _same_bits(gammaln(x), scipy_gammaln(x))


def test_interpreted_mode_uses_scipy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numerics, "JIT", False)
    x = np.array([0.3, 7.5, 42.0])
    assert _same_bits(gammaln(x), scipy_gammaln(x))
