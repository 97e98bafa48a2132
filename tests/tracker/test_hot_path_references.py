"""The per-frame hot paths of the object level, the GLMB's estimate and the scorer give the
same output bit for bit as their plain reference versions."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from bnptrack.sinks.run_scorer import RunScorer, _positions
from bnptrack.tracker.bnp import TRACKER_PRESETS, make_tracker
from bnptrack.tracker.bnp.clusters import _birth_frame, _Clusters
from bnptrack.tracker.bnp.filter import BnpTracker, _born_between
from bnptrack.tracker.glmb import estimate as glmb_estimate
from bnptrack.tracker.glmb import filter as glmb_filter
from bnptrack.tracker.glmb.filter import make_glmb
from bnptrack.tracker.state import run
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate


class _Uncached(BnpTracker):
    """The reference step: the sensor and its models built afresh every frame."""

    def _sensor_models(self, frame):
        sensor = self.params.frame_sensor(frame)
        return (sensor, self.params.measurement(frame.kind, sensor), self.params.clutter(frame.kind, sensor),
                self.params.detection(frame.kind, sensor))


def _states_equal(a, b) -> bool:
    return (a.labels == b.labels and np.array_equal(a.mean, b.mean) and np.array_equal(a.cov, b.cov)
            and np.array_equal(a.existence, b.existence) and np.array_equal(a.popularity, b.popularity)
            and a.alpha == b.alpha and np.array_equal(a.hyper_loglik, b.hyper_loglik))


def _moving(frames: list[Frame]) -> list[Frame]:
    """The frames with a pose that changes every third frame (a sensor set-up that moves)."""
    poses = [(0.0, 0.0, 0.0), (5.0, -3.0, 0.01)]
    return [Frame(f.frame, f.stamp_ns, f.sensor, f.kind, f.z, f.truth, poses[(i // 3) % 2]) for i, f in enumerate(frames)]


@pytest.mark.parametrize("moving", [False, True])
def test_sensor_models_once_per_setup_same_output(vo_params, vo_frames, estimates_equal, moving):
    frames = _moving(vo_frames[:30]) if moving else vo_frames[:30]
    cached = make_tracker("ddp-mb", vo_params)
    fresh = _Uncached(cached.params, cached.config, cached.name)
    for (_, ea, sa), (_, eb, sb) in zip(run(cached, frames, 5), run(fresh, frames, 5)):
        assert estimates_equal(ea, eb) and _states_equal(sa, sb)
        assert np.array_equal(ea.cardinality_pmf, eb.cardinality_pmf)
        assert {k: v for k, v in ea.diagnostics.items() if k != "ms"} == \
               {k: v for k, v in eb.diagnostics.items() if k != "ms"}


def test_sensor_models_cached_per_setup(vo_params, vo_frames):
    tr = make_tracker("ddp-mb", vo_params)
    f0, f1 = vo_frames[0], vo_frames[1]
    a, b = tr._sensor_models(f0), tr._sensor_models(f1)
    assert all(x is y for x, y in zip(a, b))  # same set-up: the same objects
    moved = Frame(f1.frame, f1.stamp_ns, f1.sensor, f1.kind, f1.z, f1.truth, (10.0, 0.0, 0.0))
    c = tr._sensor_models(moved)
    assert c[0].x == 10.0 and a[0].x != 10.0 and c[1] is not a[1]
    assert c[0] == vo_params.frame_sensor(moved)


def test_born_between_and_birth_frame_as_before():
    labels = ("3.0", "7.2", "12.1", "5.5", "12.0", "9.3", "0.4")
    r = np.array([0.5, 0.25, 0.125, 0.9, 1e-3, 0.3, 0.7])
    c = _Clusters(labels, np.zeros((7, 5)), np.zeros((7, 5, 5)), r, np.ones(7))
    for lo, hi in [(-1, 20), (3, 9), (5, 12), (12, 12), (6, 7)]:
        old = float(sum(x for lab, x in zip(labels, r.tolist()) if lo < int(lab.split(".")[0]) <= hi))
        assert _born_between(c, lo, hi) == old
    assert _born_between(c, 3, 9) == 0.9 + 0.25 + 0.3  # frames 5, 7, 9 in label order (hand value)
    assert [_birth_frame(x) for x in ("17.3", "-2.1", "g4.0", "8")] == [17, -2, 0, 8]
    with pytest.raises(ValueError):
        _born_between(_Clusters(("a.1",), np.zeros((1, 5)), np.zeros((1, 5, 5)), np.ones(1), np.ones(1)), 0, 5)


def test_bnp_estimate_rows_are_copies(vo_params, vo_frames):
    # the model's existence published unchanged (calibration off), to compare with the state's
    tr = make_tracker("ddp-mb", vo_params, msgspec.structs.replace(TRACKER_PRESETS["ddp-mb"], calibration_weight=0.0))
    for _, est, state in run(tr, vo_frames[:15], 2):
        idx = {lab: i for i, lab in enumerate(state.labels)}
        for t in est.tracks:
            i = idx[t.label]
            assert np.array_equal(t.state, state.mean[i]) and np.array_equal(t.covariance, state.cov[i])
            assert t.existence == float(state.existence[i]) and type(t.existence) is float
            assert not np.shares_memory(t.state, state.mean) and not np.shares_memory(t.covariance, state.cov)
    assert est.tracks


def _estimate_from_rows_before(st, row_meas, mg, frame, rows) -> Estimate:
    """``glmb.estimate.estimate_from_rows`` as it was (a5c58f3)."""
    tracks = tuple(TrackEstimate(st.labels[r], st.mean[r].copy(), st.cov[r].copy(),
                                 float(min(1.0, mg.existence[mg.label_id[r]]))) for r in rows.tolist())
    M = frame.n_measurements
    assignments = [None] * M
    probs = np.clip(1.0 - mg.p_used[:M], 0.0, 1.0).tolist()
    for r in rows.tolist():
        m = int(row_meas[r])
        if m >= 0:
            assignments[m] = st.labels[r]
            probs[m] = min(1.0, max(0.0, float(mg.pair_p[mg.label_id[r] * M + m])))
    return Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assignments), tuple(probs))


def test_glmb_estimate_as_before(vo_params, vo_frames, estimates_equal, monkeypatch):
    seen = []

    def both(st, row_meas, mg, frame, rows):
        new = glmb_estimate.estimate_from_rows(st, row_meas, mg, frame, rows)
        seen.append((new, _estimate_from_rows_before(st, row_meas, mg, frame, rows), st))
        return new

    monkeypatch.setattr(glmb_filter, "estimate_from_rows", both)
    list(run(make_glmb(vo_params), vo_frames[:30], 4))
    assert len(seen) == 30 and sum(len(n.tracks) for n, _, _ in seen) > 30
    for new, old, st in seen:
        assert estimates_equal(new, old)
        assert [type(t.existence) for t in new.tracks] == [float] * len(new.tracks)
        assert all(not np.shares_memory(t.state, st.mean) and not np.shares_memory(t.covariance, st.cov)
                   for t in new.tracks)


def test_glmb_existence_capped_at_one_nan_too():
    """``min(1.0, r)`` per row: 1.0 for r above 1 and for NaN, r itself below."""
    r = np.array([0.25, 1.0 + 1e-12, math.nan, 1.0])
    got = np.fmin(r, 1.0).tolist()
    assert got == [min(1.0, x) for x in r.tolist()] == [0.25, 1.0, 1.0, 1.0]


def test_positions_as_estimate_positions():
    rng = np.random.default_rng(9)
    for n in (0, 1, 7):
        tracks = tuple(TrackEstimate(f"{i}.0", rng.normal(size=5) * 1e3, np.eye(5), 0.9) for i in range(n))
        est = Estimate(3, 0, tracks)
        got, want = _positions(est), est.positions
        assert got.dtype == want.dtype and got.shape == want.shape == (n, 2)
        assert np.array_equal(got, want)
    t = TrackEstimate("1.0", np.array([1.5, 0.0, -2.25, 0.0, 0.0]), np.eye(5), 1.0)
    assert _positions(Estimate(0, 0, (t,))).tolist() == [[1.5, -2.25]]


def test_run_scorer_raises_on_a_non_finite_estimate():
    from bnptrack.tracker.types import Truth

    t = TrackEstimate("1.0", np.array([np.nan, 0.0, 1.0, 0.0, 0.0]), np.eye(5), 1.0)
    f = Frame(0, 0, "s", "xy", np.zeros((0, 2)), Truth(("a",), np.zeros((1, 5))))
    with pytest.raises(ValueError):
        RunScorer().update(f, Estimate(0, 0, (t,)))


@pytest.mark.parametrize("dt_scale", [1.0, 0.5, 2.0])
def test_predict_survival_and_detection_as_params(vo_params, vo_frames, dt_scale):
    """P_S and P_D of the prediction equal ModelParams.survival_over and Detection.prob at the
    predicted means, inside and outside the field of view (one test of it at dt = T)."""
    from bnptrack.tracker import filtering as kf
    from bnptrack.tracker.bnp.filter import BnpState

    tr = make_tracker("ddp-mb", vo_params)
    rng = np.random.default_rng(11)
    n = 60
    mean = np.column_stack([rng.uniform(-2500, 2500, n), rng.normal(0, 20, n), rng.uniform(-500, 2500, n),
                            rng.normal(0, 20, n), rng.normal(0, 0.02, n)])
    cov = np.broadcast_to(np.diag([100.0, 4.0, 100.0, 4.0, 1e-4]), (n, 5, 5)).copy()
    state = BnpState(frame=3, labels=tuple(f"1.{i}" for i in range(n)), mean=mean, cov=cov,
                     existence=rng.uniform(0.1, 1.0, n), popularity=np.ones(n))
    frame = vo_frames[4]
    sensor, _, _, detection = tr._sensor_models(frame)
    dt = vo_params.T * dt_scale
    pred = tr._predict(state, dt, frame.kind, sensor, detection)
    m, P = kf.ukf_predict(vo_params.motion(dt) if dt != vo_params.T else tr.motion, mean, cov)
    want_q = state.existence * vo_params.survival_over(m, dt, frame.kind, sensor)
    want_pd = vo_params.detection(frame.kind, sensor).prob(m)
    assert np.array_equal(pred.mean, m) and np.array_equal(pred.cov, P)
    assert np.array_equal(pred.q, want_q) and np.array_equal(pred.p_detect, want_pd)
    assert 0 < int(np.sum(want_pd > 0)) < n  # both sides of the field of view were tested
