"""Survival over a gap (``ModelParams.survival_over``, ``survival_dt``): per scan along the path."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.models.params import load_params


def _leaving(r_end: float) -> np.ndarray:
    """An object on the boresight (+y) moving outwards at 20 m/s, at range ``r_end``."""
    return np.array([[0.0, 0.0, r_end, 20.0, 0.0]])


def test_an_object_that_left_in_the_gap_is_outside_only_after_it_left():
    """vo2017: P_S 0.99 inside the 2000 m field of view, 0.7 beyond.  Predicted at 2010 m over
    a 2 s gap it was at 1990 m (inside) one scan earlier: 0.99 * 0.7 (the two scans' own
    survivals), where the end point alone says 0.7^2; over 3 s from 2030 m: 0.7 * 0.7 * 0.99."""
    p = load_params("vo2017")
    assert p.survival_over(_leaving(2010.0), 2.0)[0] == pytest.approx(0.99 * 0.7, rel=1e-12)
    assert p.survival_over(_leaving(2030.0), 3.0)[0] == pytest.approx(0.7 * 0.7 * 0.99, rel=1e-12)
    end = load_params("vo2017", ["survival_dt='end'"])
    assert end.survival_over(_leaving(2010.0), 2.0)[0] == pytest.approx(0.7**2, rel=1e-12)
    assert end.survival_over(_leaving(2030.0), 3.0)[0] == pytest.approx(0.7**3, rel=1e-12)


@pytest.mark.parametrize("dt", [0.25, 0.5, 1.0])
def test_no_gap_no_change(dt):
    """At dt <= T both rules are P_S(x)^(dt/T), and dt == T is P_S(x) itself (bit for bit)."""
    x = np.vstack([_leaving(1995.0), _leaving(2005.0)])
    path, end = load_params("vo2017"), load_params("vo2017", ["survival_dt='end'"])
    np.testing.assert_array_equal(path.survival_over(x, dt), end.survival_over(x, dt))
    np.testing.assert_allclose(path.survival_over(x, dt), [0.99**dt, 0.7**dt], rtol=1e-14)
    if dt == 1.0:
        np.testing.assert_array_equal(path.survival_over(x, dt), path.survival(x))


def test_gap_equals_scans_that_saw_nothing():
    """Over dt = 2 T the product of the per-scan survivals at the two scan instants (a turning
    object: the path back is the CT flow), for objects inside, outside and crossing."""
    p = load_params("vo2017")
    x = np.array([[300.0, 15.0, 1990.0, 12.0, 0.02], [0.0, 5.0, 3000.0, 1.0, 0.0],
                  [1400.0, 20.0, 1420.0, 20.0, -0.01]])
    back = p.motion(-1.0).f(x)
    np.testing.assert_allclose(p.survival_over(x, 2.0), p.survival(x) * p.survival(back), rtol=1e-12)


def test_zero_survival_is_allowed():
    p = load_params("vo2017", ["p_survival_outside=0.0"])
    assert p.survival_over(_leaving(2010.0), 2.0)[0] == 0.0
    assert p.survival_over(_leaving(1500.0), 2.0)[0] == pytest.approx(0.99**2, rel=1e-12)


@pytest.mark.parametrize("dt", [0.5, 1.0, 2.0])
def test_the_callers_field_of_view_test_gives_the_same_survival(dt):
    """``visible``: the frame's sensor's own test of the states (a tracker's P_D shares it,
    BnpTracker._predict) gives the survival computed without it, bit for bit, with no declared
    sensor and with one (``far``, 2500 m up, sees 3000 m: 0.99 there only with it)."""
    x = np.vstack([_leaving(1990.0), _leaving(2010.0), _leaving(3000.0), _leaving(4600.0)])
    for p, want in ((load_params("vo2017"), [0.99, 0.7, 0.7, 0.7]),
                    (load_params("vo2017", ["sensors.far.y=2500.0"]), [0.99, 0.7, 0.99, 0.7])):
        seen = p.detection().visible(x)
        np.testing.assert_array_equal(p.survival_over(x, dt, visible=seen), p.survival_over(x, dt))
        np.testing.assert_array_equal(p.survival(x, visible=seen), want)
