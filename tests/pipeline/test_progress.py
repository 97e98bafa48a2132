"""Progress lines of `bnptrack launch` / `replay` (pipeline.progress) and the running scores
behind them (sinks.run_scorer.ScoreTally)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from bnptrack.pipeline.progress import Progress, Status, progress_line
from bnptrack.sinks.metrics import OspaResult
from bnptrack.sinks.run_scorer import ScoreTally
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, Truth


def _sink(frames: int, t_s: float, *, ospa=None, last=None, tracks=3, latency=2.5) -> dict:
    return {"role": "sink", "t_ns": int(t_s * 1e9), "frames_written": frames, "last_latency_ms": latency,
            "scores": {"tracks": tracks, "ospa": ospa, "last_ospa": last}}


def _source(published: int) -> dict:
    return {"role": "source", "counters": {"published": published}}


def test_progress_line_reference_text():
    st = Status(4.0, source=_source(33), sink=_sink(31, 10.0, ospa=26.84, last=24.12, tracks=9))
    assert progress_line(st, 10.0) == (
        "[   4.0 s] frames 31 (10.0/s), behind 2 frames / 2.5 ms, tracks 9, OSPA 24.1 m (mean 26.8)")
    # no truth: no OSPA; one frame behind: singular
    st = Status(12.25, source=_source(8), sink=_sink(7, 1.0, tracks=0, latency=None))
    assert progress_line(st, None) == "[  12.2 s] frames 7, behind 1 frame, tracks 0"


def test_progress_line_before_the_first_frame():
    assert progress_line(Status(0.0, phase="checking"), None) == (
        "[   0.0 s] checking the configuration (tracker, source, paths) before starting anything")
    st = Status(0.5, stages={"sink": "running", "tracker": "running", "source": "running"})
    assert progress_line(st, None) == "[   0.5 s] starting: waiting for sink, tracker, source (frames 0)"
    st = Status(3.0, sink=_sink(0, 1.0))
    assert progress_line(st, None) == "[   3.0 s] frames 0: the sink is ready, waiting for the first frame"


def test_progress_non_tty_plain_lines_once_a_second_with_rate():
    buf = io.StringIO()
    pr = Progress(buf, tty=False, period=1.0)
    assert pr.update(Status(0.2, source=_source(0), sink=_sink(0, 100.0)))
    assert not pr.update(Status(0.9, source=_source(5), sink=_sink(5, 100.5)))  # not due yet
    assert pr.update(Status(1.2, source=_source(12), sink=_sink(10, 101.0)))  # 10 frames in 1 s
    assert pr.update(Status(2.3, source=_source(30), sink=_sink(30, 102.0)))  # 20 frames in 1 s
    assert pr.update(Status(2.4, source=_source(30), sink=_sink(30, 102.0), phase="final"))  # always
    pr.echo("stage tracker restarted (pid 1)")
    pr.close()
    text = buf.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[1].startswith("[   1.2 s] frames 10 (10.0/s), behind 2 frames")
    assert lines[2].startswith("[   2.3 s] frames 30 (20.0/s), behind 0 frames")
    assert lines[3].startswith("[   2.4 s] frames 30 (20.0/s)")
    assert lines[4] == "stage tracker restarted (pid 1)" and len(lines) == 5


def test_progress_final_line_equal_to_the_last_is_not_repeated():
    """A short run: the sink's last health message came with the last update, in the same
    tenth of a second; the final line would repeat it word for word."""
    buf = io.StringIO()
    pr = Progress(buf, tty=False, period=1.0)
    assert pr.update(Status(1.1, source=_source(30), sink=_sink(30, 50.0)))
    assert not pr.update(Status(1.14, source=_source(30), sink=_sink(30, 50.0), phase="final"))
    assert pr.update(Status(1.3, source=_source(30), sink=_sink(30, 50.0), phase="final"))  # a new time
    lines = buf.getvalue().splitlines()
    assert lines == ["[   1.1 s] frames 30, behind 0 frames / 2.5 ms, tracks 3",
                     "[   1.3 s] frames 30, behind 0 frames / 2.5 ms, tracks 3"]


def test_progress_checking_line_on_a_terminal_only_and_erased_if_nothing_follows():
    buf = io.StringIO()
    assert not Progress(buf, tty=False).update(Status(0.0, phase="checking"))
    assert buf.getvalue() == ""  # off a terminal: a configuration error stays one line
    pr = Progress(buf, tty=True)
    assert pr.update(Status(0.0, phase="checking"))
    pr.close()  # e.g. a configuration error follows: the line is erased, not ended
    assert buf.getvalue().endswith("before starting anything\r\x1b[2K") and "\n" not in buf.getvalue()


def test_progress_tty_rewrites_one_line_and_ends_it():
    buf = io.StringIO()
    pr = Progress(buf, tty=True)
    pr.update(Status(0.1, sink=_sink(1, 1.0)))
    pr.update(Status(1.1, sink=_sink(2, 2.0)))
    pr.echo("note")
    pr.update(Status(2.1, sink=_sink(3, 3.0)))
    pr.close()
    pr.close()  # idempotent
    text = buf.getvalue()
    assert text.count("\r\x1b[2K") == 3
    # the line in place is ended before the message, the message, and the end at close
    assert text.count("\n") == 3 and "tracks 3\nnote\n\r" in text and text.endswith("frames 3 (1.0/s), behind 2.5 ms, tracks 3\n")


def _track(label: str, x: float, y: float) -> TrackEstimate:
    return TrackEstimate(label, np.array([x, 0.0, y, 0.0, 0.0]), np.eye(5), 1.0)


def test_score_tally_means_by_hand():
    tally = ScoreTally()
    truth2 = Truth(("a", "b"), np.array([[0.0, 0, 0, 0, 0], [100.0, 0, 0, 0, 0]]))
    f1 = Frame(1, 1, "s", "bearing_range", np.zeros((0, 2)), truth2)
    e1 = Estimate(1, 1, (_track("1.1", 0.0, 0.0),))
    tally.add(f1, e1, {"ospa": OspaResult(50.0, 0.0, 50.0), "ospa2": 40.0})
    e2 = Estimate(2, 2, (_track("1.1", 0.0, 0.0), _track("2.1", 100.0, 0.0), _track("2.2", 9.0, 9.0)))
    f2 = Frame(2, 2, "s", "bearing_range", np.zeros((0, 2)), truth2)
    tally.add(f2, e2, {"ospa": OspaResult(20.0, 5.0, 15.0), "ospa2": 30.0})
    f3 = Frame(3, 3, "s", "bearing_range", np.zeros((0, 2)))  # no truth: counted, not scored
    tally.add(f3, Estimate(3, 3, (_track("2.2", 9.0, 9.0),)), {"ospa": None, "ospa2": None})
    d = tally.as_dict()
    assert d["frames"] == 3 and d["frames_scored"] == 2
    assert d["ospa"] == pytest.approx(35.0) and d["ospa2"] == pytest.approx(35.0)
    assert d["cardinality_error"] == pytest.approx((1 + 1) / 2)  # |1-2|, |3-2|
    assert d["tracks"] == 1 and d["labels"] == 3 and d["last_ospa"] == 20.0
    assert ScoreTally().as_dict()["ospa"] is None


def test_a_restarted_sink_gives_no_negative_rate():
    """A sink restarted mid-run counts ``frames_written`` from 0 again: the line shows no rate
    until two of its health messages are in (it once printed ``(-535.8/s)``)."""
    pr = Progress(io.StringIO(), tty=False)
    assert pr._rate({"frames_written": 1500, "t_ns": 1_000_000_000}) is None
    assert pr._rate({"frames_written": 1550, "t_ns": 2_000_000_000}) == 50.0
    assert pr._rate({"frames_written": 0, "t_ns": 3_000_000_000}) is None
    assert pr._rate({"frames_written": 40, "t_ns": 4_000_000_000}) == 40.0
