"""Time between frames dt != T: process noise Q(dt), survival and births
over dt, the hyperparameter birth lag across skipped frame numbers (docs/models.md, "Time
between frames")."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp.clusters import _Clusters
from bnptrack.tracker.bnp.filter import _born_between
from bnptrack.tracker.glmb import GlmbConfig, GlmbState, make_glmb
from bnptrack.tracker.models.motion import CoordinatedTurn, process_noise_block
from bnptrack.tracker.models.params import BirthComponent, load_params
from bnptrack.tracker.types import Frame

SA, ST = 5.0, np.deg2rad(1.0)


def _F_cv(dt):
    """Constant-velocity transition of [px, vx, py, vy, w] (the CT Jacobian at w = 0, v = 0)."""
    F = np.eye(5)
    F[0, 1] = F[2, 3] = dt
    return F


def test_process_noise_block_hand_values():
    # q = sa^2 T0 = 25; dt = 2: c = 8/3 - 1/6 = 2.5; dt = 0.5: c = 0.125 / 4
    np.testing.assert_allclose(process_noise_block(2.0, SA, 1.0), [[62.5, 50.0], [50.0, 50.0]], rtol=1e-14)
    np.testing.assert_allclose(process_noise_block(0.5, SA, 1.0), [[0.78125, 3.125], [3.125, 12.5]], rtol=1e-14)
    # T0 = 2, dt = 3: q = 50, c = 9 - 4 * 3 / 12 = 8
    np.testing.assert_allclose(process_noise_block(3.0, SA, 2.0), [[400.0, 225.0], [225.0, 150.0]], rtol=1e-14)


@pytest.mark.parametrize("T", [1.0, 0.5, 2.0])
def test_at_the_scan_period_q_is_the_papers_bit_for_bit(T):
    composed = CoordinatedTurn(T, SA, ST, period=T)
    paper = CoordinatedTurn(T, SA, ST)
    assert np.array_equal(composed.G, paper.G) and np.array_equal(composed.Q, paper.Q)
    assert np.array_equal(load_params("vo2017", [f"T={T}"]).motion(T).Q, paper.Q)


@pytest.mark.parametrize("n", [2, 3, 5])
def test_q_over_n_periods_is_n_paper_steps(n):
    """A dropped frame is predicted as if the sensor had scanned and seen nothing: Q(n T) is the
    sum over i < n of F^i Q(T) F^iT (constant-velocity F)."""
    T = 0.8
    step = CoordinatedTurn(T, SA, ST).Q
    total = sum(np.linalg.matrix_power(_F_cv(T), i) @ step @ np.linalg.matrix_power(_F_cv(T), i).T
                for i in range(n))
    np.testing.assert_allclose(CoordinatedTurn(n * T, SA, ST, period=T).Q, total, rtol=1e-12)


@pytest.mark.parametrize("a, b", [(1.3, 2.4), (1.0, 1.7), (3.5, 1.0)])
def test_q_composes_exactly_beyond_the_period(a, b):
    Qa, Qb = (CoordinatedTurn(t, SA, ST, period=1.0).Q for t in (a, b))
    np.testing.assert_allclose(_F_cv(b) @ Qa @ _F_cv(b).T + Qb, CoordinatedTurn(a + b, SA, ST, period=1.0).Q,
                               rtol=1e-12)


def test_below_the_period_velocity_and_turn_noise_grow_linearly():
    for dt in (0.1, 0.5, 0.9):
        Q = CoordinatedTurn(dt, SA, ST, period=1.0).Q
        assert Q[1, 1] == pytest.approx(SA**2 * dt) and Q[3, 3] == pytest.approx(SA**2 * dt)
        assert Q[0, 1] == pytest.approx(SA**2 * dt**2 / 2) and Q[4, 4] == pytest.approx(ST**2 * dt)
        assert Q[0, 0] == pytest.approx(SA**2 * dt**3 / 4)
    assert not CoordinatedTurn(0.0, SA, ST, period=1.0).Q.any()  # two sensors at one instant


def test_q_is_psd_and_continuous_across_the_period():
    for dt in np.linspace(0.0, 4.0, 81):
        assert np.linalg.eigvalsh(CoordinatedTurn(dt, SA, ST, period=1.0).Q).min() > -1e-9
    lo, hi = (CoordinatedTurn(t, SA, ST, period=1.0).Q for t in (1.0 - 1e-9, 1.0 + 1e-9))
    np.testing.assert_allclose(lo, hi, atol=1e-6)


def test_samples_over_a_gap_have_covariance_q():
    """Generative check: x' - f(x) over dt = 2.5 (the (5, 5) gain) has covariance Q(2.5)."""
    m = CoordinatedTurn(2.5, SA, ST, period=1.0)
    x = np.zeros((200_000, 5))
    d = m.sample(np.random.default_rng(7), x) - m.f(x)
    scale = np.sqrt(np.outer(np.diag(m.Q), np.diag(m.Q)))
    assert np.all(np.abs(np.cov(d.T) - m.Q) <= 0.015 * scale)  # ~5 standard errors at n = 2e5


def test_dwna_ablation_is_the_papers_formula_at_dt():
    p = load_params("vo2017", ["process_noise_dt='dwna'"])
    np.testing.assert_allclose(p.motion(2.0).Q, CoordinatedTurn(2.0, SA, ST).Q, rtol=1e-15)
    assert p.motion(2.0).Q[1, 1] == pytest.approx(100.0)  # sa^2 dt^2, twice the composed 50


def test_survival_over_dt_composes():
    p = load_params("vo2017")
    x = np.array([[0.0, 1.0, 800.0, 1.0, 0.0], [0.0, 1.0, 3000.0, 1.0, 0.0]])  # inside, outside
    np.testing.assert_allclose(p.survival_over(x, 0.7) * p.survival_over(x, 1.6), p.survival_over(x, 2.3),
                               rtol=1e-13)
    np.testing.assert_allclose(p.survival_over(x, 2.0), [0.99**2, 0.7**2], rtol=1e-13)


def _glmb_birth_r(dt_ns, prev_sensor):
    p = load_params("vo2017")
    comps = [BirthComponent(0.03, [0.0, 0.0, 500.0, 0.0, 0.0], [10.0, 10.0, 10.0, 10.0, 0.01])]
    tr = make_glmb(p, GlmbConfig(birth=comps, birth_model="static"))
    st = GlmbState(5, 5_000_000_000, birth_sensor=prev_sensor)
    frame = Frame(7, 5_000_000_000 + dt_ns, "s", "bearing_range", np.zeros((0, 2)))
    return float(tr._births(st, frame, dt_ns / 1e9).r[0])


def test_glmb_static_birth_over_dt():
    """A region's r is per scan T: over dt from the same sensor's previous frame 1-(1-r)^(dt/T)
    (two dropped scans: a birth in any of them); exactly r at dt = T; a frame of another sensor
    keeps r (the sensors' frames interleave within one scan)."""
    assert _glmb_birth_r(1_000_000_000, "s") == 0.03
    assert _glmb_birth_r(2_000_000_000, "s") == pytest.approx(1 - 0.97**2, rel=1e-12)
    assert _glmb_birth_r(500_000_000, "s") == pytest.approx(1 - 0.97**0.5, rel=1e-12)
    assert _glmb_birth_r(0, "cam") == 0.03


def test_born_between_counts_each_frame_once_across_skipped_numbers():
    labels = ("1.0", "2.3", "2.4", "4.1", "5.0", "12.7")
    c = _Clusters(labels, np.zeros((6, 5)), np.zeros((6, 5, 5)), np.array([0.5, 0.25, 0.125, 1.0, 0.75, 0.9]),
                  np.ones(6))
    lag = 4
    # frames 1, 2, 4, 5, 7, 8, 10, ... (every third dropped): frame k counts births in (prev - lag, k - lag]
    processed = [1, 2, 4, 5, 7, 8, 10, 11, 13, 14, 16, 17]
    counted = [_born_between(c, prev - lag, k - lag) for prev, k in zip([-1] + processed, processed)]
    assert sum(counted) == pytest.approx(0.5 + 0.25 + 0.125 + 1.0 + 0.75 + 0.9)
    assert counted[processed.index(7)] == pytest.approx(0.375)  # window (1, 3]: frame 2
    assert counted[processed.index(5)] == pytest.approx(0.5)  # window (0, 1]: frame 1


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
@pytest.mark.parametrize("turn_deg, tol", [(0.0, 0.02), (3.0, 0.03)])
def test_one_prediction_over_a_gap_equals_two_scans(filt, turn_deg, tol):
    """Dropped frame = a scan that saw nothing: predicting 2 s at once gives the mean, covariance
    and existence of two 1 s predictions.  Covariance entries agree within ``tol`` of
    sqrt(P_ii P_jj): what is left is the turn (the first scan's noise rotated by omega T into the
    other axis, and the turn noise carried into position), which the paper's omega-free G leaves
    out of Q."""
    from bnptrack.tracker.bnp import BnpConfig, BnpState, make_tracker

    p = load_params("vo2017")
    tr = make_tracker("ddp-mb", p, BnpConfig(filter=filt))
    x = np.array([100.0, 8.0, 900.0, -5.0, np.deg2rad(turn_deg)])
    P = np.diag([50.0, 4.0, 60.0, 3.0, 1e-4])
    st = BnpState(5, 5_000_000_000, ("1.0",), x[None], P[None], np.array([0.9]), np.ones(1))
    once = tr._predict(st, 2.0, "bearing_range")
    half = tr._predict(st, 1.0, "bearing_range")
    twice = tr._predict(BnpState(6, 6_000_000_000, ("1.0",), half.mean, half.cov, half.q, np.ones(1)), 1.0,
                        "bearing_range")
    sd = np.sqrt(np.diag(once.cov[0]))
    assert np.all(np.abs(once.mean[0] - twice.mean[0]) <= 1e-3 * sd)  # the UKF's mean is a sigma-point mean
    scale = np.sqrt(np.outer(np.diag(once.cov[0]), np.diag(once.cov[0])))
    assert np.all(np.abs(once.cov[0] - twice.cov[0]) <= tol * scale)
    assert once.q[0] == pytest.approx(twice.q[0], rel=1e-12)
    # the paper's formula at dt (``dwna``) adds twice the velocity variance of two scans
    old = make_tracker("ddp-mb", load_params("vo2017", ["process_noise_dt='dwna'"]), BnpConfig(filter=filt))
    assert old._predict(st, 2.0, "bearing_range").cov[0, 1, 1] > twice.cov[0, 1, 1] + 40.0


def test_bnp_hyperparameter_forgetting_is_per_scan_period():
    """The grid log-likelihood of past frames decays by hyper_forgetting^(dt/T): from a state
    without clusters (nothing else depends on dt) frames 1 s and 2 s later differ only there."""
    from bnptrack.tracker.bnp import BnpState, make_tracker

    tr = make_tracker("ddp-mb", load_params("vo2017"))
    grid = tr.initial_state().hyper_loglik
    h0 = -np.arange(grid.size, dtype=float).reshape(grid.shape) / 7.0
    st = BnpState(4, 4_000_000_000, alpha=0.1, hyper_loglik=h0)
    z = np.array([[0.1, 800.0], [-0.4, 1200.0]])
    out = {}
    for dt_s in (1, 2):
        frame = Frame(6, (4 + dt_s) * 1_000_000_000, "s", "bearing_range", z)
        out[dt_s] = tr.step(st, frame, np.random.default_rng(3))[0].hyper_loglik
    f = tr.config.hyper_forgetting
    np.testing.assert_allclose(out[2] - out[1], (f**2 - f) * h0, rtol=1e-10, atol=1e-12)


def test_process_noise_backwards_in_time_is_an_error():
    """Prediction noise is defined forward in time only; ``f`` alone still runs backwards (the
    scenarios back-propagate a path's start with ``T = -1``)."""
    back = CoordinatedTurn(T=-1.0)
    assert back.f(np.array([[0.0, 1.0, 0.0, 2.0, 0.0]]))[0, 0] == -1.0
    with pytest.raises(ValueError, match="T must be >= 0"):
        back.Q
