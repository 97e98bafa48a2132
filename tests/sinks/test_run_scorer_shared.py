"""RunScorer's shared per-frame distances (Monte Carlo throughput): OSPA, GOSPA and
the OSPA(2) window from one cut-off distance matrix per frame must give what the public
functions give, bit for bit, and the hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sinks.metrics import gospa, ospa, ospa2_series

from bnptrack.sinks.run_scorer import RunScorer
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, Truth

C = 100.0


def _state(x: float, y: float) -> np.ndarray:
    return np.array([x, 0.0, y, 0.0, 0.0])


def _frame(k: int, truth: dict | None) -> Frame:
    t = None if truth is None else Truth(tuple(truth), np.array([_state(*p) for p in truth.values()]).reshape(-1, 5))
    return Frame(k, k * 1_000_000_000, "s", "xy", np.zeros((0, 2)), truth=t)


def _estimate(k: int, tracks: dict) -> Estimate:
    return Estimate(k, k * 1_000_000_000,
                    tuple(TrackEstimate(lab, _state(*p), np.eye(5), 1.0) for lab, p in tracks.items()))


def _random_run(rng: np.random.Generator, K: int) -> tuple[list[dict], list[dict | None]]:
    """Labels that appear, vanish and come back, positions near each other (some beyond c),
    empty scans on both sides and a few frames without truth."""
    est, true = [], []
    for _ in range(K):
        e_labels = [f"e{i}" for i in range(12) if rng.random() < 0.5]
        t_labels = [f"t{i}" for i in range(10) if rng.random() < 0.6]
        rng.shuffle(e_labels)  # a tracker may report its labels in any order
        est.append({lab: tuple(rng.normal(0.0, 80.0, 2)) for lab in e_labels})
        true.append(None if rng.random() < 0.1 else {lab: tuple(rng.normal(0.0, 80.0, 2)) for lab in t_labels})
    return est, true


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("window", [1, 3, 10])
def test_scorer_equals_the_public_functions_bit_for_bit(seed, window):
    rng = np.random.default_rng(seed)
    est, true = _random_run(rng, 40)
    scorer = RunScorer(c=C, p=1.0, window=window, gospa_alpha=2.0)
    series = ospa2_series([{k: np.array(v) for k, v in e.items()} for e in est],
                          [{k: np.array(v) for k, v in (t or {}).items()} for t in true], window=window, c=C)
    scored = 0
    for k, (e, t) in enumerate(zip(est, true)):
        got = scorer.update(_frame(k, t), _estimate(k, e))
        if t is None:
            assert got == {"ospa": None, "ospa2": None, "gospa": None}
            continue
        X = np.array(list(t.values())).reshape(-1, 2)
        Y = np.array(list(e.values())).reshape(-1, 2)
        assert got["ospa"] == ospa(X, Y, c=C, p=1.0)
        assert got["gospa"] == gospa(X, Y, c=C, p=1.0, alpha=2.0)
        assert got["ospa2"] == series[k]
        scored += 1
    assert scored > 30


def test_scorer_order_two_matches_the_series():
    """q = 2 and p = 2 (the squares are computed per scan here, per window there)."""
    est, true = _random_run(np.random.default_rng(7), 25)
    true = [t or {} for t in true]
    scorer = RunScorer(c=C, p=2.0, window=5, q=2.0)
    got = [scorer.update(_frame(k, t), _estimate(k, e))["ospa2"] for k, (e, t) in enumerate(zip(est, true))]
    series = ospa2_series([{k: np.array(v) for k, v in e.items()} for e in est],
                          [{k: np.array(v) for k, v in t.items()} for t in true], window=5, c=C, p=2.0, q=2.0)
    np.testing.assert_allclose(got, series, rtol=1e-13, atol=0.0)


def test_hand_computed_window():
    """Window 2. Scan 0: estimate a at (0, 0), truth x at (3, 4). Scan 1: a and x at (0, 0),
    estimate b at (1000, 0).  d(a, x) = (5 + 0) / 2 = 2.5; d(b, x) = (c + c) / 2 = 100 (x alone
    at scan 0, b beyond the cut-off at scan 1); OSPA(2) = (2.5 + c * (2 - 1)) / 2 = 51.25.
    GOSPA at scan 1: a-x paired at 0, b false: c / 2 = 50.  OSPA at scan 0: 5."""
    scorer = RunScorer(c=C, p=1.0, window=2, gospa_alpha=2.0)
    s0 = scorer.update(_frame(0, {"x": (3.0, 4.0)}), _estimate(0, {"a": (0.0, 0.0)}))
    assert s0["ospa"].total == 5.0 and s0["ospa2"] == 5.0 and s0["gospa"].total == 5.0
    s1 = scorer.update(_frame(1, {"x": (0.0, 0.0)}), _estimate(1, {"a": (0.0, 0.0), "b": (1000.0, 0.0)}))
    assert s1["ospa2"] == 51.25
    assert (s1["gospa"].total, s1["gospa"].n_false, s1["gospa"].n_missed) == (50.0, 1, 0)
    assert (s1["ospa"].localisation, s1["ospa"].cardinality) == (0.0, 50.0)


def test_more_true_points_than_estimates_share_one_assignment():
    """A tall matrix (3 true, 1 estimate): OSPA solves the transpose, GOSPA the matrix; the
    shared assignment gives both hand values: pair (1, 0)-(0, 0) at 1, two missed."""
    scorer = RunScorer(c=C, p=1.0, window=3, gospa_alpha=2.0)
    got = scorer.update(_frame(0, {"x": (1.0, 0.0), "y": (500.0, 0.0), "z": (0.0, 300.0)}),
                        _estimate(0, {"a": (0.0, 0.0)}))
    assert got["gospa"].total == 1.0 + 2 * C / 2 and got["gospa"].n_missed == 2
    assert got["ospa"].total == (1.0 + 2 * C) / 3


def test_empty_sides():
    scorer = RunScorer(c=C, p=1.0, window=4, gospa_alpha=2.0)
    none = scorer.update(_frame(0, {}), _estimate(0, {}))
    assert none["ospa"].total == 0.0 and none["ospa2"] == 0.0 and none["gospa"].total == 0.0
    only_est = scorer.update(_frame(1, {}), _estimate(1, {"a": (0.0, 0.0), "b": (9.0, 9.0)}))
    assert only_est["ospa"].total == C and only_est["ospa2"] == C and only_est["gospa"].total == C
