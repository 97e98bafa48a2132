"""Reference-value tests for the motion, measurement, clutter, detection models and params."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.models.clutter import Detection, UniformClutter
from bnptrack.tracker.models.measurement import BearingRange, RangeOnly, wrap_angle
from bnptrack.tracker.models.motion import ConstantVelocity, CoordinatedTurn
from bnptrack.tracker.models.params import load_params


def test_ct_transition_hand_computed_quarter_turn():
    # omega*T = pi/2: sin = 1, cos = 0, sin/w = 2/pi, (1-cos)/w = 2/pi.
    w = np.pi / 2
    ct = CoordinatedTurn(T=1.0, sigma_accel=5.0, sigma_turn=np.pi / 180)
    x = np.array([[10.0, 3.0, -5.0, 4.0, w]])
    a = b = 2 / np.pi
    expected = [10 + a * 3 - b * 4, -4.0, b * 3 - 5 + a * 4, 3.0, w]
    np.testing.assert_allclose(ct.f(x)[0], expected, rtol=0, atol=1e-12)


def test_ct_straight_line_limit_matches_constant_velocity():
    ct = CoordinatedTurn(T=2.0)
    x = np.array([[1.0, 2.0, 3.0, -4.0, 0.0], [1.0, 2.0, 3.0, -4.0, 1e-12]])
    out = ct.f(x)
    np.testing.assert_allclose(out[:, :4], [[5.0, 2.0, -5.0, -4.0]] * 2, atol=1e-9)
    # continuity: tiny omega vs zero
    near = ct.f(np.array([[1.0, 2.0, 3.0, -4.0, 1e-7]]))
    np.testing.assert_allclose(near[0, :4], out[0, :4], atol=1e-5)


@pytest.mark.parametrize("T", [1.0, 2.5, -1.0])
def test_ct_path_is_the_repeated_transition_bit_for_bit(T):
    ct = CoordinatedTurn(T=T)
    rng = np.random.default_rng(5)
    for w in (0.0, 1e-12, -1e-11, 0.05, -0.3, np.pi / 2):
        x = np.r_[rng.normal(0.0, 500.0, 4), w]
        want = [x]
        for _ in range(40):
            want.append(ct.f(want[-1]))
        got = ct.path(x, 40)
        assert got.shape == (41, 5) and got.tobytes() == np.array(want).tobytes()
    assert ct.path(x, 0).tobytes() == x[None].tobytes()


def test_ct_process_noise_matches_spec_form():
    ct = CoordinatedTurn(T=1.0, sigma_accel=15.0, sigma_turn=np.pi / 180)
    s2 = 15.0**2
    Q = np.zeros((5, 5))
    Q[:2, :2] = Q[2:4, 2:4] = s2 * np.array([[0.25, 0.5], [0.5, 1.0]])
    Q[4, 4] = (np.pi / 180) ** 2
    np.testing.assert_allclose(ct.Q, Q, rtol=1e-12)  # the paper's Q_u at T = 1


def test_ct_jacobian_finite_difference():
    ct = CoordinatedTurn(T=1.0)
    for w in (0.0, 0.05, -0.3):
        x = np.array([100.0, -7.0, 50.0, 12.0, w])
        J = ct.jacobian(x[None])[0]
        eps = 1e-6
        fd = np.stack(
            [(ct.f((x + eps * e)[None])[0] - ct.f((x - eps * e)[None])[0]) / (2 * eps) for e in np.eye(5)],
            axis=1,
        )
        np.testing.assert_allclose(J, fd, atol=1e-5)


def test_ct_sample_moments():
    ct = CoordinatedTurn(T=1.0, sigma_accel=5.0, sigma_turn=np.pi / 180)
    x = np.array([[0.0, 10.0, 0.0, 0.0, 0.02]])
    rng = np.random.default_rng(3)
    draws = ct.sample(rng, np.repeat(x, 200_000, axis=0))
    np.testing.assert_allclose(draws.mean(0), ct.f(x)[0], atol=0.05)
    np.testing.assert_allclose(np.cov(draws.T), ct.Q, rtol=0.02, atol=0.05)


def test_cv_matrices_and_logpdf_against_scipy():
    cv = ConstantVelocity(T=2.0, sigma_accel=3.0)
    np.testing.assert_array_equal(cv.F[:2, :2], [[1, 2], [0, 1]])
    np.testing.assert_allclose(cv.Q[:2, :2], 9 * np.array([[4.0, 4.0], [4.0, 4.0]]))
    x = np.array([[1.0, 1.0, 2.0, -1.0]])
    g = np.array([2.0, 2.0])  # [T^2/2, T]: the per-axis noise direction (Q is rank 2)
    xn = cv.f(x) + np.concatenate([0.7 * g, -1.3 * g])[None]
    # Q is singular per axis block ([[4,4],[4,4]]): compare on the support
    ref = stats.multivariate_normal(cv.f(x)[0], cv.Q, allow_singular=True).logpdf(xn[0])
    np.testing.assert_allclose(cv.logpdf(xn, x)[0], ref, rtol=1e-9)


def test_bearing_range_measurement_hand_values():
    br = BearingRange(sigma_bearing=np.deg2rad(2), sigma_range=10.0)
    x = np.array([[300.0, 0, 400.0, 0, 0], [-300.0, 0, 400.0, 0, 0]])
    z = br.h(x)
    np.testing.assert_allclose(z[:, 1], [500.0, 500.0])
    np.testing.assert_allclose(z[:, 0], [np.arctan2(3, 4), -np.arctan2(3, 4)])
    H = br.jacobian(x[:1])[0]
    np.testing.assert_allclose(H[0, [0, 2]], [400 / 500**2, -300 / 500**2])
    np.testing.assert_allclose(H[1, [0, 2]], [0.6, 0.8])


def test_bearing_range_logpdf_against_scipy_and_wrap():
    br = BearingRange(sigma_bearing=0.03, sigma_range=10.0)
    x = np.array([[0.0, 0, -1000.0, 0, 0]])  # straight down -y: bearing +-pi
    zhat = br.h(x)[0]
    z = np.array([[np.pi - 0.01, 1005.0]])
    # residual wraps: true bearing is pi (or -pi), so the residual is -0.01 either way
    ref = stats.multivariate_normal([0, 0], br.R).logpdf([-0.01, 5.0])
    np.testing.assert_allclose(br.logpdf(z, x)[0], ref, rtol=1e-10)
    assert abs(wrap_angle(zhat[0] - z[0, 0])) < 0.02


def test_range_only_model():
    ro = RangeOnly(sigma_range=5.0)
    x = np.array([[30.0, 0, 40.0, 0, 0]])
    assert ro.h(x)[0, 0] == pytest.approx(50.0)
    np.testing.assert_allclose(ro.jacobian(x)[0, 0, [0, 2]], [0.6, 0.8])
    np.testing.assert_allclose(ro.logpdf(np.array([[53.0]]), x), stats.norm(50, 5).logpdf(53.0))


def test_a_negative_noisy_range_is_written_as_the_same_point_in_canonical_polar_form():
    br = BearingRange(sigma_bearing=0.01, sigma_range=2000.0)
    x = np.array([[30.0, 0, 40.0, 0, 0]] * 400)  # range 50 m: most draws with sigma 2 km are negative
    raw = br.h(x) + np.random.default_rng(3).standard_normal((400, 2)) * [0.01, 2000.0]
    z = br.sample(np.random.default_rng(3), x)
    neg = raw[:, 1] < 0
    assert neg.sum() > 100 and (z[:, 1] >= 0).all() and (z[:, 0] >= -np.pi).all() and (z[:, 0] < np.pi).all()
    np.testing.assert_array_equal(z[~neg], np.stack([wrap_angle(raw[~neg, 0]), raw[~neg, 1]], 1))
    np.testing.assert_allclose(z[neg, 1], -raw[neg, 1])
    # the same point of the plane: r [sin b, cos b]
    pos_raw = raw[:, 1:] * np.stack([np.sin(raw[:, 0]), np.cos(raw[:, 0])], 1)
    np.testing.assert_allclose(br.to_cartesian(z)[0], pos_raw, atol=1e-6)
    ro = RangeOnly(sigma_range=2000.0)
    raw_r = ro.h(x) + 2000.0 * np.random.default_rng(4).standard_normal((400, 1))
    zr = ro.sample(np.random.default_rng(4), x)
    assert (raw_r < 0).sum() > 100
    np.testing.assert_array_equal(zr, np.abs(raw_r))


def test_to_cartesian_matches_monte_carlo():
    br = BearingRange(sigma_bearing=np.deg2rad(1), sigma_range=5.0)
    z = np.array([[0.3, 1200.0]])
    pos, cov = br.to_cartesian(z)
    np.testing.assert_allclose(pos[0], [1200 * np.sin(0.3), 1200 * np.cos(0.3)])
    rng = np.random.default_rng(0)
    zs = z + rng.standard_normal((200_000, 2)) * [br.sigma_bearing, br.sigma_range]
    ps = np.stack([zs[:, 1] * np.sin(zs[:, 0]), zs[:, 1] * np.cos(zs[:, 0])], axis=1)
    np.testing.assert_allclose(np.cov(ps.T), cov[0], rtol=0.03)


def test_uniform_clutter_density_and_samples():
    cl = UniformClutter(rate=15.0, low=(-np.pi / 2, 0.0), high=(np.pi / 2, 2000.0))
    assert cl.log_density == pytest.approx(-np.log(2000 * np.pi))
    assert cl.log_intensity == pytest.approx(np.log(15 / (2000 * np.pi)))
    lp = cl.logpdf(np.array([[0.0, 100.0], [2.0, 100.0], [0.0, 2500.0]]))
    assert lp[0] == pytest.approx(cl.log_density) and np.isneginf(lp[1:]).all()
    rng = np.random.default_rng(1)
    counts = [cl.sample(rng).shape[0] for _ in range(4000)]
    assert abs(np.mean(counts) - 15.0) < 4 * np.sqrt(15.0 / 4000)
    zs = np.concatenate([cl.sample(rng) for _ in range(300)])
    assert stats.kstest(zs[:, 1], stats.uniform(0, 2000).cdf).pvalue > 1e-3


def test_detection_field_of_view_and_snr():
    det = Detection(p_detect=0.9, range_max=2000.0)
    x = np.array([[0, 0, 1000.0, 0, 0], [0, 0, 2100.0, 0, 0], [0, 0, -500.0, 0, 0]], dtype=float)
    np.testing.assert_allclose(det.prob(x), [0.9, 0.0, 0.0])
    # Swerling I: p_D(snr) = p_D ** ((1 + snr_ref) / (1 + snr)); at snr = snr_ref unchanged
    same = Detection(p_detect=0.9, snr_db=13.0, snr_reference_db=13.0)
    assert same.p_detect_effective == pytest.approx(0.9)
    low = Detection(p_detect=0.98, snr_db=-3.0, snr_reference_db=13.0)
    snr, ref = 10 ** -0.3, 10 ** 1.3
    assert low.p_detect_effective == pytest.approx(0.98 ** ((1 + ref) / (1 + snr)))


def test_params_builtin_values_and_overrides(tmp_path):
    vo = load_params("vo2017")
    assert (vo.sigma_accel, vo.p_survival, vo.p_detect, vo.clutter_rate) == (5.0, 0.99, 0.98, 15.0)
    assert vo.measurement().sigma_bearing == pytest.approx(np.deg2rad(2.0))
    assert vo.birth == [] and vo.birth_rate is None and vo.anywhere_birth_rate == 0.1  # where: the scenario
    paper = load_params("paper")
    assert (paper.sigma_accel, paper.p_survival, paper.sigma_range) == (15.0, 0.95, 5.0)
    snr = load_params("vo2017", ["snr_db=-10"])
    assert snr.measurement().sigma_range == pytest.approx(10.0 * np.sqrt(10.0))
    assert load_params("vo2017", ["clutter_rate=3"]).clutter_rate == 3.0
    with pytest.raises(ConfigError, match="p_detect"):
        load_params("vo2017", ["p_detect=1.5"])
    with pytest.raises(ConfigError, match="unknown key 'nope'"):
        load_params("vo2017", ["nope=1"])
    with pytest.raises(ConfigError, match="not a built-in"):
        load_params("nosuchset")
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nsigma_range = -1\n')
    with pytest.raises(ConfigError, match="bad.toml.*sigma_range"):
        load_params(bad)
    good = tmp_path / "mine.toml"
    good.write_text('name = "mine"\nclutter_rate = 2.5\n')
    assert load_params(good).clutter_rate == 2.5


def test_sensor_kind_literal_matches_the_registry():
    """``tracker.types.SensorKind`` names exactly the kinds of the registry ``KINDS``."""
    from typing import get_args

    from bnptrack.tracker.models.measurement import KINDS
    from bnptrack.tracker.types import SensorKind

    assert set(get_args(SensorKind)) == set(KINDS)


def test_registry_builds_each_kind_from_the_sensor():
    """``ModelParams`` builds measurement, clutter and detection models through the registry:
    hand-checked fields for each of the three kinds at a posed sensor."""
    from bnptrack.tracker.models.clutter import SectorClutter
    from bnptrack.tracker.models.measurement import Cartesian

    p = load_params("vo2017", ["range_clutter_rate=2.0", "sigma_xy=7.0"])
    s_br = p.sensor("r0", "bearing_range", (100.0, -50.0, 0.25))
    assert p.measurement("bearing_range", s_br) == BearingRange(np.deg2rad(2.0), 10.0, 100.0, -50.0, 0.25)
    c = p.clutter("bearing_range", s_br)
    assert isinstance(c, UniformClutter) and c.rate == 15.0
    assert c.low == (-np.pi / 2, 0.0) and c.high == (np.pi / 2, 2000.0)
    assert not p.detection("bearing_range", s_br).range_only
    s_r = p.sensor("r1", "range", (0.0, 0.0, 0.0))
    assert p.measurement("range", s_r) == RangeOnly(10.0, 0.0, 0.0, np.pi / 2, 0.0)
    c = p.clutter("range", s_r)
    assert c.rate == 2.0 and c.low == (0.0,) and c.high == (2000.0,)  # range_clutter_rate applies
    assert p.detection("range", s_r).range_only
    s_xy = p.sensor("c0", "xy", (1.0, 2.0, 0.5))
    assert p.measurement("xy", s_xy) == Cartesian(7.0, 1.0, 2.0, 0.5)
    assert p.clutter("xy", s_xy) == SectorClutter(15.0, 0.0, 2000.0, np.pi / 2, 1.0, 2.0, 0.5)
    with pytest.raises(ValueError, match="unknown measurement kind"):
        p.measurement("sonar", s_xy)


def test_a_new_kind_is_its_model_class_and_registry_entry(monkeypatch):
    """Registering a kind (model class with ``from_sensor`` + a ``KINDS`` entry) is enough for
    ``ModelParams`` to build its measurement, clutter and detection models."""
    from dataclasses import dataclass

    from bnptrack.tracker.models import measurement as mm

    @dataclass(frozen=True)
    class Bearing1D:
        sigma: float
        x: float
        dim: int = 1
        kind: str = "bearing"

        @classmethod
        def from_sensor(cls, s):
            return cls(s.sigma_bearing, s.x)

    entry = mm.MeasurementKind("bearing", Bearing1D, 1, (0,), (-np.pi,), (np.pi,), "[bearing_rad]",
                               lambda s: UniformClutter(s.clutter_rate, (-s.half_fov,), (s.half_fov,)),
                               clutter_rate_field="range_clutter_rate")
    monkeypatch.setitem(mm.KINDS, "bearing", entry)
    p = load_params("vo2017", ["range_clutter_rate=3.0"])
    s = p.sensor("esm", "bearing", (5.0, 0.0, 0.0))
    assert p.measurement("bearing", s) == Bearing1D(np.deg2rad(2.0), 5.0)
    c = p.clutter("bearing", s)
    assert c.rate == 3.0 and c.high == (np.pi / 2,)
    assert not p.detection("bearing", s).range_only
