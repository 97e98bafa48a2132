"""``bnptrack track --start/--end`` and ``--set source.KEY``: the frames replay would publish
(sources/frame_window.py), and one-line errors before anything is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from bnptrack.api import simulate, track
from bnptrack.pipeline.cli import main
from bnptrack.sources.mcap_log import read_log

FAST_SET = ["--set", "tracker.sweeps=8", "--set", "tracker.burn_in=2"]


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("window") / "vo.mcap"
    simulate("vo2017", 1, out=out)
    return out


def _frames_tracked(path: Path) -> list[int]:
    return [e.frame for e in read_log(path).tracks]


def test_start_and_end_track_those_frames_as_a_fresh_run(log, tmp_path):
    out = tmp_path / "w.mcap"
    res = invoke("track", log, "--tracker", "ddp-mb", *FAST_SET, "--start", "5f", "--end", "12f", "--out", out, "-q")
    assert res.exit_code == 0, res.output
    got = read_log(out).tracks
    assert [e.frame for e in got] == list(range(5, 13))
    # the same as tracking those frames alone (the tracker starts at frame 5)
    frames = [f for f in read_log(log).frames if 5 <= f.frame <= 12]
    ref = track(frames, "ddp-mb", overrides=["tracker.sweeps=8", "tracker.burn_in=2"], scenario="vo2017").estimates
    assert [e.labels for e in got] == [e.labels for e in ref]
    for a, b in zip(got, ref):
        np.testing.assert_array_equal(a.positions, b.positions)


def test_source_keys_of_set_mean_what_they_mean_in_replay(log, tmp_path):
    out = tmp_path / "s.mcap"
    res = invoke("track", log, "--tracker", "ddp-mb", *FAST_SET, "--set", "source.start_s=3",
                 "--set", "source.frames=4", "--out", out, "-q")
    assert res.exit_code == 0, res.output
    assert _frames_tracked(out) == [4, 5, 6, 7]  # vo2017: frame k at k s; 3 s after frame 1


@pytest.mark.parametrize("args, message", [
    (["--start", "30f", "--end", "20f"], "Invalid value for --end: '20f' is before --start '30f'"),
    (["--start", "later"], "Invalid value for --start: 'later': expected seconds of log time"),
    (["--set", "source.frames=-1"], "Error: --set 'source.frames=-1': expected `int` >= 0"),
    (["--set", "source.rate=2"], "Error: --set 'source.rate=2': an offline run reads its log's frames as fast as it "
                                 "can; its source keys are frames, start_s, end_s, start_frame, end_frame"),
    (["--set", "sink.rerun=false"], "Error: --set 'sink.rerun=false': an offline run chooses its outputs with --out"),
    (["--set", "source.start_s=5", "--set", "source.end_s=2"], "Error: source.end_s = 2 is before source.start_s = 5"),
    (["replay", "--start", "30f", "--end", "20f"], "Invalid value for --end: '20f' is before --start '30f'"),
    (["replay", "--start", "30", "--end", "20s"], "Invalid value for --end: '20s' is before --start '30'"),
])
def test_a_bad_window_is_one_line_exit_2_and_writes_nothing(log, tmp_path, args, message):
    """``track`` (and ``replay``, first in ``args``) refuse the window before writing."""
    command, args = ("replay", args[1:]) if args[0] == "replay" else ("track", args)
    out = tmp_path / "bad.mcap"
    res = invoke(command, log, *args, "--out", out)
    assert res.exit_code == 2
    assert message in res.output
    assert not out.exists()


def test_a_window_with_no_frame_of_the_log_is_an_error_before_writing(log, tmp_path):
    out = tmp_path / "empty.mcap"
    res = invoke("track", log, "--start", "101f", "--out", out)
    assert res.exit_code == 2
    assert f"Error: {log}: no frame in the window --start 101f; `bnptrack info LOG`" in res.output
    assert not out.exists()
    # the last frame alone is a window
    res = invoke("track", log, "--tracker", "ddp-mb", *FAST_SET, "--start", "100f", "--out", out, "-q")
    assert res.exit_code == 0, res.output
    assert _frames_tracked(out) == [100]
