"""Issue 17: nothing lost, nothing forged -- restarts at any moment, history for restarted
consumers, a pipeline closed to other local processes, bounded resources.

The in-memory tests (pipeline.membus) run in seconds; the tests over real Zenoh sessions
(loopback only, every wait bounded) take a few seconds each; those marked ``slow`` run
2,000-frame pipelines (minutes)."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest

from pipeline.membus import MemoryNetwork
from pipeline.config import PipelineConfig, resolve_run
from pipeline.stages import (
    EXIT_OK,
    STAGES,
    SUMMARY_NAME,
    StageContext,
    commit_parts,
    part_path,
    read_snapshot,
)
from sources.mcap_log import read_log
from tracker.config import apply_overrides

ROOT = Path(__file__).resolve().parent.parent


def _mem_cfg(tmp_path: Path, frames: int = 8) -> PipelineConfig:
    overrides = [f"source.frames={frames}", "tracker.overrides=['sweeps=8', 'burn_in=2']",
                 "sink.rerun=false", "tracker.snapshot_every=4", "delivery.eos_grace_s=0.3",
                 "supervisor.linger_s=0.5"]
    return resolve_run(apply_overrides(PipelineConfig(run="mem", out=str(tmp_path / "out")), overrides))


def _run_stage(cfg: PipelineConfig, net: MemoryNetwork, role: str) -> int:
    bus = net.bus(cfg.run, role)
    try:
        return STAGES[role](StageContext(cfg, bus, name=role)).run()
    finally:
        bus.close()


def _memory_run(cfg: PipelineConfig, net: MemoryNetwork) -> None:
    """The whole pipeline in threads on one manual clock (``test_pipeline_stages``)."""
    from test_pipeline_stages import _run_memory_pipeline

    codes = _run_memory_pipeline(cfg, net)
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- restarts (in memory)


def test_outputs_appear_only_complete_and_a_restarted_sink_keeps_them(tmp_path):
    """The sink writes .tracks.mcap.part and renames it after sink.json; a sink started again
    after the run (killed while it lingered) announces the recorded end of stream again,
    exits 0, and leaves every file byte for byte as it was."""
    cfg = _mem_cfg(tmp_path)
    net = MemoryNetwork()
    _memory_run(cfg, net)
    out = Path(cfg.out)
    mcap = out / "tracks.mcap"
    assert mcap.exists() and not part_path(mcap).exists()
    before = {p.name: _digest(p) for p in (mcap, out / SUMMARY_NAME)}
    n_eos = sum(1 for r, t, *_ in net.history if t == "eos/sink")
    assert n_eos == 1
    t0 = time.monotonic()
    assert _run_stage(cfg, net, "sink") == EXIT_OK
    assert time.monotonic() - t0 < 10
    assert {p.name: _digest(p) for p in (mcap, out / SUMMARY_NAME)} == before
    eos = [msgspec.json.decode(p) for r, t, p, a in net.history if t == "eos/sink"]
    assert len(eos) == 2 and eos[1]["last_seq"] == 7 and eos[1]["frames"] == 8
    assert len(read_log(mcap).tracks) == 8


def test_a_tracker_restarted_after_it_finished_announces_its_end_again(tmp_path):
    cfg = _mem_cfg(tmp_path)
    net = MemoryNetwork()
    _memory_run(cfg, net)
    snap = read_snapshot(Path(cfg.out) / "tracker.snap")
    assert snap.eos is not None and snap.eos.last_seq == 7 and snap.eos.frames == 8
    journal = _digest(Path(cfg.out) / "tracker.journal")
    t0 = time.monotonic()
    assert _run_stage(cfg, net, "tracker") == EXIT_OK  # the sink's eos is in the history
    assert time.monotonic() - t0 < 10
    eos = [msgspec.json.decode(p) for r, t, p, a in net.history if t == "eos/tracker"]
    assert len(eos) == 2 and eos[0] == eos[1]
    assert _digest(Path(cfg.out) / "tracker.journal") == journal


def test_a_sink_killed_between_its_summary_and_the_renames_is_completed(tmp_path):
    """sink.json says complete but tracks.mcap is still .part: the next sink (or the
    launcher) finishes the rename instead of recording again."""
    cfg = _mem_cfg(tmp_path)
    net = MemoryNetwork()
    _memory_run(cfg, net)
    out = Path(cfg.out)
    mcap = out / "tracks.mcap"
    digest = _digest(mcap)
    os.replace(mcap, part_path(mcap))  # as if killed right after sink.json
    assert _run_stage(cfg, net, "sink") == EXIT_OK
    assert _digest(mcap) == digest and not part_path(mcap).exists()
    commit_parts([mcap])  # nothing left to do: no error
    assert _digest(mcap) == digest


def test_frames_lost_on_the_way_are_fetched_from_the_publishers_cache_not_guessed(tmp_path):
    """Issue 17 item 3: frames 3-6 never arrive (neither live nor in the subscribers'
    history), but their publishers still hold them: the tracker and the sink fetch them
    explicitly, so there is no gap and the tracks equal the offline run of every frame."""
    from pipeline.stages import source_frames
    from tracker.state import run as run_offline
    from pipeline.resolve import apply_split_overrides, build_tracker, resolve_config, resolve_params

    cfg = _mem_cfg(tmp_path, frames=12)
    net = MemoryNetwork()
    net.fetchable = True

    def tap(run, topic, payload, att):
        if topic in ("measurements", "truth", "tracks") and att and json.loads(att)["seq"] in (3, 4, 5, 6):
            return []
        return [(payload, att)]

    net.tap = tap
    _memory_run(cfg, net)
    s = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert s["gaps"] == {"measurements": [], "truth": [], "tracks": []} and not s["missing"]
    meta, frames = source_frames(cfg)
    choice = resolve_params(None, meta)
    conf, _ = resolve_config("ddp", None)
    params, conf = apply_split_overrides(choice.params, conf, cfg.tracker.overrides)
    ests = [e for _, e, _ in run_offline(build_tracker("ddp", params, conf), list(frames), 0)]

    def strip(e):
        d = {k: v for k, v in e.diagnostics.items() if k != "ms"}
        return (e.frame, e.labels, e.assignments, d, [(t.state.tolist(), t.existence) for t in e.tracks])

    assert [strip(e) for e in read_log(Path(cfg.out) / "tracks.mcap").tracks] == [strip(e) for e in ests]


def test_sequencer_catch_up_holds_until_the_announced_live_head():
    """Issue 17 failure 8: Sequencer(32, 0, catch_up=10000), push(0), push(5000) declared
    4,968 gaps and push(1) was late, because catch-up ended when the buffer was empty once.
    With the publisher's live head announced (5000), catch-up holds until seq 5000 is
    released: nothing is declared missing and the history 1..4999 is accepted."""
    from pipeline.stages import GAP, Sequencer

    old = Sequencer(32, 0, "m", 10_000)
    old.push(0, 0)
    old.push(5000, 5000)
    assert len(old.gaps) == 4968 and old.push(1, 1)[0] == "late"  # without a head: as before

    q = Sequencer(32, 0, "m", 10_000)
    q.hold_catch_up_through(5000)
    assert q.push(0, 0) == ("accepted", [(0, 0)])
    assert q.push(5000, 5000) == ("accepted", [])
    assert q.gaps == [] and not q.caught_up
    released = []
    for s in range(1, 5000):
        status, rel = q.push(s, s)
        assert status == "accepted"
        released += rel
    assert [x for _, x in released] == list(range(1, 5001)) and GAP not in released
    assert q.caught_up and q.window == 32
    # once caught up, the normal window applies again
    status, rel = q.push(5040, 5040)
    assert status == "accepted" and len(q.gaps) == 5040 - 32 - 5000


# --------------------------------------------------------------------------- over Zenoh


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["RERUN_ANALYTICS"] = "0"
    return env


def _popen(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pipeline", *args], cwd=ROOT, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)


def _wait(p: subprocess.Popen, timeout: float) -> tuple[int, str]:
    try:
        out, _ = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, _ = p.communicate(timeout=10)
        pytest.fail(f"{p.args} did not finish in {timeout} s:\n{out.decode()}")
    return p.returncode, out.decode()


def _wait_for(what: str, cond, p: subprocess.Popen, timeout: float = 90) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline and p.poll() is None, what
        time.sleep(0.01)


def _offline_tracks(log: Path, out: Path) -> list:
    from pipeline.offline import track_log
    from pipeline.resolve import build_tracker, resolve_config, resolve_params
    from sources.mcap_log import read_metadata

    meta = read_metadata(log)
    config, _ = resolve_config("ddp", None)
    track_log(log, out, build_tracker("ddp", resolve_params(None, meta).params, config), 0, meta)
    return _tracks(out)


def _tracks(path: Path) -> list:
    def strip(e):
        d = {k: v for k, v in e.diagnostics.items() if k != "ms"}
        return (e.frame, e.labels, e.assignments, d, [(t.state.tolist(), t.existence) for t in e.tracks])

    return [strip(e) for e in read_log(path).tracks]


@pytest.mark.parametrize("role", ["sink", "tracker"])
def test_a_stage_killed_just_after_the_run_was_recorded_leaves_it_complete(tmp_path, role):
    """Issue 17, failure 1 and 11: SIGKILL of the sink (or the tracker) the moment sink.json
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
    assert _tracks(out / "tracks.mcap") == _offline_tracks(out / "tracks.mcap", tmp_path / "off.mcap")
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] and s["frames_written"] == 30 and not s["missing"]
    assert not list(out.glob(".*.part"))


# --------------------------------------------------------------------------- closed by default


def _forge(endpoint: str, run: str, user: str = "", password: str = "") -> str:
    """What an outsider on this host achieves: open a client session to the run's router
    (no credentials, or wrong ones) and put a forged end of stream and a forged frame 10**9.
    Returns "refused" when the session cannot be opened, else "sent"."""
    import zenoh

    from tracker.messages import encode
    from tracker.types import Frame
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
    """Issue 17, failures 4-7 with the default launch: per-run credentials and the ACL keep
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
    assert _tracks(out / "tracks.mcap") == _offline_tracks(out / "tracks.mcap", tmp_path / "off.mcap")


def test_with_the_acl_a_stage_cannot_put_on_another_stages_keys_or_declare_its_tokens(tmp_path):
    """An authenticated user (the sink's credentials) may not put a forged eos/source or
    /measurements, nor declare the tracker's ready token."""
    import zenoh

    from pipeline.config import DeliveryConfig, ZenohConfig
    from pipeline.transport import Bus, Router

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
    """Issue 17 item 6 (disk full / I/O error, here EFBIG from RLIMIT_FSIZE): one line naming
    the stage and the file, every stage process stopped, exit 2 within 10 s of the error, no
    .part or temporary file left."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from faults import make_log

    log = make_log(tmp_path / "vo300.mcap", 300)
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "pipeline", "replay", str(log), "--as-fast-as-possible",
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
    return log, _offline_tracks(log, d / "offline.mcap")


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_long_run_tracker_then_sink_killed_at_seeded_points_equals_offline(tmp_path, long_log, seed):
    """Issue 17 item 3: in a 2,000-frame replay at 50 frames/s (client mode, the default
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
    assert _tracks(out / "tracks.mcap") == expected
