"""Time from stamps: one prediction per frame over dt = stamp difference."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp import BnpConfig, BnpState, make_tracker
from bnptrack.tracker.glmb import GlmbConfig, GlmbState, make_glmb
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import Frame, FrameBoundError, frame_dt

S = 1_000_000_000


def test_frame_dt_rules():
    # stamps present: their difference, irregular or across a dropped frame
    assert frame_dt(4, 4 * S, 5, 4 * S + 700_000_000, 1.0) == pytest.approx(0.7, abs=1e-15)
    assert frame_dt(4, 4 * S, 6, 6 * S + 250_000_000, 1.0) == pytest.approx(2.25, abs=1e-15)
    # the simulator's stamps round(k T 1e9): exactly (frame difference) x T
    T = 0.1
    assert frame_dt(3, round(3 * T * 1e9), 5, round(5 * T * 1e9), T) == 2 * T
    # no stamps (both 0): frame difference x T; before the first frame: T
    assert frame_dt(2, 0, 5, 0, 0.5) == 1.5
    assert frame_dt(-1, 0, 7, 123, 0.5) == 0.5
    # equal stamps (two sensors at the same instant): no time passes
    assert frame_dt(2, 5 * S, 3, 5 * S, 1.0) == 0.0
    with pytest.raises(FrameBoundError, match="before that of frame 2"):
        frame_dt(2, 5 * S, 3, 4 * S, 1.0)


def _ct_by_hand(x, dt, sa, st, mode="composed", T0=1.0):
    """The CT transition over dt written out (Vo 2017, IV.B) and its Q(dt): ``dwna`` the
    paper's formula at dt; ``composed`` (docs/models.md, "Time between frames") per axis
    q [[c, dt^2/2], [dt^2/2, dt]], q = sa^2 T0, c = dt^3/4 (dt <= T0) or dt^3/3 - T0^2 dt/12,
    turn-rate variance st^2 T0 dt."""
    px, vx, py, vy, w = x
    s, c = np.sin(w * dt), np.cos(w * dt)
    f = np.array([px + s / w * vx - (1 - c) / w * vy, c * vx - s * vy,
                  (1 - c) / w * vx + py + s / w * vy, s * vx + c * vy, w])
    if mode == "dwna":
        G = np.zeros((5, 3))
        G[0:2, 0] = G[2:4, 1] = sa * np.array([dt**2 / 2, dt])
        G[4, 2] = dt * st
        return f, G @ G.T
    q = sa**2 * T0
    cpp = dt**3 / 4 if dt <= T0 else dt**3 / 3 - T0**2 * dt / 12
    Q = np.zeros((5, 5))
    for i in (0, 2):
        Q[i, i], Q[i, i + 1], Q[i + 1, i], Q[i + 1, i + 1] = q * cpp, q * dt**2 / 2, q * dt**2 / 2, q * dt
    Q[4, 4] = st**2 * T0 * dt
    return f, Q


def _ct_jacobian_numeric(x, dt, sa, st, eps=1e-6):
    J = np.zeros((5, 5))
    for i in range(5):
        e = np.zeros(5)
        e[i] = eps
        J[:, i] = (_ct_by_hand(x + e, dt, sa, st)[0] - _ct_by_hand(x - e, dt, sa, st)[0]) / (2 * eps)
    return J


@pytest.mark.parametrize("mode", ["composed", "dwna"])
@pytest.mark.parametrize("stamp_s, frame_no", [(5.0 + 0.63, 6), (7.0, 7), (7.5, 7)])  # irregular; dropped
def test_bnp_predicts_once_over_dt(stamp_s, frame_no, mode):
    p = load_params("vo2017", [f"process_noise_dt='{mode}'"])
    tr = make_tracker("ddp-mb", p, BnpConfig(filter="ekf"))
    x = np.array([100.0, 8.0, 900.0, -5.0, np.deg2rad(3.0)])
    P = np.diag([50.0, 4.0, 60.0, 3.0, 1e-4])
    st = BnpState(5, 5 * S, ("1.0",), x[None], P[None], np.array([0.9]), np.ones(1))
    dt = stamp_s - 5.0
    pred = tr._predict(st, frame_dt(st.frame, st.stamp_ns, frame_no, round(stamp_s * S), p.T), "bearing_range")
    f, Q = _ct_by_hand(x, dt, p.sigma_accel, np.deg2rad(p.sigma_turn_deg), mode)
    J = _ct_jacobian_numeric(x, dt, p.sigma_accel, np.deg2rad(p.sigma_turn_deg))
    np.testing.assert_allclose(pred.mean[0], f, rtol=1e-9)
    np.testing.assert_allclose(pred.cov[0], J @ P @ J.T + Q, rtol=1e-6, atol=1e-6)
    assert pred.q[0] == pytest.approx(0.9 * p.p_survival**dt, rel=1e-12)  # inside the FOV: P_S^(dt/T)


def test_glmb_predicts_once_over_dt():
    p = load_params("vo2017")
    tr = make_glmb(p, GlmbConfig(filter="ekf", birth=[]))
    x = np.array([-300.0, 10.0, 700.0, 4.0, np.deg2rad(-2.0)])
    P = np.diag([40.0, 4.0, 40.0, 4.0, 1e-4])
    st = GlmbState(5, 5 * S, ("1.0",), x[None], P[None], np.array([[0]]), np.zeros(1))
    frame = Frame(7, 5 * S + 1_400_000_000, "s", "bearing_range", np.zeros((0, 2)))  # 1.4 s, frame 6 dropped
    c = tr._candidates(st, frame_dt(5, 5 * S, 7, frame.stamp_ns, p.T), frame)
    f, Q = _ct_by_hand(x, 1.4, p.sigma_accel, np.deg2rad(p.sigma_turn_deg))
    J = _ct_jacobian_numeric(x, 1.4, p.sigma_accel, np.deg2rad(p.sigma_turn_deg))
    np.testing.assert_allclose(c.mean[0], f, rtol=1e-9)
    np.testing.assert_allclose(c.cov[0], J @ P @ J.T + Q, rtol=1e-6, atol=1e-6)
    assert np.exp(c.log_e[0]) == pytest.approx(p.p_survival**1.4, rel=1e-12)


@pytest.mark.parametrize("make", [lambda p: make_tracker("ddp-mb", p), lambda p: make_glmb(p)])
def test_stamp_going_back_is_rejected(make):
    p = load_params("vo2017")
    tr = make(p)
    st, _ = tr.step(tr.initial_state(), Frame(1, 10 * S, "s", "bearing_range", [[0.1, 500.0]]),
                    np.random.default_rng(0))
    with pytest.raises(FrameBoundError, match="before that of frame 1"):
        tr.step(st, Frame(2, 9 * S, "s", "bearing_range", [[0.1, 500.0]]), np.random.default_rng(0))
