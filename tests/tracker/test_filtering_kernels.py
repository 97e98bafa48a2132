"""The compiled filter kernels (tracker/models/_kernels.py) against the numpy reference of
tracker/filtering.py on random batches, plus hand-computed values.

``tracker.numerics.JIT`` selects the path at each call: ``True`` runs the kernels (compiled,
or interpreted when numba is missing: the same code), ``False`` the numpy reference.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bnptrack.tracker import numerics
from bnptrack.tracker import filtering as kf
from bnptrack.tracker.models import _kernels
from bnptrack.tracker.models.measurement import BearingRange, Cartesian, RangeOnly, wrap_angle
from bnptrack.tracker.models.motion import ConstantVelocity, CoordinatedTurn

FIELDS = ("z_pred", "S", "S_inv", "log_det_S", "gain", "P_upd", "cross_cov")


def _batch(rng: np.random.Generator, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Random CT states around a sensor at the origin (some behind it: bearings near +-pi,
    some with a turn rate below the straight-line threshold) and random SPD covariances."""
    m = np.column_stack([rng.uniform(-2000, 2000, N), rng.normal(0, 15, N), rng.uniform(-2000, 2000, N),
                         rng.normal(0, 15, N), rng.normal(0, 0.05, N)])
    m[::5, 4] = 1e-12
    m[1::7, 4] = 0.0
    m[2::6, 0], m[2::6, 2] = rng.uniform(-3, 3, m[2::6].shape[0]), -1500.0  # straight behind: bearing ~ +-pi
    A = rng.normal(size=(N, 5, 5)) * np.array([30.0, 3.0, 30.0, 3.0, 0.01])[None, :, None]
    P = A @ A.transpose(0, 2, 1) + np.diag([25.0, 4.0, 25.0, 4.0, 1e-4])
    return m, P


def _both(monkeypatch, fn, *args):
    monkeypatch.setattr(numerics, "JIT", True)
    new = fn(*args)
    monkeypatch.setattr(numerics, "JIT", False)
    ref = fn(*args)
    monkeypatch.setattr(numerics, "JIT", True)
    return new, ref


def _close(a, b, rtol=1e-12):
    """Equal to rounding: entrywise within ``rtol`` of the array's largest entry."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(np.abs(b).max(initial=0.0), 1e-300))


@pytest.mark.parametrize("T, period", [(1.0, None), (2.5, 1.0), (0.4, 1.0)])
def test_ct_prediction_matches_the_numpy_reference(monkeypatch, T, period):
    rng = np.random.default_rng(7)
    m, P = _batch(rng, 60)
    motion = CoordinatedTurn(T=T, sigma_accel=3.0, sigma_turn=0.02, period=period)
    (m1, P1), (m0, P0) = _both(monkeypatch, kf.ukf_predict, motion, m, P)
    _close(m1, m0)
    for a, b in zip(P1, P0):
        _close(a, b)
    np.testing.assert_array_equal(P1, np.swapaxes(P1, 1, 2))  # exactly symmetric, like the reference


@pytest.mark.parametrize("meas", [BearingRange(), BearingRange(np.deg2rad(1.0), 5.0, 120.0, -40.0, 0.7),
                                  BearingRange(noise=((3e-4, 2e-3), (2e-3, 90.0))), RangeOnly(),
                                  RangeOnly(7.0, 50.0, 60.0, heading=-1.0), Cartesian(),
                                  Cartesian(noise=((40.0, 12.0), (12.0, 90.0)))])
def test_innovation_matches_the_numpy_reference(monkeypatch, meas):
    m, P = _batch(np.random.default_rng(11), 60)
    new, ref = _both(monkeypatch, kf.ukf_innovation, meas, m, P)
    for f in FIELDS:
        for a, b in zip(getattr(new, f).reshape(60, -1), getattr(ref, f).reshape(60, -1)):
            _close(a, b, 1e-10 if f == "gain" else 1e-12)  # K = C S^-1 of a nearly singular S loses digits
        assert not getattr(new, f).flags.writeable
    np.testing.assert_array_equal(new.S, np.swapaxes(new.S, 1, 2))
    np.testing.assert_array_equal(new.P_upd, np.swapaxes(new.P_upd, 1, 2))


@pytest.mark.parametrize("meas", [BearingRange(heading=0.3), RangeOnly(), Cartesian()])
@pytest.mark.parametrize("gate", [None, 0.999])
def test_likelihoods_and_gate_match_the_numpy_reference(monkeypatch, meas, gate):
    rng = np.random.default_rng(3)
    m, P = _batch(rng, 40)
    innov = kf.ukf_innovation(meas, m, P)
    Z = meas.sample(rng, m[rng.integers(0, 40, 30)])
    Z = np.concatenate([Z, Z[:3] + 5.0 * np.sqrt(np.diag(meas.R))])
    Z[4] = np.nan  # a non-finite measurement is never a candidate
    new, ref = _both(monkeypatch, kf.log_likelihood_matrix, meas, innov, Z, gate)
    np.testing.assert_array_equal(np.isfinite(new), np.isfinite(ref))
    assert np.isfinite(new).sum() > 30 and np.all(new[:, 4] == -np.inf)
    _close(new[np.isfinite(new)], ref[np.isfinite(ref)], 1e-13)
    if gate is not None:
        (t1, j1, l1), (t0, j0, l0) = _both(monkeypatch, kf.gated_log_likelihood, meas, innov, Z, gate)
        np.testing.assert_array_equal(t1, t0)
        np.testing.assert_array_equal(j1, j0)
        _close(l1, l0, 1e-13)
        assert t1.dtype == j1.dtype == np.int64


@pytest.mark.parametrize("meas", [BearingRange(), RangeOnly(), Cartesian()])
def test_large_frame_gate_through_the_grid_equals_the_kd_tree_bit_for_bit(monkeypatch, meas):
    """Above ``SCIPY_PAIRS`` pairs the compiled gate (:func:`_kernels.loglik_balls`, a grid over
    the measurements) gives the KD-tree reference's pairs and log-likelihoods exactly, across
    the bearing cut too (a fifth of the tracks straight behind the sensor)."""
    rng = np.random.default_rng(11)
    m, P = _batch(rng, 300)
    innov = kf.ukf_innovation(meas, m, P)
    Z = np.concatenate([meas.sample(rng, m[rng.integers(0, 300, 250)]), meas.sample(rng, m[:40])])
    Z[7] = np.nan  # a non-finite measurement is never a candidate
    assert len(innov) * Z.shape[0] > kf.SCIPY_PAIRS
    (t1, j1, l1), (t0, j0, l0) = _both(monkeypatch, kf.gated_log_likelihood, meas, innov, Z, 0.9999)
    assert t0.size > 300 and not np.any(j1 == 7)
    np.testing.assert_array_equal(t1, t0)
    np.testing.assert_array_equal(j1, j0)
    np.testing.assert_array_equal(l1, l0)
    assert t1.dtype == j1.dtype == np.int64
    if isinstance(meas, BearingRange):  # some gated pairs really are across the cut
        assert np.any(np.abs(innov.z_pred[t1, 0] - Z[j1, 0]) > np.pi)


def test_not_positive_definite_falls_back_to_the_reference(monkeypatch):
    """A covariance without a Cholesky factor: the kernel declines and the numpy reference
    (eigen-factor) answers, so the results are the reference's exactly."""
    m, P = _batch(np.random.default_rng(5), 6)
    P[2] = np.diag([100.0, 4.0, 100.0, 4.0, 0.0])  # singular: a zero pivot
    (m1, P1), (m0, P0) = _both(monkeypatch, kf.ukf_predict, CoordinatedTurn(), m, P)
    np.testing.assert_array_equal(m1, m0)
    np.testing.assert_array_equal(P1, P0)
    new, ref = _both(monkeypatch, kf.ukf_innovation, BearingRange(), m, P)
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(new, f), getattr(ref, f))


def test_other_models_use_the_numpy_path(monkeypatch):
    """A model without a kernel (constant velocity) never reaches the CT kernel: it runs the
    numpy reference, with the same values as with the JIT switched off."""
    m = np.array([[10.0, 1.0, 20.0, -1.0]])
    P = np.eye(4)[None] * 4.0
    (m1, P1), (m0, P0) = _both(monkeypatch, kf.ukf_predict, ConstantVelocity(), m, P)
    np.testing.assert_array_equal(m1, m0)
    np.testing.assert_array_equal(P1, P0)

    def no_kernel(*args):
        raise AssertionError("the CT kernel was called for a constant-velocity model")

    monkeypatch.setattr(_kernels, "ct_ukf_predict", no_kernel)
    m2, P2 = kf.ukf_predict(ConstantVelocity(), m, P)
    np.testing.assert_array_equal(m2, m0)
    with pytest.raises(AssertionError, match="CT kernel was called"):
        kf.ukf_predict(CoordinatedTurn(), np.array([[10.0, 1.0, 20.0, -1.0, 0.0]]), np.eye(5)[None] * 4.0)


def test_hand_computed_straight_line_prediction():
    """omega = 0, P = diag: the CT model is linear, the UT exact: m' = [p + v T, v, ...],
    P'_pp = P_pp + T^2 P_vv + Q_pp, P'_pv = T P_vv + Q_pv."""
    motion = CoordinatedTurn(T=2.0, sigma_accel=1.0, sigma_turn=0.0)
    m = np.array([[100.0, 3.0, -50.0, -2.0, 0.0]])
    P = np.diag([9.0, 1.0, 16.0, 4.0, 1e-20])[None]  # turn-rate spread: no curvature
    m1, P1 = kf.ukf_predict(motion, m, P)
    np.testing.assert_allclose(m1[0, :4], [106.0, 3.0, -54.0, -2.0], rtol=0, atol=1e-12)
    # Q per axis with sigma_a = 1, T = 2: [[T^4/4, T^3/2], [T^3/2, T^2]] = [[4, 4], [4, 4]]
    np.testing.assert_allclose(P1[0, 0, 0], 9.0 + 4.0 * 1.0 + 4.0, rtol=1e-6)
    np.testing.assert_allclose(P1[0, 0, 1], 2.0 * 1.0 + 4.0, rtol=1e-6)
    np.testing.assert_allclose(P1[0, 2, 2], 16.0 + 4.0 * 4.0 + 4.0, rtol=1e-6)
    np.testing.assert_allclose(P1[0, 3, 3], 4.0 + 4.0, rtol=1e-6)


def test_hand_computed_cartesian_innovation():
    """xy is linear: S = P_pos + R, C = P[:, pos], K = C S^-1, and a diagonal P gives
    K_xx = P_xx / (P_xx + sigma^2); log det S = log((9 + 4)(16 + 4))."""
    meas = Cartesian(sigma=2.0)
    m = np.array([[10.0, 1.0, 20.0, -1.0, 0.01]])
    P = np.diag([9.0, 1.0, 16.0, 4.0, 1e-4])[None]
    innov = kf.ukf_innovation(meas, m, P)
    np.testing.assert_allclose(innov.z_pred, [[10.0, 20.0]], atol=1e-12)
    np.testing.assert_allclose(innov.S[0], np.diag([13.0, 20.0]), atol=1e-12)
    np.testing.assert_allclose(innov.log_det_S[0], math.log(13.0 * 20.0), rtol=1e-14)
    np.testing.assert_allclose(innov.gain[0, 0, 0], 9.0 / 13.0, rtol=1e-14)
    np.testing.assert_allclose(innov.gain[0, 2, 1], 16.0 / 20.0, rtol=1e-14)
    np.testing.assert_allclose(innov.P_upd[0, 0, 0], 9.0 - 81.0 / 13.0, rtol=1e-13)
    L = kf.log_likelihood_matrix(meas, innov, np.array([[13.0, 16.0]]))
    expected = -0.5 * (2 * math.log(2 * math.pi) + math.log(260.0) + 9.0 / 13.0 + 16.0 / 20.0)
    np.testing.assert_allclose(L[0, 0], expected, rtol=1e-14)


def test_bearing_through_pi_is_wrapped():
    """An object straight behind the sensor (bearing +-pi): the predicted bearing is +-pi,
    not 0, and the bearing variance is the small one of the state's spread, not ~pi^2."""
    meas = BearingRange(sigma_bearing=0.01, sigma_range=1.0)
    m = np.array([[0.0, 0.0, -1000.0, 0.0, 0.0]])
    P = np.diag([100.0, 1.0, 100.0, 1.0, 1e-6])[None]
    innov = kf.ukf_innovation(meas, m, P)
    assert abs(abs(innov.z_pred[0, 0]) - math.pi) < 1e-9
    np.testing.assert_allclose(innov.S[0, 0, 0], 100.0 / 1000.0**2 + 1e-4, rtol=1e-3)


def test_wrap_is_numpys_bit_for_bit():
    a = np.concatenate([np.linspace(-20.0, 20.0, 4001), [-math.pi, math.pi, np.nextafter(math.pi, 0.0),
                                                         -np.nextafter(math.pi, 4.0), 0.0, -0.0, 1e300, np.nan]])
    w = np.array([_kernels._wrap.py_func(float(x)) if hasattr(_kernels._wrap, "py_func") else _kernels._wrap(float(x))
                  for x in a])
    np.testing.assert_array_equal(w, wrap_angle(a))


@pytest.mark.parametrize("meas", [BearingRange(heading=-2.9), RangeOnly(), Cartesian()])
def test_pair_updates_match_the_numpy_reference(monkeypatch, meas):
    rng = np.random.default_rng(9)
    m, P = _batch(rng, 30)
    innov = kf.ukf_innovation(meas, m, P)
    Z = meas.sample(rng, m[rng.integers(0, 30, 20)])
    ti, mi = rng.integers(0, 30, 50), rng.integers(0, 20, 50)
    new, ref = _both(monkeypatch, kf.update_pairs, meas, innov, m, Z, ti, mi)
    _close(new, ref, 1e-14)
    # one pair by hand: m + K r, the bearing residual wrapped
    r = Z[mi[0]] - innov.z_pred[ti[0]]
    if isinstance(meas, BearingRange):
        r[0] = wrap_angle(r[0])
    np.testing.assert_allclose(new[0], m[ti[0]] + innov.gain[ti[0]] @ r, rtol=1e-14, atol=1e-9)


def test_unique_ints_equals_numpy_unique():
    """The sort-based unique gives numpy's values, order and dtype (hand case, then random)."""
    from bnptrack.tracker.numerics import unique_ints

    assert unique_ints(np.array([7, 3, 7, -1, 3], dtype=np.int64)).tolist() == [-1, 3, 7]
    rng = np.random.default_rng(4)
    for n in (0, 1, 2, 9, 5000):
        x = rng.integers(-20, 400, n)
        got, want = unique_ints(x), np.unique(x)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
