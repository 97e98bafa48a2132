"""A stage's key cannot be taken from another process's view, and a forged end of stream does
not pass for the source's: real launches, stage processes over Zenoh on loopback.  The
in-memory checks are in tests/pipeline/test_eos_check.py."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import pytest

from bnptrack.pipeline.stages import SUMMARY_NAME

from testkit import finish, popen_bnptrack, wait_until

pytestmark = pytest.mark.integration

_ASSIGNED = re.compile(rb"(?:PASSWORD|password)[\"']?\s*[=:]\s*[\"']?([A-Za-z0-9_\-]{8,})")


def _wait_for(what: str, cond, p: subprocess.Popen, timeout: float = 120) -> None:
    wait_until(cond, timeout, what, interval=0.01, abort=lambda: p.poll() is not None)


def _read(path: Path) -> bytes:
    """What a process of the same user reads at ``path`` (nothing when refused or not a file;
    never blocks on a FIFO)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return b""
    try:
        return os.read(fd, 1 << 20)
    except OSError:
        return b""
    finally:
        os.close(fd)


def harvest(pids: list[int], out: Path) -> set[str]:
    """Every password another process of this user finds: the stages' environment and
    command line, whatever their open descriptors let it open, and the run's files."""
    blobs: list[bytes] = []
    for pid in pids:
        proc = Path(f"/proc/{pid}")
        blobs += [_read(proc / "environ").replace(b"\0", b"\n"), _read(proc / "cmdline").replace(b"\0", b" ")]
        try:
            fds = list((proc / "fd").iterdir())
        except OSError:
            fds = []
        blobs += [_read(fd) for fd in fds]
    blobs += [_read(f) for f in out.rglob("*") if f.is_file()]
    found = {m.group(1).decode() for b in blobs for m in _ASSIGNED.finditer(b)}
    for b in blobs:  # a users file's "source:<password>" lines
        found |= {m.decode() for m in re.findall(rb"^(?:source|tracker|sink|launcher):([A-Za-z0-9_\-]{16,})$", b, re.M)}
    return found


def forge_eos(endpoint: str, run: str, last_seq: int, user: str = "", password: str = "") -> str:
    """Open a client session to the run's router as ``user`` and put a forged end of stream of
    the source at ``last_seq``: "refused" when the session cannot be opened, else "sent"."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if user:
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    try:
        session = zenoh.open(conf)
    except Exception:
        return "refused"
    with session:
        eos = {"stage": "source", "run": run, "last_seq": last_seq, "frames": last_seq + 1}
        session.put(f"bnptrack/{run}/eos/source", json.dumps(eos).encode())
    return "sent"


def _launch(out: Path, run: str, *extra: str) -> subprocess.Popen:
    return popen_bnptrack("launch", "--set", "source.frames=100", "--set", "source.rate=20", "--set",
                          "sink.rerun=false", "--set", "tracker.snapshot_every=5", "--set", "supervisor.linger_s=30",
                          *extra, "--run", run, "--out", str(out), "--timeout", "150")


def test_no_process_of_the_user_finds_a_stage_key_and_a_forged_end_of_stream_is_refused(tmp_path):
    """While a default launch runs, the stages' environment, command lines, open descriptors
    and the run's files hold no password; the source's name with anything found (or nothing)
    cannot open a session, so no forged end of stream gets in: 100 frames, exit 0."""
    out = tmp_path / "run"
    run = "keys"
    p = _launch(out, run)
    try:
        _wait_for("the tracker's first snapshot", (out / "tracker.snap").exists, p)
        stages = json.loads((out / "stages.json").read_text())
        pids = [int(s["pid"]) for s in stages.values()]
        endpoint = json.loads((out / "pipeline.json").read_text())["zenoh"]["connect"][0]
        environ = _read(Path(f"/proc/{stages['source']['pid']}/environ"))
        assert environ and b"BNPTRACK_ZENOH_PASSWORD" not in environ
        found = harvest(pids, out)
        assert found == set()
        for pw in sorted(found) or ["", "not-the-password"]:
            assert forge_eos(endpoint, run, 41, "source", pw) == "refused"
    finally:
        code, text = finish(p, 200)
    assert code == 0, text
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["output_complete"] and s["frames_written"] == 100 and s["source_eos"] == {"last_seq": 99, "frames": 100}


def test_a_forged_end_of_stream_that_gets_in_ends_the_run_with_exit_3_naming_the_conflict(tmp_path):
    """With authentication off anyone may put on the run's keys (as one with a stolen key
    could): an end of stream of the source at seq 5 while the source is still publishing.
    The source sees it on the bus and tells its launcher, which stops the run at once and
    exits 3 naming the conflict; sink.json is incomplete and says what it lacks."""
    out = tmp_path / "run"
    run = "forged"
    p = _launch(out, run, "--set", "zenoh.auth=false")
    try:
        _wait_for("the tracker's first snapshot", (out / "tracker.snap").exists, p)
        endpoint = json.loads((out / "pipeline.json").read_text())["zenoh"]["connect"][0]
        assert forge_eos(endpoint, run, 5) == "sent"
    finally:
        code, text = finish(p, 200)
    assert code == 3, text
    error = text.strip().splitlines()[-1]
    assert error.startswith("Error: output incomplete: end of stream conflict: "), text
    assert "at seq 5 (6 frame(s))" in error and "that the source process never sent" in error, error
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["output_complete"] is False
    if s["complete"]:  # the sink ended on it before the launcher stopped the run: sink.json says so
        assert s["source_eos"] == {"last_seq": 5, "frames": 6} and "never sent" in s["eos_conflict"]
    assert s["frames_written"] < 100  # stopped at once, not after the source's 5 s of frames
