"""The fixed-lag layer (tracker.lag): hindsight deaths, births, continuations and smoothing on
scripted online estimates, exact snapshots, and the offline run with ``lag``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from bnptrack.tracker.lag import FixedLag, restore_lag, run_lagged, snapshot_lag
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate

PARAMS = load_params("vo2017")
COV = np.diag([4.0, 1.0, 4.0, 1.0, 1e-4])


@dataclass(frozen=True)
class Count:
    n: int


class Scripted:
    """A tracker whose online estimates are given: ``script[k]`` is a list of
    ``(label, state, measurement row or None)`` for frame ``k``."""

    name = "scripted"

    def __init__(self, script):
        self.script = script

    def initial_state(self):
        return Count(0)

    def step(self, state, frame, rng):
        rows = self.script[frame.frame]
        tracks = tuple(TrackEstimate(lab, np.array(x, float), COV.copy(), 0.9) for lab, x, _ in rows)
        assign = [None] * frame.n_measurements
        for lab, _, m in rows:
            if m is not None:
                assign[m] = lab
        return Count(state.n + 1), Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assign), (1.0,) * len(assign))


def _xy(k, rows):
    return Frame(k, k * 10**9, "cam", "xy", np.array(rows, float).reshape(-1, 2))


def _run(script, frames, lag, smooth=False):
    layer = FixedLag(Scripted(script), PARAMS, lag, smooth=smooth)
    return [(f.frame, e) for f, e, _ in run_lagged(layer, frames, seed=0)]


def _line(k, v=10.0):
    """A constant-velocity object at x = 100 + v k, y = 50 (state [px, vx, py, vy, omega])."""
    return [100.0 + v * k, v, 50.0, 0.0, 0.0]


def test_every_frame_is_published_once_in_order_with_its_lag():
    frames = [_xy(k, [[0.0, 0.0]]) for k in range(6)]
    out = _run({k: [] for k in range(6)}, frames, lag=2)
    assert [k for k, _ in out] == [0, 1, 2, 3, 4, 5]
    assert all(e.lag == 2 and e.frame == k for k, e in out)


def test_a_dead_track_ends_at_its_last_detection():
    # "a" detected at frames 0-2, coasting at 3-4 (no measurement assigned), gone from 5
    script = {k: ([("a", _line(k), 0 if k <= 2 else None)] if k <= 4 else []) for k in range(8)}
    frames = [_xy(k, [_line(k)[0], 50.0] if k <= 2 else [[900.0, 900.0]]) for k in range(8)]
    labels = {k: e.labels for k, e in _run(script, frames, lag=3)}
    assert [labels[k] for k in range(6)] == [("a",), ("a",), ("a",), (), (), ()]
    # lag 1 sees the death only from frame 5: frame 3 was published before it
    labels1 = {k: e.labels for k, e in _run(script, frames, lag=1)}
    assert [labels1[k] for k in range(6)] == [("a",), ("a",), ("a",), ("a",), (), ()]


def test_a_new_track_is_reported_from_its_first_detection():
    # the object is measured at frames 1-5; the tracker reports "b" from frame 3 (its third detection)
    frames = [_xy(0, [[900.0, 900.0]])] + [_xy(k, [[_line(k)[0], 50.0]]) for k in range(1, 6)]
    script = {k: ([("b", _line(k), 0)] if k >= 3 else []) for k in range(6)}
    out = dict(_run(script, frames, lag=2))
    assert out[0].labels == ()          # no measurement near the path at frame 0
    assert out[1].labels == ("b",) and out[2].labels == ("b",)
    assert out[1].assignments == ("b",)
    # back-followed from frame 3 at 10 m/s and updated with the measurement on the path
    np.testing.assert_allclose(out[1].tracks[0].position, [110.0, 50.0], atol=1e-6)
    # with lag 1 only frame 2 is recovered
    out1 = dict(_run(script, frames, lag=1))
    assert out1[1].labels == () and out1[2].labels == ("b",)


def test_a_broken_track_is_continued_under_its_first_label():
    # "a" reported at 0-1, lost at 2, the same object re-reported as "c" from 3
    frames = [_xy(k, [[_line(k)[0], 50.0]] if k != 2 else [[900.0, 900.0]]) for k in range(7)]
    script = {k: ([("a", _line(k), 0)] if k <= 1 else [] if k == 2 else [("c", _line(k), 0)]) for k in range(7)}
    out = dict(_run(script, frames, lag=3))
    assert [out[k].labels for k in range(7)] == [("a",)] * 2 + [()] + [("a",)] * 4
    assert out[4].assignments == ("a",)


def test_smoothing_keeps_a_path_the_model_predicts_and_moves_a_perturbed_state():
    frames = [_xy(k, [[_line(k)[0], 50.0]]) for k in range(5)]
    script = {k: [("a", _line(k), 0)] for k in range(5)}
    out = dict(_run(script, frames, lag=2, smooth=True))
    np.testing.assert_allclose(out[0].tracks[0].state, _line(0), atol=1e-9)   # later states predicted exactly
    script[1] = [("a", np.add(_line(1), [6.0, 0, 0, 0, 0]), 0)]              # frame 1 six metres ahead
    out = dict(_run(script, frames, lag=2, smooth=True))
    assert 0.0 < out[0].tracks[0].state[0] - 100.0 < 6.0                      # pulled towards it, not all the way


def test_a_restored_snapshot_continues_exactly():
    frames = [_xy(k, [[_line(k)[0], 50.0], [300.0 - 5 * k, 80.0]]) for k in range(10)]
    script = {k: [("a", _line(k), 0)] + ([("d", [300.0 - 5 * k, -5.0, 80.0, 0.0, 0.0], 1)] if k >= 4 else [])
              for k in range(10)}
    layer = FixedLag(Scripted(script), PARAMS, 3)
    whole = [(f.frame, e) for f, e, _ in run_lagged(layer, frames, seed=0)]
    state, resumed = layer.initial_state(), []
    for f in frames[:6]:
        state, st = layer.step(state, f, None)
        resumed += [] if st.lagged is None else [(st.frame.frame, st.lagged)]
    state = restore_lag(snapshot_lag(state), Count)
    assert state.inner == Count(6) and len(state.frames) == 3
    for f in frames[6:]:
        state, st = layer.step(state, f, None)
        resumed.append((st.frame.frame, st.lagged))
    resumed += [(f.frame, e) for f, e in layer.flush(state)]
    assert [k for k, _ in resumed] == [k for k, _ in whole]
    for (_, a), (_, b) in zip(whole, resumed):
        assert a.labels == b.labels and a.assignments == b.assignments
        for ta, tb in zip(a.tracks, b.tracks):
            assert np.array_equal(ta.state, tb.state) and np.array_equal(ta.covariance, tb.covariance)


def test_the_window_is_published_when_the_source_fails():
    def frames():
        for k in range(4):
            yield _xy(k, [[0.0, 0.0]])
        raise OSError("log ends in the middle of a chunk")

    layer = FixedLag(Scripted({k: [] for k in range(4)}), PARAMS, 2)
    seen = []
    with pytest.raises(OSError, match="middle of a chunk"):
        for f, _e, _s in run_lagged(layer, frames(), seed=0):
            seen.append(f.frame)
    assert seen == [0, 1, 2, 3]


def test_lag_must_be_positive():
    with pytest.raises(ValueError, match="lag must be >= 1"):
        FixedLag(Scripted({}), PARAMS, 0)


def test_a_swapped_crossing_is_undone_when_crossing_resolution_is_on():
    # objects 1 (east at 10 m/s) and 2 (west at 10 m/s) pass within 3 m of each other at x = 130 at frame 3; the tracker
    # swaps labels there: "p" follows object 1 up to frame 3, then object 2
    def obj(k, which):
        return [100.0 + 10 * k, 10.0, 50.0, 0.0, 0.0] if which == 1 else [160.0 - 10 * k, -10.0, 53.0, 0.0, 0.0]

    frames = [_xy(k, [obj(k, 1)[0:3:2], obj(k, 2)[0:3:2]]) for k in range(8)]
    script = {k: [("p", obj(k, 1 if k <= 3 else 2), 0 if k <= 3 else 1),
                  ("q", obj(k, 2 if k <= 3 else 1), 1 if k <= 3 else 0)] for k in range(8)}

    def labels_of_object_1(margin):
        layer = FixedLag(Scripted(script), PARAMS, 3, smooth=False, swap_margin=margin)
        out = {f.frame: e for f, e, _ in run_lagged(layer, frames, seed=0)}
        return [next(t.label for t in out[k].tracks if np.allclose(t.position, obj(k, 1)[0:3:2])) for k in range(8)]

    assert labels_of_object_1(None) == ["p"] * 4 + ["q"] * 4   # as the tracker decided
    assert labels_of_object_1(4.0) == ["p"] * 8                  # resolved by the scans after it


class Timed(Scripted):
    """:class:`Scripted` whose estimates carry diagnostics: ``ms`` 10 + frame, ``n_tracks``."""

    def step(self, state, frame, rng):
        state, est = super().step(state, frame, rng)
        return state, Estimate(est.frame, est.stamp_ns, est.tracks, est.assignments, est.assignment_prob,
                               {"ms": 10.0 + frame.frame, "n_tracks": float(len(est.tracks))})


def test_a_lagged_frame_costs_its_online_step_plus_the_layer(monkeypatch):
    import bnptrack.tracker.lag as lag_module

    class Clock:  # every reading 2.5 ms after the previous one: the layer's publication reads it twice
        t = 0.0

        def __call__(self):
            self.t += 0.0025
            return self.t

    monkeypatch.setattr(lag_module.time, "perf_counter", Clock())
    script = {k: [("a", _line(k), 0)] for k in range(5)}
    frames = [_xy(k, [_line(k)[0], 50.0]) for k in range(5)]
    layer = FixedLag(Timed(script), PARAMS, 2, smooth=False)
    out = [(f.frame, e) for f, e, _ in run_lagged(layer, frames, seed=0)]
    # frame k: its online step (10 + k ms) plus one publication of 2.5 ms, flushed frames too
    assert [k for k, _ in out] == list(range(5))
    assert [e.diagnostics["ms"] for _, e in out] == pytest.approx([12.5 + k for k in range(5)], abs=1e-9)
    assert all(e.diagnostics["n_tracks"] == 1.0 for _, e in out)  # the other diagnostics as online
