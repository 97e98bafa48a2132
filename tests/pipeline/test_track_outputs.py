"""What `track` does with its files: an existing output is never replaced without
``--overwrite`` (refused with exit 2 before the log is read, and left as it was), and a log cut
short before its channels is reported as truncated."""

from __future__ import annotations

import shutil
from pathlib import Path

from click.testing import CliRunner

from bnptrack.pipeline.cli import main

LOG = Path(__file__).resolve().parents[2] / "recordings" / "vo2017-s1.mcap"


def track(*args: str):
    return CliRunner().invoke(main, ["track", *args, "--tracker", "ddp-mb", "--end", "5f", "-q"])


def test_an_existing_out_is_refused_and_kept(tmp_path):
    log = tmp_path / "log.mcap"
    shutil.copy(LOG, log)
    out = tmp_path / "tracks.mcap"
    assert track(str(log), "--out", str(out)).exit_code == 0
    finished = out.read_bytes()
    res = track(str(log), "--out", str(out))
    assert res.exit_code == 2
    assert f"{out} exists: give --overwrite to replace it, or another --out" in res.output
    assert out.read_bytes() == finished


def test_an_existing_recording_is_refused_too(tmp_path):
    out, rrd = tmp_path / "t.mcap", tmp_path / "t.rrd"
    rrd.write_bytes(b"an earlier recording")
    res = track(str(LOG), "--out", str(out), "--rrd", str(rrd))
    assert res.exit_code == 2 and f"{rrd} exists" in res.output
    assert not out.exists() and rrd.read_bytes() == b"an earlier recording"


def test_overwrite_replaces_the_file(tmp_path):
    out = tmp_path / "tracks.mcap"
    out.write_bytes(b"old")
    res = track(str(LOG), "--out", str(out), "--overwrite")
    assert res.exit_code == 0, res.output
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n"


def test_a_log_cut_before_its_channels_is_reported_as_truncated(tmp_path):
    data = LOG.read_bytes()
    for size in (1, 8, 100, 1000):
        cut = tmp_path / f"cut{size}.mcap"
        cut.write_bytes(data[:size])
        res = track(str(cut), "--out", str(tmp_path / f"out{size}.mcap"))
        assert res.exit_code == 2
        assert f"the file ends after {size} bytes, before any channel is declared" in res.output
        assert "no /measurements channel" not in res.output


def test_an_unknown_scenario_in_the_record_is_a_warning(tmp_path):
    import bnptrack

    frames = bnptrack.read_log(LOG).frames[:5]
    log = bnptrack.write_log(tmp_path / "harbour.mcap", frames, {"scenario": "harbour", "params": "vo2017"})
    res = track(str(log), "--out", str(tmp_path / "out.mcap"))
    assert res.exit_code == 0, res.output
    assert "warning: the log's record names an unknown scenario 'harbour', so no scenario defaults" in res.output
    known = bnptrack.write_log(tmp_path / "vo.mcap", frames, {"scenario": "vo2017", "params": "vo2017"})
    assert "warning" not in track(str(known), "--out", str(tmp_path / "out2.mcap")).output
