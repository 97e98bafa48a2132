"""The streaming pipeline over real Zenoh sessions (loopback only, explicit
tcp/127.0.0.1:PORT endpoints, multicast scouting off, every wait bounded).

Each test runs stage processes (``python -m bnptrack ...``); the whole file takes about a
minute on two cores.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.mcap_log import iter_frames, read_log, read_metadata

from testkit import REPO_ROOT, bnptrack_env, finish, popen_bnptrack, wait_until

ROOT = REPO_ROOT
VO2017 = ROOT / "recordings" / "vo2017-s1.mcap"

FAST = ["--set", "sink.rerun=false"]


# --------------------------------------------------------------------------- helpers


_env, _popen, _wait = bnptrack_env, popen_bnptrack, finish


def _cli(*args: str, timeout: float = 120) -> tuple[int, str]:
    return _wait(_popen(*args), timeout)


def _strip(est):
    diag = {k: v for k, v in est.diagnostics.items() if k != "ms"}  # "ms" is wall-clock time
    return (est.frame, est.stamp_ns, est.labels, est.assignments, est.assignment_prob, diag,
            [(t.state.tolist(), t.covariance.tolist(), t.existence) for t in est.tracks])


def _offline(log: Path, out: Path, tracker: str = "ddp", seed: int = 0, overrides=()) -> Path:
    """What ``bnptrack track LOG --tracker T --seed S --out OUT`` writes (in-process)."""
    from bnptrack.pipeline.offline import track_log
    from bnptrack.pipeline.resolve import tracker_setup

    meta = read_metadata(log)
    track_log(log, out, tracker_setup(tracker, overrides=overrides, metadata=meta).tracker, seed, meta)
    return out


def _assert_same_run(a: Path, b: Path, n: int | None = None) -> None:
    """Same input frames and the same /tracks messages (up to the wall-clock ``ms``)."""
    la, lb = read_log(a), read_log(b)
    assert [f.frame for f in la.frames] == [f.frame for f in lb.frames]
    for fa, fb in zip(la.frames, lb.frames):
        assert np.array_equal(fa.z, fb.z) and fa.stamp_ns == fb.stamp_ns
        assert (fa.truth is None) == (fb.truth is None)
        if fa.truth is not None:
            assert fa.truth.ids == fb.truth.ids and np.array_equal(fa.truth.states, fb.truth.states)
    assert [_strip(e) for e in la.tracks] == [_strip(e) for e in lb.tracks]
    if n is not None:
        assert len(la.tracks) == n


def _summary(out: Path) -> dict:
    return json.loads((out / "sink.json").read_text())


def _short_log(path: Path, n: int) -> Path:
    """The first ``n`` frames of recordings/vo2017-s1.mcap (with its metadata record)."""
    with McapLogWriter(path, read_metadata(VO2017)) as w:
        for i, frame in enumerate(iter_frames(VO2017)):
            if i == n:
                break
            w.write_frame(frame)
    return path


@pytest.fixture
def router():
    from bnptrack.pipeline.transport import Router

    r = Router(ZenohConfig())
    try:
        yield r
    finally:
        r.close()


# --------------------------------------------------------------------------- tests


def _timed_lines(p: subprocess.Popen, timeout: float) -> tuple[int, list[tuple[float, str]], str]:
    """Run ``p`` (stderr piped) to its end; (exit code, its stderr lines with the time each
    arrived, seconds from now, and its stdout)."""
    import threading

    t0 = time.monotonic()
    lines: list[tuple[float, str]] = []

    def read() -> None:
        for raw in p.stderr:
            lines.append((time.monotonic() - t0, raw.decode()))

    th = threading.Thread(target=read, daemon=True)
    th.start()
    try:
        out = p.stdout.read()
        p.wait(timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        pytest.fail(f"{p.args} did not finish in {timeout} s: {lines}")
    th.join(10)
    return p.returncode, lines, out.decode()


def test_launch_default_end_to_end_equals_offline_track(tmp_path):
    out = tmp_path / "run"
    p = _popen("launch", "--set", "source.frames=20", "--run", "e2e-1", "--out", str(out), "--timeout", "150")
    code, lines, stdout = _timed_lines(p, 180)
    text = stdout + "".join(line for _t, line in lines)
    assert code == 0, text
    assert "tracks.mcap" in text and str(out) in text
    # progress: plain lines on a pipe, the first within 3 s of the command's start, then
    # about one a second; the summary scores the run and ends with the command to view it
    progress = [(t, line) for t, line in lines if line.startswith("[")]
    assert "\r" not in text and progress, text
    assert progress[0][0] < 3.0, progress[0]
    # the last line (printed when the stages have ended) has the sink's final figures
    assert " frames 20" in progress[-1][1] and "tracks " in progress[-1][1] and "OSPA " in progress[-1][1], text
    summary_rows = stdout.splitlines()
    assert summary_rows[-1] == f"open with         bnptrack view {out / 'run.rrd'}", stdout
    s = _summary(out)
    assert s["view"] == f"bnptrack view {out / 'run.rrd'}" and s["scores"]["frames_scored"] == 20
    assert f"mean OSPA         {s['scores']['ospa']:.2f} m" in stdout
    log = read_log(out / "tracks.mcap")
    assert len(log.frames) == 20 and len(log.tracks) == 20
    assert log.metadata["scenario"] == "vo2017" and log.metadata["tracker"] == "ddp"
    # the input is the simulator's frames 1..20 ...
    from bnptrack.sources.scenarios import get_scenario
    from bnptrack.sources.synthetic import simulate
    from bnptrack.sources.scenarios import scenario_params

    sim = list(simulate(get_scenario("vo2017"), scenario_params("vo2017", "vo2017"), 1))[:20]
    assert all(np.array_equal(a.z, b.z) for a, b in zip(log.frames, sim))
    # ... and the tracks are those of `bnptrack track` on that input
    _assert_same_run(out / "tracks.mcap", _offline(out / "tracks.mcap", tmp_path / "offline.mcap"), 20)
    s = _summary(out)
    assert s["complete"] and s["counters"]["rejected"] == 0 and s["gaps"]["tracks"] == []
    assert (out / "tracker.snap").exists() and (out / "health.jsonl").stat().st_size > 0
    if s["files"] and any(f.endswith(".rrd") for f in s["files"]):
        assert (out / "run.rrd").stat().st_size > 0


def test_tracker_killed_and_restarted_resumes_with_identical_output(tmp_path):
    from bnptrack.pipeline.stages import read_snapshot

    out = tmp_path / "kill"
    p = _popen("launch", "--set", "source.frames=60", "--set", "source.rate=25",
               "--set", "tracker.snapshot_every=5", *FAST, "--run", "kill-1", "--out", str(out),
               "--timeout", "150")
    try:
        snap = out / "tracker.snap"
        _wait_for("the tracker never snapshotted", snap.exists, p)  # >= 5 frames processed
        # a second snapshot: the tracker is well into the run (>= 10 frames) when it is killed
        _wait_for("the tracker never snapshotted twice", lambda: read_snapshot(snap).last_seq >= 9, p)
        pid = json.loads((out / "stages.json").read_text())["tracker"]["pid"]
        os.kill(pid, signal.SIGKILL)
    finally:
        code, text = _wait(p, 180)
    assert code == 0, text
    assert "crashed (killed by SIGKILL)" in text and "restarted" in text
    stages = json.loads((out / "stages.json").read_text())
    assert stages["tracker"]["restarts"] == 1
    assert "resuming from" in (out / "logs" / "tracker.log").read_text()
    s = _summary(out)
    assert s["complete"] and s["gaps"] == {"measurements": [], "truth": [], "tracks": []}
    assert s["counters"]["duplicates"] > 0  # the restarted tracker re-sent frames: dropped
    _assert_same_run(out / "tracks.mcap", _offline(out / "tracks.mcap", tmp_path / "offline.mcap"), 60)


def _wait_for(what: str, cond, p: subprocess.Popen, timeout: float = 90) -> None:
    wait_until(cond, timeout, what, interval=0.05, abort=lambda: p.poll() is not None)


@pytest.mark.slow
def test_tracker_then_sink_killed_still_gives_identical_output(tmp_path):
    """Double crash: the tracker is killed (and restarted), later the sink too.  The restarted
    tracker published its journal again, so the restarted sink gets every frame's tracks
    from the new tracker's cache: tracks.mcap equals an uninterrupted run."""
    from bnptrack.pipeline.stages import read_snapshot

    out = tmp_path / "double"
    # 100 frames at 10 per second: the source is still publishing when the restarted tracker
    # (a few seconds of imports and warm-up) has caught up and the sink is killed
    p = _popen("launch", "--set", "source.frames=100", "--set", "source.rate=10",
               "--set", "tracker.snapshot_every=5", *FAST, "--run", "double-1", "--out", str(out),
               "--timeout", "150")
    snap = out / "tracker.snap"

    def stages() -> dict:
        return json.loads((out / "stages.json").read_text())

    try:
        _wait_for("the tracker never snapshotted", snap.exists, p)
        os.kill(stages()["tracker"]["pid"], signal.SIGKILL)
        killed_at = read_snapshot(snap).last_seq
        # the restarted tracker has resumed and gone on by a few snapshots
        _wait_for("the tracker was not restarted", lambda: stages()["tracker"]["restarts"] == 1, p)
        _wait_for("the restarted tracker made no progress",
                  lambda: read_snapshot(snap).last_seq >= killed_at + 10, p)
        assert not (out / "sink.json").exists(), "the run ended before the sink could be killed"
        os.kill(stages()["sink"]["pid"], signal.SIGKILL)
    finally:
        code, text = _wait(p, 180)
    assert code == 0, text
    assert stages()["tracker"]["restarts"] == 1 and stages()["sink"]["restarts"] == 1, text
    assert "published the" in (out / "logs" / "tracker.log").read_text()  # ... journal again
    s = _summary(out)
    assert s["complete"] and s["gaps"] == {"measurements": [], "truth": [], "tracks": []}
    _assert_same_run(out / "tracks.mcap", _offline(out / "tracks.mcap", tmp_path / "offline.mcap"), 100)


def test_sigint_stops_every_stage_and_flushes_files(tmp_path):
    out = tmp_path / "int"
    p = _popen("launch", "--set", "source.rate=10", "--set", "tracker.snapshot_every=10", *FAST,
               "--run", "int-1", "--out", str(out), "--timeout", "150")
    try:
        _wait_for("a tracker snapshot (>= 10 frames through the tracker)", (out / "tracker.snap").exists, p)
        pids = {k: v["pid"] for k, v in json.loads((out / "stages.json").read_text()).items()}
        os.kill(p.pid, signal.SIGINT)
    finally:
        code, text = _wait(p, 60)
    assert code == 130, text
    assert "Interrupted" in text
    for pid in pids.values():  # every stage process is gone
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    s = _summary(out)
    assert not s["complete"] and s["frames_written"] >= 10
    log = read_log(out / "tracks.mcap")
    assert len(log.frames) == s["frames_written"] and len(log.tracks) == s["tracks_written"]
    from mcap.reader import make_reader

    with open(out / "tracks.mcap", "rb") as f:  # closed properly: summary and footer written
        summary = make_reader(f).get_summary()
    # the stop may come between a frame's /measurements and its /truth: that truth is a gap
    truths = s["frames_written"] - len(set(s["gaps"]["truth"]) - set(s["gaps"]["measurements"]))
    assert summary is not None and summary.statistics.message_count == s["frames_written"] + truths + s["tracks_written"]
    from bnptrack.pipeline.stages import read_snapshot

    assert read_snapshot(out / "tracker.snap").last_seq >= 9
    for role in ("source", "tracker", "sink"):
        assert "SIGTERM: stopping" in (out / "logs" / f"{role}.log").read_text()


def test_replay_is_rate_invariant_and_equals_track(tmp_path):
    log = _short_log(tmp_path / "vo30.mcap", 30)
    a, b = tmp_path / "afap", tmp_path / "rate"
    pa = _popen("replay", str(log), "--as-fast-as-possible", "--seed", "2", *FAST, "--out", str(a),
                "--timeout", "150")
    pb = _popen("replay", str(log), "--rate", "40", "--seed", "2", *FAST, "--out", str(b), "--timeout", "150")
    (ca, ta), (cb, tb) = _wait(pa, 180), _wait(pb, 180)
    assert ca == 0, ta
    assert cb == 0, tb
    _assert_same_run(a / "tracks.mcap", b / "tracks.mcap", 30)
    _assert_same_run(a / "tracks.mcap", _offline(log, tmp_path / "track.mcap", seed=2), 30)
    assert read_log(a / "tracks.mcap").metadata["tracker_seed"] == "2"


def test_replay_topic_of_a_foreign_log_equals_track_topic(tmp_path):
    """A log whose measurements are on /radar/detections (truth on /gt): ``replay --topic``
    over Zenoh records the frames and /tracks of ``track --topic`` on it."""
    from testkit import rename_channels

    log = rename_channels(VO2017, tmp_path / "radar.mcap", {"/measurements": "/radar/detections", "/truth": "/gt"},
                          n=20)
    topics = ["--topic", "/radar/detections=/measurements", "--topic", "/gt=/truth"]
    out, off = tmp_path / "r", tmp_path / "track.mcap"
    code, text = _cli("replay", str(log), *topics, "--as-fast-as-possible", "--seed", "2", *FAST,
                      "--out", str(out), "--timeout", "150", timeout=180)
    assert code == 0, text
    code, text = _cli("track", str(log), *topics, "--seed", "2", "--out", str(off), "-q")
    assert code == 0, text
    _assert_same_run(out / "tracks.mcap", off, 20)
    assert read_log(out / "tracks.mcap").frames[-1].truth is not None
    assert _summary(out)["scores"]["frames_scored"] == 20


def test_two_runs_on_one_router_do_not_see_each_other(tmp_path, router):
    ep = router.endpoints[0]
    outs = [tmp_path / "one", tmp_path / "two"]
    procs = [
        _popen("launch", "--connect", ep, "--run", f"side-{i}", "--out", str(o),
               "--set", "source.frames=15", "--set", f"source.seed={i + 1}", "--set", f"tracker.seed={i}",
               *FAST, "--timeout", "150")
        for i, o in enumerate(outs)
    ]
    results = [_wait(p, 180) for p in procs]
    for code, text in results:
        assert code == 0, text
    for i, o in enumerate(outs):
        s = _summary(o)
        assert s["complete"] and s["counters"]["rejected"] == 0 and s["counters"]["duplicates"] == 0
        assert s["counters"]["accepted"] == 45  # 15 x (measurements, truth, tracks): nothing foreign
        log = read_log(o / "tracks.mcap")
        assert log.metadata["seed"] == str(i + 1) and log.metadata["run"] == f"side-{i}"
        _assert_same_run(o / "tracks.mcap", _offline(o / "tracks.mcap", tmp_path / f"off{i}.mcap", seed=i), 15)
    a, b = read_log(outs[0] / "tracks.mcap"), read_log(outs[1] / "tracks.mcap")
    assert not np.array_equal(a.frames[0].z, b.frames[0].z)


def _stage(role: str, run: str, ep: str, out: Path, *sets: str) -> subprocess.Popen:
    args = ["stage", role, "--run", run, "--connect", ep, "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    return _popen(*args, log=out.parent / f"{run}-{role}.log")


def _wait_eos(bus, stage: str, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ev = bus.recv(0.2)
        if ev is not None and ev.topic == f"eos/{stage}":
            return json.loads(ev.payload)
    pytest.fail(f"no end of stream from {stage} within {timeout} s")


def _wait_deadletters(bus, stage: str, n: int, timeout: float) -> None:
    """Wait until ``bus`` (subscribed to ``deadletter``) has received ``n`` dead letters of ``stage``."""
    deadline = time.monotonic() + timeout
    seen = 0
    while seen < n and time.monotonic() < deadline:
        ev = bus.recv(0.2)
        if ev is not None and ev.topic == "deadletter" and json.loads(ev.payload)["stage"] == stage:
            seen += 1
    assert seen >= n, f"{seen} dead letter(s) of {stage} within {timeout} s, not {n}"


def test_late_sink_gets_history_and_rejects_bad_input(tmp_path, router):
    """Source and tracker run to the end before the sink exists; the sink then receives the
    cached history.  Malformed, NaN, wrong-run and unsequenced samples published on the
    run's keys are rejected (counted, dead-lettered) and change nothing."""
    from bnptrack.tracker.messages import encode
    from bnptrack.pipeline.transport import Bus
    from bnptrack.tracker.types import Frame

    ep, run, out = router.endpoints[0], "late-1", tmp_path / "late"
    common = ["source.frames=12", "source.wait_for=['tracker']", "sink.rerun=false"]
    procs = [_stage("tracker", run, ep, out, *common), _stage("source", run, ep, out, *common)]
    intruder = Bus(run, "intruder", ZenohConfig(connect=[ep]), DeliveryConfig())
    watcher = Bus(run, "watcher", ZenohConfig(connect=[ep]), DeliveryConfig())
    try:
        watcher.subscribe(["eos/*", "deadletter"])
        eos = _wait_eos(watcher, "tracker", 90)
        assert eos["last_seq"] == 11 and eos["gaps"] == []
        good = Frame(frame=3, stamp_ns=3, sensor="x", kind="bearing_range", z=np.array([[0.1, 10.0]]))
        intruder.publish("measurements", b"{definitely not json", {"seq": 2})
        intruder.publish("measurements", encode(good, "other-run"), {"seq": 2, "frame": 3})
        intruder.publish("measurements", encode(good, run))  # no sequence number
        intruder.publish("tracks", b'{"v":1,"run":"late-1","frame":1,"stamp_ns":0,"tracks":[],'
                                   b'"assignments":[],"assignment_prob":[NaN]}', {"seq": 0})
        intruder.publish("truth", b'{"v":7,"run":"late-1","frame":1,"stamp_ns":0,"objects":[]}', {"seq": 0})
        # the tracker (still serving) has rejected the three bad /measurements: they are out
        _wait_deadletters(watcher, "tracker", 3, 60)
        sink = _stage("sink", run, ep, out, *common)
        code, _ = _wait(sink, 120)
        for p in procs:
            assert _wait(p, 60)[0] == 0
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
        intruder.close()
        watcher.close()
    assert code == 0, (out.parent / f"{run}-sink.log").read_text()
    s = _summary(out)
    assert s["complete"] and s["frames_written"] == 12 and s["gaps"]["measurements"] == []
    assert s["rejected_by_topic"] == {"measurements": 3, "tracks": 1, "truth": 1}
    sink_log = (out.parent / f"{run}-sink.log").read_text()
    assert "rejected measurements sample" in sink_log and "non-finite" in sink_log
    assert "unsupported schema version" in sink_log and "not this run" in sink_log
    tracker_log = (out.parent / f"{run}-tracker.log").read_text()
    assert tracker_log.count("rejected measurements sample") == 3
    _assert_same_run(out / "tracks.mcap", _offline(out / "tracks.mcap", tmp_path / "off.mcap"), 12)


def test_late_sink_beyond_the_cache_records_explicit_gaps(tmp_path, router):
    ep, run, out = router.endpoints[0], "late-2", tmp_path / "late2"
    common = ["source.frames=10", "source.wait_for=['tracker']", "sink.rerun=false",
              "delivery.cache_frames=4", "delivery.eos_grace_s=1.5"]
    procs = [_stage("tracker", run, ep, out, *common), _stage("source", run, ep, out, *common)]
    from bnptrack.pipeline.transport import Bus

    watcher = Bus(run, "watcher", ZenohConfig(connect=[ep]), DeliveryConfig())
    try:
        watcher.subscribe(["eos/*"])
        _wait_eos(watcher, "tracker", 90)
        code, _ = _wait(_stage("sink", run, ep, out, *common), 120)
        for p in procs:
            assert _wait(p, 60)[0] == 0
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
        watcher.close()
    assert code == 0
    s = _summary(out)
    assert s["complete"]
    assert s["gaps"]["measurements"] == list(range(6)) and s["gaps"]["tracks"] == list(range(6))
    log = read_log(out / "tracks.mcap")
    assert [f.frame for f in log.frames] == [7, 8, 9, 10] and [e.frame for e in log.tracks] == [7, 8, 9, 10]
    assert "recorded as a gap" in (out.parent / f"{run}-sink.log").read_text()


def test_truncated_replay_replays_the_prefix_then_fails(tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(VO2017.read_bytes()[:40_000])
    out = tmp_path / "trunc"
    code, text = _cli("replay", str(cut), "--as-fast-as-possible", *FAST, "--out", str(out),
                      "--timeout", "150", timeout=180)
    assert code == 2, text
    assert "truncated after frame" in text and "readable frame" in text
    n = len(read_log(out / "tracks.mcap").tracks)
    assert n > 10
    offline = tmp_path / "off.mcap"
    from bnptrack.sources.mcap_log import McapLogError

    with pytest.raises(McapLogError):
        list(iter_frames(cut))
    _offline(cut, offline)
    _assert_same_run(out / "tracks.mcap", offline, n)


def test_stage_command_needs_a_run_and_a_router():
    code, text = _cli("stage", "tracker", timeout=60)
    assert code == 2 and "--run RUN is required" in text
    code, text = _cli("stage", "tracker", "--run", "x", timeout=60)
    assert code == 2 and "--connect" in text


# --------------------------------------------------------------------------- multi-host: TLS + ACL


def _make_certs(d: Path) -> dict[str, str]:
    """A test CA, a router certificate for localhost / 127.0.0.1 and a client certificate
    signed by that CA; a second CA and a client certificate signed by it (``cryptography``)."""
    from cryptography import x509  # a test dependency (pyproject [test]): fail, do not skip
    import datetime
    import ipaddress

    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.timezone.utc)

    def build(subject, issuer, pub, signer, ca: bool, usage=ExtendedKeyUsageOID.SERVER_AUTH):
        b = (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer).public_key(pub)
             .serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(minutes=5))
             .not_valid_after(now + datetime.timedelta(hours=2))
             .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
        if ca:
            b = b.add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                              content_commitment=False, key_encipherment=False,
                                              data_encipherment=False, key_agreement=False,
                                              encipher_only=False, decipher_only=False), critical=True)
        else:
            b = (b.add_extension(x509.SubjectAlternativeName(
                    [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
                 .add_extension(x509.ExtendedKeyUsage([usage]), critical=False))
        return b.sign(signer, hashes.SHA256())

    def key():
        return ec.generate_private_key(ec.SECP256R1())

    def name(cn: str):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    pem = serialization.Encoding.PEM
    files: dict[str, Path] = {}

    def save(tag: str, cert, k=None) -> None:
        files[tag] = d / f"{tag}.pem"
        files[tag].write_bytes(cert.public_bytes(pem))
        if k is not None:
            files[f"{tag}_key"] = d / f"{tag}.key"
            files[f"{tag}_key"].write_bytes(k.private_bytes(pem, serialization.PrivateFormat.PKCS8,
                                                            serialization.NoEncryption()))

    client = ExtendedKeyUsageOID.CLIENT_AUTH
    for prefix, cn in (("", "bnptrack test CA"), ("other_", "another CA")):
        ca_key, srv_key, cli_key = key(), key(), key()
        ca = build(name(cn), name(cn), ca_key.public_key(), ca_key, True)
        save(f"{prefix}ca", ca)
        save(f"{prefix}client", build(name("stage"), name(cn), cli_key.public_key(), ca_key, False, client), cli_key)
        if not prefix:
            save("cert", build(name("localhost"), name(cn), srv_key.public_key(), ca_key, False), srv_key)
    files["key"] = files.pop("cert_key")
    return {k: str(v) for k, v in files.items()}


def test_stages_over_tls_with_access_control(tmp_path):
    """The multi-host recipe on loopback: a TLS router with usrpwd authentication and the
    generated ACL; source, tracker and sink as separate `bnptrack stage` processes with their
    own credentials.  A client without the CA, or with a wrong password, is refused; a stage
    cannot put on another stage's keys."""
    from bnptrack.pipeline.config import TlsConfig
    from bnptrack.pipeline.transport import Bus, Router, TransportError

    certs = _make_certs(tmp_path)
    users = tmp_path / "users.txt"
    pw = {"source": "s3cret-src", "tracker": "s3cret-trk", "sink": "s3cret-snk", "watch": "w"}
    users.write_text("".join(f"{u}:{p}\n" for u, p in pw.items()))
    zr = ZenohConfig(tls=TlsConfig(root_ca_certificate=certs["ca"], listen_certificate=certs["cert"],
                                   listen_private_key=certs["key"]),
                     users_file=str(users), acl=True)
    run, out = "secure-1", tmp_path / "secure"
    common = ["source.frames=10", "sink.rerun=false", f"zenoh.tls.root_ca_certificate='{certs['ca']}'"]
    with Router(zr, ["tls/127.0.0.1:0"]) as router:
        ep = router.endpoints[0]
        assert ep.startswith("tls/127.0.0.1:")
        client = ZenohConfig(connect=[ep], connect_timeout_s=1.0)
        with pytest.raises(TransportError):  # no CA: the router's certificate is not trusted
            Bus(run, "x", msgspec_replace(client, user="sink", password=pw["sink"]), DeliveryConfig())
        tls_client = msgspec_replace(client, tls=TlsConfig(root_ca_certificate=certs["ca"]))
        with pytest.raises(TransportError):  # wrong password
            Bus(run, "x", msgspec_replace(tls_client, user="sink", password="nope"), DeliveryConfig())
        # a stage publishing on another stage's key: the router drops it
        rogue = Bus(run, "rogue", msgspec_replace(tls_client, user="sink", password=pw["sink"]), DeliveryConfig())
        procs = []
        try:
            rogue.publish("measurements", b"{rogue", {"seq": 0})
            rogue.publish("tracks", b"{rogue", {"seq": 0})
            for role in ("sink", "tracker", "source"):
                env = {"BNPTRACK_ZENOH_USER": role, "BNPTRACK_ZENOH_PASSWORD": pw[role]}
                args = ["stage", role, "--run", run, "--connect", ep, "--out", str(out)]
                for s in common:
                    args += ["--set", s]
                procs.append(_popen(*args, log=tmp_path / f"{role}.log", env=env))
            rc = {p.args[4]: _wait(p, 120)[0] for p in procs}
        finally:
            for p in procs:
                if p.poll() is None:
                    os.killpg(p.pid, signal.SIGKILL)
            rogue.close()
    assert rc == {"sink": 0, "tracker": 0, "source": 0}, [(tmp_path / f"{r}.log").read_text() for r in rc]
    s = _summary(out)
    assert s["complete"] and s["frames_written"] == 10 and s["counters"]["rejected"] == 0
    assert "rejected" not in (tmp_path / "tracker.log").read_text()
    _assert_same_run(out / "tracks.mcap", _offline(out / "tracks.mcap", tmp_path / "off.mcap"), 10)


def msgspec_replace(obj, **kw):
    import msgspec

    return msgspec.structs.replace(obj, **kw)


def _roundtrip(zcfg: ZenohConfig, run: str) -> bytes | None:
    """Open two stage sessions with ``zcfg``; what one receives of the other's put."""
    from bnptrack.pipeline.transport import Bus

    with Bus(run, "a", zcfg, DeliveryConfig()) as a, Bus(run, "b", zcfg, DeliveryConfig()) as b:
        b.subscribe(["deadletter"], advanced=False)
        b.declare_alive("ready")
        assert not a.wait_alive(["b"], 20, "ready")
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            a.publish("deadletter", b"hello", {"seq": 0})
            ev = b.recv(0.2)
            if ev is not None:
                return ev.payload
    return None


def test_mutual_tls_refuses_clients_without_a_certificate_of_the_ca(tmp_path):
    """Router with ``mtls = true``: a client needs a certificate signed by the CA.  Without
    one, or with one from another CA, ``zenoh.open`` fails; with one, data flows."""
    from bnptrack.pipeline.config import TlsConfig
    from bnptrack.pipeline.transport import Bus, Router, TransportError

    c = _make_certs(tmp_path)
    zr = ZenohConfig(tls=TlsConfig(root_ca_certificate=c["ca"], listen_certificate=c["cert"],
                                   listen_private_key=c["key"], mtls=True))
    with Router(zr, ["tls/127.0.0.1:0"]) as router:
        ep = router.endpoints[0]

        def client(**tls) -> ZenohConfig:
            return ZenohConfig(mode="client", connect=[ep], connect_timeout_s=1.0,
                               tls=TlsConfig(root_ca_certificate=c["ca"], **tls))

        refused = {
            "no client certificate": client(),
            "no client certificate (mtls on)": client(mtls=True),
            "certificate of another CA": client(connect_certificate=c["other_client"],
                                                connect_private_key=c["other_client_key"], mtls=True),
        }
        for why, zcfg in refused.items():
            with pytest.raises(TransportError):
                Bus("mtls-1", "x", zcfg, DeliveryConfig()).close()
                pytest.fail(f"the router accepted a client with {why}")
        good = client(connect_certificate=c["client"], connect_private_key=c["client_key"], mtls=True)
        assert _roundtrip(good, "mtls-1") == b"hello"


def test_peer_mode_links_stages_directly(router):
    """``zenoh.mode = "peer"``: stages that only know the router learn each other's loopback
    endpoints by gossip and connect directly."""
    from bnptrack.pipeline.transport import Bus

    zcfg = ZenohConfig(mode="peer", connect=[router.endpoints[0]])
    assert _roundtrip(zcfg, "peer-1") == b"hello"
    with Bus("peer-2", "a", zcfg, DeliveryConfig()) as a, Bus("peer-2", "b", zcfg, DeliveryConfig()) as b:
        wait_until(lambda: min(a.links()["peers"], b.links()["peers"]) >= 1, 20,
                   "the two peers to link directly", interval=0.05)
        assert a.links() == {"routers": 1, "peers": 1} and b.links()["peers"] == 1


def test_peer_mode_refuses_tls_and_access_control():
    from bnptrack.pipeline.config import TlsConfig, load_pipeline
    from bnptrack.tracker.config import ConfigError

    for bad in ({"acl": True}, {"users_file": "u.txt"}, {"tls": TlsConfig(root_ca_certificate="ca.pem")}):
        with pytest.raises(ValueError, match="peer"):
            ZenohConfig(mode="peer", **bad)
    with pytest.raises(ConfigError, match="peer"):
        load_pipeline(None, ["zenoh.mode='peer'", "zenoh.acl=true"])
    assert ZenohConfig(acl=True).mode == "client"


def test_launch_connect_streams_the_recording_live_with_the_same_rows(tmp_path):
    """``launch --connect rerun+http://...``: the sink streams run.rrd's rows to a running
    viewer (here its gRPC server alone, saving what it receives); a URL where no viewer
    listens is a configuration error before anything starts."""
    from test_live_view import Receiver, rows

    recv = Receiver(tmp_path / "received.rrd")
    try:
        out = tmp_path / "run"
        code, text = _cli("launch", "--set", "source.frames=12", "--out", str(out), "--connect", recv.url,
                          "--timeout", "150", timeout=180)
        assert code == 0, text
        want = rows(out / "run.rrd")
        assert recv.rows(want) == want
    finally:
        recv.stop()
    t0 = time.monotonic()
    code, text = _cli("launch", "--out", str(tmp_path / "none"), "--connect", "rerun+http://127.0.0.1:9/proxy")
    assert code == 2 and text.startswith("Error: no Rerun viewer at rerun+http://127.0.0.1:9/proxy"), text
    assert not (tmp_path / "none").exists() and time.monotonic() - t0 < 10


def test_replay_loop_with_start_and_end(tmp_path):
    """``replay --start 20s --end 29 --loop 2``: two fresh runs (RUN-1, RUN-2, each in its
    own directory) of log time 20..29 s (vo2017-s1: frames 21..30), each with the tracks of
    a fresh tracker; a malformed offset is a usage error (exit 2) before anything starts."""
    out = tmp_path / "loop"
    code, text = _cli("replay", str(VO2017), "--as-fast-as-possible", "--start", "20s", "--end", "29",
                      "--loop", "2", "--run", "lp", "--out", str(out), *FAST, "--timeout", "150", timeout=400)
    assert code == 0, text
    assert sorted(p.name for p in out.iterdir()) == ["lp-1", "lp-2"]
    for i in (1, 2):
        log = read_log(out / f"lp-{i}" / "tracks.mcap")
        assert [f.frame for f in log.frames] == list(range(21, 31)) and log.metadata["run"] == f"lp-{i}"
    _assert_same_run(out / "lp-1" / "tracks.mcap", out / "lp-2" / "tracks.mcap", 10)
    code, text = _cli("replay", str(VO2017), "--start", "ten", "--out", str(tmp_path / "none"))
    assert code == 2 and "--start" in text and not (tmp_path / "none").exists()
