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

#: statistical oracles over many simulated runs: the slow tier (docs/testing.md)
pytestmark = pytest.mark.slow


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


def _p(x: float, y: float = 0.0) -> np.ndarray:
    return np.array([x, y])


def _hand_scans() -> list[rb.Scan]:
    """Objects a (dies after scan 2) and b, 1 km apart.  The tracker: track t1 on a from a's 2nd
    detection (scan 1), lost at scan 2 (a gap), still reported at scan 3 after a's death; t2 on
    b from b's 3rd detection; a false track f at scan 2 and 3."""
    a, b = _p(0), _p(1000)
    return [
        rb.Scan(truth={"a": a, "b": b}, oracle={"a": _p(0, 10)}, looks={"a": 1}, tracks={}),
        rb.Scan(truth={"a": a, "b": b}, oracle={"a": _p(0, 10), "b": _p(1000, 10)}, looks={"a": 2, "b": 1},
                tracks={"t1": _p(0, 20)}),
        rb.Scan(truth={"a": a, "b": b}, oracle={"a": _p(0, 10), "b": _p(1000, 10)}, looks={"a": 3, "b": 2},
                tracks={"f": _p(5000)}),
        rb.Scan(truth={"b": b}, oracle={"b": _p(1000, 10)}, looks={"a": 3, "b": 3},
                tracks={"t1": _p(0, 20), "t2": _p(1000, 30), "f": _p(5000)}),
    ]


def test_decomposition_steps_by_hand():
    """Per-scan OSPA (c = 100, p = 1) of every step, worked out by hand: the oracle from the 3rd
    detection [100, 100, (10+100)/2, 10]; a reported from scan 1 (its first match); a lost at
    scan 2; the tracker's positions (20 m, 30 m off; both tracks young, so all in ``young``); a's
    dead track; the false track."""
    scans = _hand_scans()
    steps = rb.hybrids(scans, confirm=3)
    expected = {"oracle": [100, 100, 55, 10], "delay": [100, 55, 55, 10], "gaps": [100, 55, 100, 10],
                "young": [100, 60, 100, 30], "positions": [100, 60, 100, 30], "labels": [100, 60, 100, 30], "dead": [100, 60, 100, 65],
                "false": [100, 60, 100, (30 + 100 + 100) / 3]}
    scores = rb.score_steps(scans, steps)
    for k, per_scan in expected.items():
        assert scores[k]["ospa"] == pytest.approx(np.mean(per_scan)), k
    assert set(steps["labels"][3]) == {"t2"} and set(steps["dead"][3]) == {"t1", "t2"}
    assert set(steps["positions"][3]) == {"b"}  # true ids until the labels step
    assert rb.first_report_looks(scans) == {"a": 2, "b": 3}
    assert scores["false"]["card_err"] == pytest.approx(np.mean([2, 1, 1, 2]))


def test_young_positions_are_the_first_scans_after_the_first_match():
    """One object matched from scan 0 on, the tracker 20 m off: its first YOUNG + 1 scans'
    positions come in at ``young``, the rest at ``positions``."""
    n = rb.YOUNG + 3
    scans = [rb.Scan(truth={"a": _p(0)}, oracle={"a": _p(0)}, looks={"a": k + 1}, tracks={"t": _p(0, 20)})
             for k in range(n)]
    scores = rb.score_steps(scans, rb.hybrids(scans, confirm=1))
    assert scores["gaps"]["ospa"] == pytest.approx(0.0)
    assert scores["young"]["ospa"] == pytest.approx(20.0 * (rb.YOUNG + 1) / n)
    assert scores["positions"]["ospa"] == pytest.approx(20.0)


@pytest.mark.parametrize("coast", [0, 1])
def test_coasting_oracle_reports_objects_seen_in_the_last_coast_scans(coast):
    """random, seed 3: the coasting oracle reports exactly the objects (alive or dead) with at
    least 2 detections that were detected in one of the last ``coast + 1`` scans, counted here
    from the replayed draws."""
    sc = get_scenario("random", 3)
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, 3)
    dets = [labelled_detections(params, f, 3) for f in frames]
    est = rb.CoastingOracle(params, confirm=2, coast=coast).run(frames, dets)
    looks: dict[str, int] = {}
    dead_reported = 0
    for k, (f, (ids, states)) in enumerate(zip(frames, est)):
        for i in dets[k]:
            looks[i] = looks.get(i, 0) + 1
        recent = set().union(*(dets[j] for j in range(max(0, k - coast), k + 1)))
        assert set(ids) == {i for i in recent if looks[i] >= 2}
        assert states.shape == (len(ids), 5) and np.isfinite(states).all()
        dead_reported += len(set(ids) - set(f.truth.ids))
    assert (dead_reported > 0) == (coast > 0)


def test_decomposition_ends_at_the_trackers_own_scores():
    """random, seed 101, ddp-mb: the last step is the tracker's output, scored as accuracy.py does."""
    from benchmarks.accuracy import setup
    from bnptrack.sinks.metrics import ospa
    from bnptrack.tracker.state import run
    out = rb.decompose_run(("ddp-mb", "random", 101, [], [], 3))
    sc, tracker, frames = setup("ddp-mb", "vo2017", "random", 101, [])
    direct = np.mean([ospa(f.truth.positions, e.positions, c=100.0, p=1.0).total for f, e, _ in run(tracker, frames, 101)])
    assert out["scores"]["false"]["ospa"] == pytest.approx(direct, abs=1e-9)
    assert out["scores"]["oracle"]["ospa"] == pytest.approx(rb.one_run((101, "random", [], [3]))[3]["ospa"], abs=1e-9)
    assert out["dead_scans"] > 0 and out["objects"] == len(sc.ids)
