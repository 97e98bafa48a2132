"""Nothing lost, nothing forged -- restarts at any moment, history for restarted
consumers, a pipeline closed to other local processes, bounded resources.

The tests here run stage processes over real Zenoh sessions (loopback only, every wait
bounded) and take a few seconds each; those marked ``slow`` run 2,000-frame pipelines
(minutes).  The in-memory restart tests are in tests/pipeline/test_pipeline_restarts.py."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from bnptrack.pipeline.stages import SUMMARY_NAME, read_snapshot
from bnptrack.sources.mcap_log import read_log

from testkit import REPO_ROOT, bnptrack_env, finish, log_tracks, offline_log_tracks, popen_bnptrack, wait_until

ROOT = REPO_ROOT


# --------------------------------------------------------------------------- over Zenoh


_env, _popen, _wait = bnptrack_env, popen_bnptrack, finish


def _wait_for(what: str, cond, p: subprocess.Popen, timeout: float = 90) -> None:
    wait_until(cond, timeout, what, interval=0.01, abort=lambda: p.poll() is not None)


@pytest.mark.parametrize("role", ["sink", "tracker"])
def test_a_stage_killed_just_after_the_run_was_recorded_leaves_it_complete(tmp_path, role):
    """SIGKILL of the sink (or the tracker) the moment sink.json
    appears.  The recording stays complete (30 frames, equal to offline `track`), the launch
    ends with exit 0, and no stage records anything again."""
    out = tmp_path / "run"
    p = _popen("launch", "--set", "source.frames=30", "--set", "sink.rerun=false", "--run", f"fin-{role}",
               "--out", str(out), "--timeout", "120")
    try:
        _wait_for("the sink never wrote sink.json", (out / SUMMARY_NAME).exists, p)
        pid = json.loads((out / "stages.json").read_text())[role]["pid"]
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:  # already gone: the case still holds
            pass
    finally:
        code, text = _wait(p, 150)
    assert code == 0, text
    assert len(read_log(out / "tracks.mcap").tracks) == 30
    assert log_tracks(out / "tracks.mcap") == offline_log_tracks(out / "tracks.mcap", tmp_path / "off.mcap")
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] and s["frames_written"] == 30 and not s["missing"]
    assert not list(out.glob(".*.part"))


# --------------------------------------------------------------------------- closed by default


def _forge(endpoint: str, run: str, user: str = "", password: str = "") -> str:
    """What an outsider on this host achieves: open a client session to the run's router
    (no credentials, or wrong ones) and put a forged end of stream and a forged frame 10**9.
    Returns "refused" when the session cannot be opened, else "sent"."""
    import zenoh

    from bnptrack.tracker.messages import encode
    from bnptrack.tracker.types import Frame
    import numpy as np

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
        eos = {"stage": "source", "run": run, "last_seq": 2, "frames": 3}
        session.put(f"bnptrack/{run}/eos/source", json.dumps(eos).encode())
        frame = Frame(10**9, 10**18, "x", "bearing_range", np.array([[0.1, 100.0]]))
        for seq in (3, 4, 5, 10**6):
            session.put(f"bnptrack/{run}/measurements", encode(frame, run),
                        attachment=json.dumps({"seq": seq, "t": 1, "frame": 10**9}).encode())
    return "sent"


@pytest.mark.parametrize("who", ["anonymous", "wrong-password"])
def test_a_default_launch_refuses_forged_samples_from_other_local_processes(tmp_path, who):
    """With the default launch, per-run credentials and the ACL keep
    an outsider (no credentials, or a stage's name with a wrong password) out; the run ends
    complete, equal to offline `track`, nothing rejected."""
    out = tmp_path / "run"
    run = f"closed-{who}"
    p = _popen("launch", "--set", "source.frames=40", "--set", "source.rate=20", "--set", "sink.rerun=false",
               "--set", "tracker.snapshot_every=5", "--run", run, "--out", str(out), "--timeout", "120")
    try:
        _wait_for("the tracker never snapshotted", (out / "tracker.snap").exists, p)
        endpoint = json.loads((out / "pipeline.json").read_text())["zenoh"]["connect"][0]
        assert endpoint.startswith("tcp/127.0.0.1:")
        assert not list(out.glob("*users*"))  # the password file is gone once the router read it
        user, pw = ("", "") if who == "anonymous" else ("source", "not-the-password")
        assert _forge(endpoint, run, user, pw) == "refused"
    finally:
        code, text = _wait(p, 150)
    assert code == 0, text
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] and s["frames_written"] == 40 and s["counters"]["rejected"] == 0
    assert log_tracks(out / "tracks.mcap") == offline_log_tracks(out / "tracks.mcap", tmp_path / "off.mcap")


def test_with_the_acl_a_stage_cannot_put_on_another_stages_keys_or_declare_its_tokens(tmp_path):
    """An authenticated user (the sink's credentials) may not put a forged eos/source or
    /measurements, nor declare the tracker's ready token."""

    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus, Router

    users = tmp_path / "users.txt"
    users.write_text("source:pw-s\nsink:pw-k\ntracker:pw-t\n")
    with Router(ZenohConfig(users_file=str(users), acl=True)) as r:
        def cfg(user, pw):
            return ZenohConfig(embedded_router=False, connect=r.connect_endpoints, user=user, password=pw)

        with Bus("acl", "tracker", cfg("tracker", "pw-t"), DeliveryConfig()) as tracker, \
                Bus("acl", "sink", cfg("sink", "pw-k"), DeliveryConfig()) as sink, \
                Bus("acl", "source", cfg("source", "pw-s"), DeliveryConfig()) as source:
            tracker.subscribe(["measurements", "eos/*"])
            # the sink forges: a token named like the tracker, an eos of the source, a frame
            sink.session.liveliness().declare_token("bnptrack/acl/ready/tracker")
            sink.session.put("bnptrack/acl/eos/source", b'{"stage":"source","run":"acl","last_seq":1}')
            sink.session.put("bnptrack/acl/measurements", b"{}", attachment=b'{"seq":0}')
            sink.declare_alive("ready")  # its own token is allowed
            source.publish("eos/source", b'{"stage":"source","run":"acl","last_seq":7}')  # the real one
            deadline = time.monotonic() + 20
            got = []
            while time.monotonic() < deadline and not any(e.topic == "eos/source" for e in got):
                ev = tracker.recv(0.1)
                if ev is not None:
                    got.append(ev)
            assert [json.loads(e.payload)["last_seq"] for e in got if e.topic == "eos/source"] == [7]
            assert not [e for e in got if e.topic == "measurements"]
            assert source.wait_alive(["sink"], 10, "ready") == set()
            assert source.alive("ready") == {"sink"}  # the forged tracker token never appeared


# --------------------------------------------------------------------------- resources


def _limit_file_size() -> None:  # in the child, before exec: every file it writes <= 200 KB
    import resource

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))


def test_a_file_that_cannot_be_written_stops_the_run_with_one_line_naming_it(tmp_path):
    """Disk full or I/O error (here EFBIG from RLIMIT_FSIZE): one line naming
    the stage and the file, every stage process stopped, exit 2 within 10 s of the error, no
    .part or temporary file left."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from faults import make_log

    log = make_log(tmp_path / "vo300.mcap", 300)
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "bnptrack", "replay", str(log), "--as-fast-as-possible",
                          "--set", "sink.rerun=false", "--out", str(out), "--timeout", "120"],
                         cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         start_new_session=True, preexec_fn=_limit_file_size)
    code, text = _wait(p, 150)
    t_end = time.time()
    assert code == 2, text
    error = [line for line in text.splitlines() if line.startswith("Error: ")]
    assert len(error) == 1, text
    assert "stage " in error[0] and "cannot write " + str(out) in error[0] and "File too large" in error[0]
    stages = json.loads((out / "stages.json").read_text())
    for role, st in stages.items():
        with pytest.raises(ProcessLookupError):
            os.kill(st["pid"], 0)
    failed = [r for r, st in stages.items() if st["returncode"] == 4]
    assert failed, stages
    # within 10 s of the failing stage's last log record, the launch was over
    assert t_end - (out / "logs" / f"{failed[0]}.log").stat().st_mtime < 10
    assert not [f.name for f in out.rglob("*") if f.name.endswith((".part", ".tmp"))]


# --------------------------------------------------------------------------- long runs


@pytest.fixture(scope="module")
def long_log(tmp_path_factory):
    """2,000 frames (vo2017-s1 repeated, consecutive frame numbers, 1 s apart) and the
    /tracks of offline `track` on them."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from faults import make_log

    d = tmp_path_factory.mktemp("long")
    log = make_log(d / "vo2000.mcap", 2000)
    return log, offline_log_tracks(log, d / "offline.mcap")


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_long_run_tracker_then_sink_killed_at_seeded_points_equals_offline(tmp_path, long_log, seed):
    """In a 2,000-frame replay at 50 frames/s (client mode, the default
    launch), SIGKILL the tracker at a seeded frame, then the sink at a later one.  The
    restarted stages get what they miss (history, explicit fetch): the output equals
    offline `track`, no gap, exit 0."""
    import random

    log, expected = long_log
    rng = random.Random(seed)
    kill_tracker_at = rng.randrange(200, 900)
    kill_sink_at = rng.randrange(kill_tracker_at + 200, 1700)
    out = tmp_path / "run"
    p = _popen("replay", str(log), "--rate", "50", "--set", "sink.rerun=false", "--set", "tracker.snapshot_every=10",
               "--out", str(out), "--timeout", "300")

    def progress() -> int:
        try:
            return read_snapshot(out / "tracker.snap").last_seq
        except Exception:
            return -1

    def pid(role: str) -> int:
        return json.loads((out / "stages.json").read_text())[role]["pid"]

    try:
        _wait_for("the tracker never reached its kill point", lambda: progress() >= kill_tracker_at, p, 200)
        os.kill(pid("tracker"), signal.SIGKILL)
        _wait_for("the restarted tracker never reached the sink's kill point",
                  lambda: progress() >= kill_sink_at, p, 200)
        assert not (out / SUMMARY_NAME).exists()
        os.kill(pid("sink"), signal.SIGKILL)
    finally:
        code, text = _wait(p, 330)
    assert code == 0, text
    stages = json.loads((out / "stages.json").read_text())
    assert stages["tracker"]["restarts"] == 1 and stages["sink"]["restarts"] == 1
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] and s["gaps"] == {"measurements": [], "truth": [], "tracks": []} and not s["missing"]
    assert log_tracks(out / "tracks.mcap") == expected
