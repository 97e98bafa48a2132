"""`bnptrack info` prints time stamps as dates (or seconds from t = 0) and spans as durations."""

from __future__ import annotations

from click.testing import CliRunner

from bnptrack import write_log
from bnptrack.pipeline.cli import main
from bnptrack.pipeline.cli.tools import duration_text, stamp_text
from bnptrack.tracker.types import Frame


def test_stamps_and_durations():
    assert stamp_text(1_709_294_405_250_000_000) == "2024-03-01 12:00:05.250 UTC"
    assert stamp_text(5_250_000_000) == "5.250 s"
    assert [duration_text(s) for s in (0.25, 1.5, 59.0, 125.0, 3 * 3600 + 125.0)] == [
        "250 ms", "1.5 s", "59 s", "2 min 05 s", "3 h 02 min 05 s"]


def test_info_of_a_dated_log(tmp_path):
    t0 = 1_709_294_400 * 10**9  # 2024-03-01 12:00:00 UTC
    frames = [Frame(k, t0 + k * 100_000_000, "radar0", "bearing_range", [[0.1, 800.0]]) for k in range(1, 1202)]
    log = write_log(tmp_path / "dated.mcap", frames)
    res = CliRunner().invoke(main, ["info", str(log)])
    assert res.exit_code == 0, res.output
    assert ("time              2024-03-01 12:00:00.100 UTC to 2024-03-01 12:02:00.100 UTC (span 2 min 00 s), "
            "10 frames/s, dt median 100 ms, min 100 ms, max 100 ms") in res.output
