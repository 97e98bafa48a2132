"""benchmarks/random_bound.py's oracle scores and benchmarks/accuracy.py's crossing-failure
classes, against independent counts and hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

import benchmarks.random_bound as rb
from benchmarks.accuracy import crossing_failure
from benchmarks.dropped_bound import labelled_detections
from bnptrack.sinks.crossings import CrossingPairResult
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.models.params import load_params


def _unconfirmed_per_frame(seed: int, confirm: int) -> float:
    """Mean over frames of the live objects with fewer than ``confirm`` detections so far:
    the oracle's only cardinality error (it never reports a false or a dead object)."""
    sc = get_scenario("random", seed)
    params = sc.adapt_params(load_params("vo2017"))
    looks: dict[str, int] = {}
    missing = []
    for f in simulate_all(sc, params, seed):
        for i in labelled_detections(params, f, seed):
            looks[i] = looks.get(i, 0) + 1
        missing.append(sum(looks.get(i, 0) < confirm for i in f.truth.ids))
    return float(np.mean(missing))


def test_oracle_cardinality_error_is_the_objects_not_yet_confirmed():
    """random, seed 2: |N_hat - N| of the oracle equals the objects with fewer than N
    detections, counted here from the replayed draws; later confirmation costs OSPA."""
    out = rb.one_run((2, "random", [], [1, 2, 3]))
    for n in (1, 2, 3):
        assert out[n]["card_err"] == pytest.approx(_unconfirmed_per_frame(2, n), abs=1e-12)
    assert out[1]["card_err"] < out[2]["card_err"] < out[3]["card_err"]
    assert out[1]["ospa"] < out[2]["ospa"] < out[3]["ospa"]
    assert out[1]["ospa"] == pytest.approx(out[1]["loc"] + out[1]["card"], abs=1e-9)


def _pair(before, after) -> CrossingPairResult:
    return CrossingPairResult("a", "b", 10, 5, 15, before, after, False)


@pytest.mark.parametrize("before, after, why", [
    ((None, "2"), ("1", "2"), "unseen before"),
    (("1", "2"), ("2", "1"), "swap"),
    (("1", "2"), ("1", None), "lost after"),
    (("1", "2"), ("1", "1"), "merged"),
    (("1", "2"), ("1", "7"), "relabel"),
])
def test_crossing_failure_classes(before, after, why):
    assert crossing_failure(_pair(before, after)) == why
