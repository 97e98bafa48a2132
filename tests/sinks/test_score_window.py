"""RunScorer(compiled=True) (Monte Carlo throughput): the OSPA(2) window built by one
compiled kernel (sinks/_score_window.py) gives what the numpy path gives, bit for bit, on
runs whose labels appear, vanish and come back, and the hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sinks._score_window import _first_seen
from bnptrack.sinks.run_scorer import RunScorer
from tests.sinks.test_run_scorer_shared import C, _estimate, _frame, _random_run


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
@pytest.mark.parametrize("window", [1, 3, 10])
@pytest.mark.parametrize(("p", "q"), [(1.0, 1.0), (2.0, 2.0)])
def test_compiled_window_equals_numpy_bit_for_bit(seed, window, p, q):
    est, true = _random_run(np.random.default_rng(seed), 40)
    plain = RunScorer(c=C, p=p, window=window, q=q, gospa_alpha=2.0)
    compiled = RunScorer(c=C, p=p, window=window, q=q, gospa_alpha=2.0, compiled=True)
    scored = 0
    for k, (e, t) in enumerate(zip(est, true)):
        a = plain.update(_frame(k, t), _estimate(k, e))
        b = compiled.update(_frame(k, t), _estimate(k, e))
        assert a == b  # dataclasses and floats compared exactly
        scored += a["ospa2"] is not None
    assert scored > 30


def test_compiled_hand_computed_window():
    """As test_run_scorer_shared.test_hand_computed_window: d(a, x) = 2.5, d(b, x) = 100,
    OSPA(2) = (2.5 + 100) / 2 = 51.25; then x's label returns after a scan without it."""
    scorer = RunScorer(c=C, p=1.0, window=2, gospa_alpha=2.0, compiled=True)
    assert scorer.update(_frame(0, {"x": (3.0, 4.0)}), _estimate(0, {"a": (0.0, 0.0)}))["ospa2"] == 5.0
    s1 = scorer.update(_frame(1, {"x": (0.0, 0.0)}), _estimate(1, {"a": (0.0, 0.0), "b": (1000.0, 0.0)}))
    assert s1["ospa2"] == 51.25
    # scan 2: no estimate; window (1, 2): a, b absent at 2 -> d(a, x) = (0 + 100) / 2 = 50,
    # d(b, x) = (100 + 100) / 2 = 100; OSPA(2) = (50 + 100 * 1) / 2 = 75
    assert scorer.update(_frame(2, {"x": (0.0, 0.0)}), _estimate(2, {}))["ospa2"] == 75.0
    # window (2, 3): no estimated track, x alone (an empty 0 x 1 matrix): OSPA(2) = c
    assert scorer.update(_frame(3, {}), _estimate(3, {}))["ospa2"] == C
    # window (3, 4): no track on either side: 0
    assert scorer.update(_frame(4, {}), _estimate(4, {}))["ospa2"] == 0.0


def test_first_seen_numbers_ids_in_order_of_appearance():
    out, k = _first_seen(np.array([5, 2, 5, 0, 2, 7], dtype=np.int64), 8)
    assert out.tolist() == [0, 1, 0, 2, 1, 3] and k == 4
