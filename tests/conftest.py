"""Shared fixtures (the vo2017 parameter set, one simulated vo2017 run, exact Estimate
equality) and the ``integration`` marker of tests/integration/.

Shared helpers that are not fixtures (``wait_until``, the ``ListSource``/``ListSink`` stage
fakes, the in-memory pipeline runner) are in tests/testkit.py; this conftest puts tests/ on
``sys.path`` (pytest's default ``prepend`` import mode), so test files ``import testkit``."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.models.params import load_params


INTEGRATION_DIR = Path(__file__).resolve().parent / "integration"

# Whether this run is CI's (testkit.require_renderer), noted before a test module sets CI.
os.environ.setdefault("BNPTRACK_TESTS_UNDER_CI", "1" if os.environ.get("CI") else "0")


def pytest_collection_modifyitems(config, items):
    """Every test under tests/integration/ is marked ``integration`` (real Zenoh sessions,
    stage processes, a live viewer)."""
    for item in items:
        if INTEGRATION_DIR in Path(str(item.path)).resolve().parents:
            item.add_marker(pytest.mark.integration)


@pytest.fixture(scope="session")
def vo_params():
    """The vo2017 parameter set with the vo2017 scenario's birth regions (Vo's four)."""
    return get_scenario("vo2017").adapt_params(load_params("vo2017"))


@pytest.fixture(scope="session")
def vo_frames(vo_params):
    return simulate_all(get_scenario("vo2017"), vo_params, 1)


@pytest.fixture(scope="session")
def estimates_equal():
    """Exact equality of two Estimates: labels, states, covariances, existence, assignments."""

    def equal(a, b) -> bool:
        return (a.labels == b.labels and np.array_equal(a.positions, b.positions)
                and a.assignments == b.assignments and a.assignment_prob == b.assignment_prob
                and [t.existence for t in a.tracks] == [t.existence for t in b.tracks]
                and all(np.array_equal(x.covariance, y.covariance) for x, y in zip(a.tracks, b.tracks)))

    return equal
