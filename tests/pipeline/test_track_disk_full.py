"""`bnptrack track` on a full disk: one line naming the file (a writer raising ENOSPC at the
adapter, and the Rerun recording child's own report), never the Rust SDK's log text."""

from __future__ import annotations

import errno
from pathlib import Path

from click.testing import CliRunner

from bnptrack.pipeline.cli import main as cli_main
from bnptrack.sinks.rerun_process import RecordingError, child_failure
from bnptrack.sinks.sink import SinkSet

from testkit import REPO_ROOT

LOG = REPO_ROOT / "recordings" / "vo2017-s1.mcap"

#: What the recording child printed on a 300 KB tmpfs (`track --rrd` onto it).
RUST_STDERR = """\
2026-12-04T06:25:26.606067Z ERROR re_log_encoding::rrd::file_sink: Failed to write log stream to /f/o.rrd: Failed to write: No space left on device (os error 28)
2026-12-04T06:25:26.627468Z  WARN re_log_encoding::rrd::encoder: encoder couldn't be finished: Failed to write: No space left on device (os error 28)
2026-12-04T06:25:26.722629Z ERROR re_sdk::recording_stream: Failed to flush previous sink: File-writer thread shut down prematurely
Traceback (most recent call last):
  File "/x/sinks/rerun_sink.py", line 327, in close
    self._rec.flush(timeout_sec=30.0)
RuntimeError: File-writer thread shut down prematurely
"""


def test_the_recording_childs_disk_full_is_an_oserror_naming_the_file():
    exc = child_failure(RUST_STDERR, Path("/f/o.rrd"), "exited with code 1")
    assert isinstance(exc, OSError) and exc.errno == errno.ENOSPC
    assert (exc.filename, exc.strerror) == ("/f/o.rrd", "No space left on device")
    other = child_failure(RUST_STDERR.replace("(os error 28)", ""), Path("/f/o.rrd"), "exited with code 1")
    assert isinstance(other, RecordingError)
    assert str(other) == ("the Rerun recording process writing /f/o.rrd exited with code 1: "
                          "RuntimeError: File-writer thread shut down prematurely")


class _Options:
    def __init__(self, path: Path) -> None:
        self.path = path


class _FullSink:
    """A sink whose writes fail as a full disk does (an OSError without a file name)."""

    def __init__(self, path: Path) -> None:
        self.options = _Options(path)

    def open(self, metadata) -> None:
        pass

    def write(self, record) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    def close(self) -> None:
        pass


def test_a_sink_set_names_the_file_of_a_failing_write(tmp_path):
    sinks = SinkSet([_FullSink(tmp_path / "a.mcap")])
    sinks.open(None)
    try:
        sinks.write(object())
    except OSError as exc:
        assert exc.errno == errno.ENOSPC and exc.filename == str(tmp_path / "a.mcap")
    else:
        raise AssertionError("the write did not fail")


def test_track_on_a_full_disk_names_the_file_in_one_line(tmp_path, monkeypatch):
    from bnptrack.sinks.mcap_writer import McapLogWriter

    calls = []

    def full(self, *args, **kwargs):
        calls.append(1)
        if len(calls) > 3:
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(McapLogWriter, "write_frame", full)
    out = tmp_path / "o.mcap"
    res = CliRunner().invoke(cli_main, ["track", str(LOG), "--out", str(out), "-q", "--tracker", "ddp-mb",
                                        "--set", "sweeps=4", "--set", "burn_in=1"])
    assert res.exit_code == 2, res.output
    assert res.output.strip().splitlines() == [f"Error: {out}: No space left on device"]
