"""The calibrated existence (tracker/calibration.py) and the two-level tracker that publishes it."""

from __future__ import annotations

from dataclasses import fields, replace

import msgspec
import numpy as np
import pytest

from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.calibration import CalibrationState, ExistenceCalibration, track_class
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.registry import build
from bnptrack.tracker.state import restore, run, snapshot
from bnptrack.tracker.types import Estimate, TrackEstimate


def _track(label: str, x: float = 0.0, r: float = 0.9) -> TrackEstimate:
    return TrackEstimate(label, np.array([x, 0.0, 0.0, 0.0, 0.0]), np.eye(5), r)


def _feed(cal: ExistenceCalibration, frames: list[tuple[list[TrackEstimate], tuple]], state=None, start: int = 1):
    """Run ``cal`` over (tracks, assignments) per frame (frames ``start``, ``start + 1``, ... at
    their number in seconds); the published existences per frame and the last state."""
    state = CalibrationState() if state is None else state
    out = []
    for k, (tracks, assigned) in enumerate(frames, start=start):
        state, est = cal.step(state, Estimate(k, k * 10**9, tuple(tracks), assigned, (1.0,) * len(assigned)))
        out.append([t.existence for t in est.tracks])
    return out, state


def test_learned_hazard_miss_rate_and_young_odds_hand_computed():
    cal = ExistenceCalibration(0.99, 0.98, weight=20.0, hazard_weight=200.0, odds_weight=5.0)
    # 300 established track-scans, 4 deaths, 5 missed scans of live objects:
    # h = (200 * 0.01 + 4) / 500 = 0.012, miss rate = (200 * 0.02 + 5) / 500 = 0.018
    learned = np.array([300.0, 4.0, 5.0, 10.0, 1.0])
    h, mu = cal.rates(learned)
    assert h == pytest.approx(0.012) and mu == pytest.approx(0.018)
    a = (1 - 0.012) * 0.018  # alive and missed, per scan
    assert cal.missed(learned, 1) == pytest.approx(a / (a + 0.012))  # 0.5971
    assert cal.missed(learned, 1) == pytest.approx(0.5970991136)
    assert cal.missed(learned, 2) == pytest.approx(a * a / (a * a + 0.012 * (1 + a)))  # 0.0252
    # without a run's evidence: the model's odds, 0.99 x 0.02 against 0.01
    assert cal.missed(np.zeros(5), 1) == pytest.approx(0.99 * 0.02 / (0.99 * 0.02 + 0.01))
    # young: odds ratio (5 + 10) / (5 + 1) = 2.5, so 0.5 -> 2.5 x 0.5 / (2.5 x 0.5 + 0.5) = 5 / 7
    assert cal.young(learned, 0.5) == pytest.approx(5 / 7)
    assert cal.young(np.zeros(5), 0.5) == pytest.approx(0.5)
    assert cal.prior(learned, 3, 0, 0.97) == 0.97 and cal.prior(learned, 1, 1, 0.5) == pytest.approx(5 / 7)


def test_a_model_without_death_or_misses_keeps_a_missed_track_alive():
    # p_survival = p_detect = 1 and no evidence: no hazard (h = 0) and no misses (mu = 0), so the
    # odds of a missed track are 0 against 0; it cannot have died, so it is alive
    cal = ExistenceCalibration(1.0, 1.0)
    with np.errstate(all="raise"):
        assert cal.missed(np.zeros(5), 1) == 1.0
        np.testing.assert_allclose(cal.prior(np.zeros(5), [3, 3, 1], [0, 2, 0], [0.9, 0.9, 0.4]), [0.9, 1.0, 0.4], rtol=1e-12)
    # with a death hazard and no misses, a missed track is dead
    assert ExistenceCalibration(0.99, 1.0).missed(np.zeros(5), 2) == 0.0


def test_classes():
    assert [track_class(n, 0) for n in (1, 2, 6, 9)] == [0, 1, 5, 5]
    assert [track_class(n, 1) for n in (0, 2, 3, 10)] == [6, 6, 9, 9]
    assert [track_class(3, m) for m in (1, 2, 3, 7)] == [9, 10, 11, 11]


_CAL = ExistenceCalibration(0.99, 0.98, weight=2.0, hazard_weight=100.0, odds_weight=1.0)
_ESTABLISHED_THEN_MISSED = [([_track("A")], ("A",))] * 3 + [([_track("A", r=0.66)], ())]


def test_a_death_is_learned_and_used_hand_computed():
    frames = _ESTABLISHED_THEN_MISSED + [([], ())] * 4
    out, state = _feed(_CAL, frames)
    # frame 1: no outcome yet, the tracker's 0.9; frame 2: frame 1 (young, 1 - r = 0.1) was
    # real, odds ratio (1 + 0.1) / 1: 1.1 x 0.9 / (1.1 x 0.9 + 0.1); frame 3 established: 0.9
    assert out[:3] == [[pytest.approx(0.9)], [pytest.approx(0.99 / 1.09)], [pytest.approx(0.9)]]
    # frame 4, first miss of an established track (exposure 2 scans): h = 1/102, miss rate
    # 2/102, alive (101/102)(2/102) against 1/102: 202/304, replacing the tracker's 0.66
    assert out[3] == [pytest.approx(202 / 304)]
    # the label ended after frame 4; 4 scans later, with no track re-born in its gate: its
    # detected frame 3 (class 2) and its miss (class 9) are counted not real, and one death
    np.testing.assert_allclose(state.learned, [2.0, 1.0, 0.0, 0.2, 0.0])
    assert state.counts[0].tolist() == [1, 1] + [0] * 10  # frames 1, 2: detected again
    assert np.flatnonzero(state.counts[1]).tolist() == [2, 9] and state.labels == ()
    # a second track: first detection, odds ratio 1.2 and class 0 one real:
    # (2 x 1.08 / 1.18 + 1) / 3; third detection, class 2 one not real: (2 x 0.9 + 0) / 3;
    # first miss, h = 2/104, miss rate 2/104, prior 204/412, class 9 one not real
    b = _track("B")
    out, _ = _feed(_CAL, [([b], ("B",))] * 3 + [([_track("B", r=0.66)], ())], state, start=9)
    assert out[0] == [pytest.approx((2 * 1.08 / 1.18 + 1) / 3)]
    assert out[2] == [pytest.approx(0.6)]
    assert out[3] == [pytest.approx((2 * 204 / 412) / 3)]


def test_one_detection_after_a_miss_holds_the_outcome():
    again = [([_track("A")], ("A",))]
    _, held = _feed(_CAL, _ESTABLISHED_THEN_MISSED + again)
    assert held.counts.sum() == 2 and held.learned[2] == 0  # frames 1, 2 only; the miss is held
    _, real = _feed(_CAL, again, held, start=6)  # a second detection in a row: the miss was a live object's
    assert real.counts[0, 9] == 1 and real.counts[0, 2] == 1 and real.counts[0, 3] == 1
    assert real.learned[2] == 1 and real.learned[1] == 0
    _, dead = _feed(_CAL, [([], ())] * 4, held, start=6)  # the label ends: held and pending not real
    assert np.flatnonzero(dead.counts[1]).tolist() == [2, 3, 9] and dead.learned[1] == 1


def test_a_track_reborn_in_the_gate_counts_real():
    _, state = _feed(_CAL, _ESTABLISHED_THEN_MISSED)
    # frame 5: A is gone and C appears 1 m away (gate: covariance 1 + 1 s^2 x 1 + 1 = 3 per axis)
    _, far = _feed(_CAL, [([_track("C", x=100.0)], ("C",))], state, start=5)  # 100 m: outside the gate
    assert far.counts[0, 9] == 0 and "A" in far.labels
    _, state = _feed(_CAL, [([_track("C", x=1.0)], ("C",))], state, start=5)
    assert state.counts[0, 2] == 1 and state.counts[0, 9] == 1 and state.counts[1].sum() == 0
    np.testing.assert_allclose(state.learned, [2.0, 0.0, 1.0, 0.2, 0.0])  # a live object's missed scan
    assert state.labels == ("C",)


def test_the_calibration_moves_only_the_existence():
    cal = ExistenceCalibration()
    t = replace(_track("A"), cluster=4)
    state, est = cal.step(CalibrationState(), Estimate(1, 10**9, (t,), ("A", None), (0.8, 0.1)))
    (u,) = est.tracks
    assert u.label == "A" and u.state is t.state and u.covariance is t.covariance and u.cluster == 4
    assert [f.name for f in fields(TrackEstimate)] == ["label", "state", "covariance", "existence", "cluster"]
    assert est.assignments == ("A", None) and est.assignment_prob == (0.8, 0.1)
    with pytest.raises(ValueError, match="weight"):
        ExistenceCalibration(weight=0.0)


def _scene():
    sc = get_scenario("random", 3, scene=("K=40",))
    params = sc.adapt_params(load_params("vo2017"))
    return params, simulate_all(sc, params, 3)


# dpyp and ddp-mb share ddp's calibration path (its discounted variant, its object level): marked slow
@pytest.mark.parametrize("name", ["ddp", pytest.param("dpyp", marks=pytest.mark.slow),
                                  pytest.param("ddp-mb", marks=pytest.mark.slow), "glmb"])
def test_published_tracks_unchanged_and_snapshot_resume_identical(name):
    params, frames = _scene()
    tr = build(name, params)
    cfg = tr.config
    two_level = name in ("ddp", "dpyp")
    off = msgspec.structs.replace(cfg.objects if two_level else cfg, calibration_weight=0.0)
    off = build(name, params, msgspec.structs.replace(cfg, objects=off) if two_level else off)
    states, ests = [], []
    for _, e, s in run(tr, frames, seed=7):
        states.append(s)
        ests.append(e)
    raw = [e for _, e, _ in run(off, frames, seed=7)]
    moved = 0
    for a, b in zip(ests, raw):
        assert a.labels == b.labels and a.assignments == b.assignments
        for x, y in zip(a.tracks, b.tracks):
            np.testing.assert_array_equal(x.state, y.state)
            np.testing.assert_array_equal(x.covariance, y.covariance)
            assert x.cluster == y.cluster and 0.0 <= x.existence <= 1.0 and type(x.existence) is float
            moved += x.existence != y.existence
    assert moved > 0
    assert states[-1].cal_learned[0] > 0 and states[-1].cal_counts.sum() > 0
    back = restore(snapshot(states[19]), type(states[19]))
    for f in ("cal_counts", "cal_learned", "cal_rows", "cal_pending", "cal_mean", "cal_cov"):
        np.testing.assert_array_equal(getattr(back, f), getattr(states[19], f))
    assert back.cal_labels == states[19].cal_labels
    resumed = [e for _, e, _ in run(tr, frames[20:], seed=7, state=back)]
    for a, b in zip(ests[20:], resumed):
        assert a.labels == b.labels
        assert [t.existence for t in a.tracks] == [t.existence for t in b.tracks]


def test_a_snapshot_without_the_calibration_loads_and_starts_it_afresh():
    params, frames = _scene()
    tr = build("ddp", params)
    states = [s for _, _, s in run(tr, frames[:12], seed=7)]
    doc = msgspec.msgpack.decode(snapshot(states[-1]))
    doc["fields"] = {k: v for k, v in doc["fields"].items() if not k.startswith("cal_")}
    old = restore(msgspec.msgpack.encode(doc), type(states[-1]))
    assert old.cal_labels == () and not old.cal_counts.any() and old.labels == states[-1].labels
    (_, est, new), = run(tr, frames[12:13], seed=7, state=old)
    assert new.cal_labels == est.labels and not new.cal_counts.any()


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_gate_prefilter_keeps_every_state_with_a_gated_position(seed):
    from bnptrack.tracker.calibration import _may_gate, gated

    rng = np.random.default_rng(seed)
    G, K = 40, 30
    mean = rng.normal(0, 200, (G, 5))
    A = rng.normal(size=(G, 5, 5)) * rng.uniform(0.5, 60, (G, 1, 1))
    cov = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(5)
    dt = rng.uniform(0.5, 4.0, G)
    pos = rng.normal(0, 300, (K, 2))
    B = rng.normal(size=(K, 2, 2)) * rng.uniform(1, 30, (K, 1, 1))
    pos_cov = B @ np.swapaxes(B, 1, 2) + 0.1 * np.eye(2)
    exact = np.array([gated(mean[g], cov[g], dt[g], pos, pos_cov).any() for g in range(G)])
    may = _may_gate(mean, cov, dt, pos, pos_cov)
    assert exact.any() and not exact.all() and not may.all()  # both outcomes occur
    assert np.all(may[exact])  # a necessary condition: never drops a state gate holds
    # hand-computed: cov I (run 1 s: position variance 1 + 1 = 2 per axis) and pos_cov I give
    # tr S = 6, so the bound keeps |d|^2 <= 13.8 x 6 = 82.8 (d = 9 m) and drops d = 10 m
    one = np.zeros((1, 5))
    eye = np.eye(5)[None]
    assert _may_gate(one, eye, np.ones(1), np.array([[9.0, 0.0]]), np.eye(2)[None]).tolist() == [True]
    assert _may_gate(one, eye, np.ones(1), np.array([[10.0, 0.0]]), np.eye(2)[None]).tolist() == [False]
    nan = np.full((1, 5), np.nan)
    assert _may_gate(nan, eye, np.ones(1), np.array([[0.0, 0.0]]), np.eye(2)[None]).tolist() == [True]
    assert _may_gate(one, eye, np.ones(1), np.zeros((0, 2)), np.zeros((0, 2, 2))).tolist() == [False]
