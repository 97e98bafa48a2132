"""Range-only scores (sinks/range_scores.py): hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sinks.range_scores import range_ospa, ranges, within_gate


def test_ranges_from_the_sensor():
    np.testing.assert_allclose(ranges(np.array([[3.0, 4.0], [0.0, 10.0]])), [[5.0], [10.0]])
    np.testing.assert_allclose(ranges(np.array([[3.0, 4.0]]), sensor=(3.0, 0.0)), [[4.0]])


def test_range_ospa_ignores_the_rotation_about_the_sensor():
    truth = np.array([[0.0, 1000.0], [600.0, 800.0]])
    rotated = np.array([[1000.0, 0.0], [-800.0, -600.0]])  # same ranges, far away in the plane
    assert range_ospa(truth, rotated) == (0.0, 1.0)
    # ranges 1000, 1000 vs 1030: one pair 30 m, one missed (c = 100): (30 + 100) / 2
    assert range_ospa(truth, np.array([[0.0, 1030.0]]))[0] == pytest.approx(65.0)


def test_within_gate_is_one_to_one():
    truth = np.array([[0.0, 1000.0], [0.0, 1050.0], [500.0, 500.0]])
    est = np.array([[0.0, 1020.0]])  # within 100 m of two objects: counts once
    assert within_gate(truth, est) == (1.0, 3.0)
    assert within_gate(truth, np.array([[0.0, 1000.0], [0.0, 1049.0], [0.0, 0.0]])) == (2.0, 3.0)
    assert within_gate(truth, np.zeros((0, 2))) == (0.0, 3.0)
    assert within_gate(np.zeros((0, 2)), est) == (0.0, 0.0)
