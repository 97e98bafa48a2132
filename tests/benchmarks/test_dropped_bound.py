"""The oracle of benchmarks/dropped_bound.py on hand-checkable cases."""

from __future__ import annotations

import numpy as np
import pytest

import benchmarks.dropped_bound as db
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import Frame, Truth

S = 10**9


def _frame(k: int, ids=("a",), n_truth: int = 1) -> Frame:
    return Frame(k, k * S, "s", "xy", np.zeros((0, 2)), Truth(ids, np.zeros((n_truth, 5))))


@pytest.mark.slow
@pytest.mark.parametrize("gap", [1, 2])
def test_oracle_is_a_kalman_filter_from_its_birth(gap):
    """xy sensor (R = 10^2 I), sigma_a = 5, birth velocity std 20: at birth the state is the
    detection with P = diag(100, 400) per axis; a zero velocity mean keeps the UKF exact (each
    sigma point moves either the velocity or the turn rate), so after one update over ``dt``:
    P_pred = F P F^T + Q(dt), Q(1) = 25 [[1/4, 1/2], [1/2, 1]], Q(2) = 25 [[2.5, 2], [2, 2]]."""
    params = load_params("vo2017", ["sigma_xy=10.0"])
    oracle = db.OracleTracker(params)
    frames = [_frame(1), _frame(1 + gap)]
    dets = [{"a": np.array([100.0, 500.0])}, {"a": np.array([100.0 + 12.0 * gap, 500.0])}]
    out = oracle.run(frames, dets)
    assert out[0][0] == ("a",)
    np.testing.assert_allclose(out[0][1][0], [100.0, 0.0, 500.0, 0.0, 0.0], atol=1e-9)
    p00, p01 = (506.25, 412.5) if gap == 1 else (1762.5, 850.0)  # by hand, above
    want_x = 100.0 + 12.0 * gap * p00 / (p00 + 100.0)
    want_v = 12.0 * gap * p01 / (p00 + 100.0)
    np.testing.assert_allclose(out[1][1][0], [want_x, want_v, 500.0, 0.0, 0.0], rtol=1e-9, atol=1e-9)


def test_oracle_reports_from_first_detection_to_true_death():
    params = load_params("vo2017", ["sigma_xy=10.0"])
    frames = [_frame(1, ("a", "b"), 2), _frame(2, ("a", "b"), 2), _frame(3, ("b",), 1)]
    dets = [{"a": np.array([100.0, 500.0])}, {"b": np.array([0.0, 900.0])}, {}]
    out = db.OracleTracker(params).run(frames, dets)
    assert [ids for ids, _ in out] == [("a",), ("a", "b"), ("b",)]


def test_scores_split_cardinality_from_localisation():
    """Two objects, one reported exactly: OSPA (c = 100, p = 1) = 100 / 2; card-free 0."""
    truth = Truth(("a", "b"), np.array([[0.0, 0, 0, 0, 0], [500.0, 0, 500.0, 0, 0]]))
    frame = Frame(1, S, "s", "xy", np.zeros((0, 2)), truth)
    total, loc = db.frame_scores(frame, ("b",), truth.states[1:])
    assert total == pytest.approx(50.0) and loc == pytest.approx(0.0)
    total, loc = db.frame_scores(frame, ("a", "b"), truth.states + [3.0, 0, 4.0, 0, 0])
    assert total == pytest.approx(5.0) and loc == pytest.approx(5.0)


def test_labelled_detections_are_the_frames_object_rows():
    """vo2017, seed 3: the replayed draws are rows of the simulated frames (624 detections of
    the 645 target-scans, P_D = 0.98)."""
    sc = get_scenario("vo2017")
    params = sc.adapt_params(load_params("vo2017"))
    n = 0
    for f in simulate_all(sc, params, 3):
        for i, z in db.labelled_detections(params, f, 3).items():
            assert i in f.truth.ids and np.any(np.all(f.z == z, axis=1))
            n += 1
    assert n == 624
