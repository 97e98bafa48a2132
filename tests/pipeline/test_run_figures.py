"""The figures every run's summary prints (pipeline/cli/run_figures.py): ``track`` and
``launch`` / ``replay`` give the same lines from their own records of a run."""

from __future__ import annotations

import numpy as np

from bnptrack.pipeline.cli.run_figures import RunFigures, figure_rows
from bnptrack.pipeline.offline import FrameMetrics, TrackResult
from bnptrack.pipeline.stages.summary import RunSummary

#: A run of 4 frames, 3 with truth: OSPA 10, 20, 30 (mean 20), OSPA(2) 12, 18, 30 (mean 20),
#: cardinality errors 0, 1, 2 (mean 1); tracker ms 1, 2, 3, 4 (median 2.5, p95 3.85).
FRAMES = (
    FrameMetrics(0, 5, 1, 1.0, n_true=1, ospa=10.0, cardinality_error=0, ospa2=12.0),
    FrameMetrics(1, 5, 2, 2.0, n_true=1, ospa=20.0, cardinality_error=1, ospa2=18.0),
    FrameMetrics(2, 5, 2, 3.0),
    FrameMetrics(3, 5, 2, 4.0, n_true=4, ospa=30.0, cardinality_error=2, ospa2=30.0),
)
EXPECTED = [
    ("mean OSPA", "20.00 m (c=100, p=1, position; 3 frames)"),
    ("mean OSPA(2)", "20.00 m (window 10 frames)"),
    ("mean card. error", "1.00"),
    ("final tracks", "2: T1.0 T3.z2 (3 labels in all)"),
    ("ms per frame", "median 2.50, p95 3.85"),
]


def _summary() -> RunSummary:
    """The same run as the sink's sink.json records it."""
    return RunSummary.of({"scores": {"frames": 4, "frames_scored": 3, "ospa": 20.0, "ospa2": 20.0,
                                     "cardinality_error": 1.0, "tracks": 2, "names": ["T1.0", "T3.z2"], "labels": 3,
                                     "last_ospa": 30.0, "c": 100.0, "p": 1.0, "ospa2_window": 10},
                          "latency": {"tracker_ms": [1.0, 2.0, 3.0, 4.0]}})


def test_track_and_the_pipeline_print_the_same_figures():
    res = TrackResult("ddp", FRAMES, 2, final_names=("T1.0", "T3.z2"), labels=3)
    assert figure_rows(RunFigures.of_track(res)) == EXPECTED
    assert figure_rows(RunFigures.of_summary(_summary())) == EXPECTED


def test_a_lagged_run_says_its_time_is_the_whole_step():
    rows = dict(figure_rows(RunFigures.of_summary(_summary(), lag=3)))
    assert rows["ms per frame"] == "median 2.50, p95 3.85 (the whole step: online step + lag layer)"


def test_every_lagged_run_says_its_lag_and_a_lag_longer_than_the_run_says_so():
    res = TrackResult("ddp", FRAMES, 2, final_names=("T1.0", "T3.z2"), labels=3)
    for rows in (figure_rows(RunFigures.of_track(res, 3)), figure_rows(RunFigures.of_summary(_summary(), 3))):
        assert rows[0] == ("lag", "3 scan(s): each frame re-decided with the 3 after it, smoothed")
    assert figure_rows(RunFigures.of_summary(_summary(), 4))[0] == (
        "lag", "4 scan(s), longer than the run's 4 frame(s): each frame re-decided with every frame after it, smoothed")


def test_a_run_without_truth_or_timing_prints_what_it_has():
    res = TrackResult("ddp", (FrameMetrics(0, 3, 0, float("nan")),), 0, final_names=(), labels=0)
    assert figure_rows(RunFigures.of_track(res)) == [
        ("mean OSPA", "n/a (no /truth with the frames)"), ("final tracks", "0 (0 labels in all)")]
