"""The exit code and the files follow the output, over real stage processes and Zenoh on
loopback: a tracker killed after its last frame with no restart left still ends a complete run
with exit 0; a launcher killed with SIGKILL leaves a ``sink.json`` that names what is missing
and a ``stages.json`` that shows no exited stage as running.  In memory:
tests/pipeline/test_exit_follows_output.py."""

from __future__ import annotations

import json
import os
import signal
import subprocess
from pathlib import Path

import pytest

from bnptrack.pipeline.stages import SUMMARY_NAME

from testkit import finish, log_tracks, offline_log_tracks, popen_bnptrack, wait_until

pytestmark = pytest.mark.integration


def _wait_for(what: str, cond, p: subprocess.Popen, timeout: float = 120) -> None:
    wait_until(cond, timeout, what, interval=0.01, abort=lambda: p.poll() is not None)


def _stages(out: Path) -> dict:
    return json.loads((out / "stages.json").read_text())


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (not gone, not a zombie)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


def test_a_tracker_killed_after_its_last_frame_with_no_restart_left_ends_a_complete_run_with_exit_0(tmp_path):
    """The sink is held (SIGSTOP) while the tracker finishes; the tracker is killed after its
    end of stream with ``max_restarts = 0`` (given up at once); the sink, let go, records
    the whole run: exit 0, 30 frames identical to offline `track`."""
    out = tmp_path / "run"
    p = popen_bnptrack("launch", "--set", "source.frames=30", "--set", "source.rate=10", "--set", "sink.rerun=false",
                       "--set", "tracker.snapshot_every=5", "--set", "supervisor.max_restarts=0",
                       "--run", "given-up", "--out", str(out), "--timeout", "150")
    sink_pid = None
    try:
        _wait_for("the tracker's first snapshot", (out / "tracker.snap").exists, p)
        pids = {role: s["pid"] for role, s in _stages(out).items()}
        sink_pid = pids["sink"]
        os.kill(sink_pid, signal.SIGSTOP)
        log = out / "logs" / "tracker.log"
        _wait_for("the tracker's end of stream", lambda: "processed 30 frame(s)" in log.read_text(), p)
        os.kill(pids["tracker"], signal.SIGKILL)
        _wait_for("the launcher to give the tracker up", lambda: _stages(out)["tracker"]["state"] == "failed", p)
    finally:
        if sink_pid is not None:
            try:
                os.kill(sink_pid, signal.SIGCONT)
            except ProcessLookupError:  # the launcher stopped it (and the run) already
                pass
        code, text = finish(p, 200)
    assert "giving up" in text and "the output is complete all the same" in text, text
    assert code == 0, text
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["output_complete"] is True and s["frames_written"] == 30 and s["missing"] == []
    assert log_tracks(out / "tracks.mcap") == offline_log_tracks(out / "tracks.mcap", tmp_path / "off.mcap")


def test_after_the_launcher_is_killed_sink_json_names_what_is_missing_and_no_stage_shows_running(tmp_path):
    """SIGKILL of the launcher in the middle of a 200-frame run at 20 frames/s: the stages see
    it gone and stop; ``sink.json`` is incomplete and names the rest of the run, from the
    first frame not written, as missing; ``stages.json`` shows each stage as stopped."""
    out = tmp_path / "run"
    p = popen_bnptrack("launch", "--set", "source.frames=200", "--set", "source.rate=20", "--set", "sink.rerun=false",
                       "--set", "tracker.snapshot_every=5", "--run", "orphans", "--out", str(out), "--timeout", "150")
    try:
        _wait_for("the tracker's first snapshot", (out / "tracker.snap").exists, p)
        pids = {role: s["pid"] for role, s in _stages(out).items()}
        os.kill(p.pid, signal.SIGKILL)
    finally:
        finish(p, 60)
    wait_until(lambda: not any(_running(pid) for pid in pids.values()), 60, "every stage to stop")
    wait_until(lambda: (out / SUMMARY_NAME).exists(), 10, "sink.json")
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] is False and s["output_complete"] is False and 0 < s["frames_written"] < 200
    why = f"not received: the sink was stopped (its launcher, pid {p.pid}, is gone)"
    first = s["last_seq"] + 1
    assert s["missing"] and all(m["why"] == why and m["from_seq"] == first for m in s["missing"]), s["missing"]
    assert {m["topic"] for m in s["missing"]} == {"/measurements", "/truth", "/tracks"}
    stages = _stages(out)
    assert {role: st["pid"] for role, st in stages.items()} == pids
    assert all(st["state"] != "running" and st["exited"] for st in stages.values()), stages
