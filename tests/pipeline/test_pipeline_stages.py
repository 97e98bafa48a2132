"""Pipeline stage logic without Zenoh: sequencing (dedupe, reordering window, gaps), intake
validation (malformed / NaN / wrong version / wrong run / oversize payloads) and whole
source -> tracker -> sink runs over the in-memory bus (pipeline.membus)."""

from __future__ import annotations

import json
import random
import threading
from pathlib import Path

import msgspec
import numpy as np
import pytest

from bnptrack.tracker.messages import encode
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.config import (
    PipelineConfig,
    default_pipeline,
    load_pipeline,
    resolve_run,
)
from bnptrack.pipeline.stages import (
    EXIT_OK,
    GAP,
    STAGES,
    ManualClock,
    SUMMARY_NAME,
    Counters,
    Intake,
    Sequencer,
    StageContext,
    read_snapshot,
    write_atomic,
)
from bnptrack.pipeline.events import Event
from bnptrack.sources.mcap_log import read_log
from bnptrack.tracker.config import ConfigError, apply_overrides
from bnptrack.tracker.types import Frame

from testkit import REPO_ROOT, ListSink, drop_seq, wait_until
from testkit import mem_cfg as _mem_cfg
from testkit import offline as _offline
from testkit import run_memory_pipeline as _run_memory_pipeline
from testkit import strip as _strip

# --------------------------------------------------------------------------- Sequencer


def _items(released):
    return [(s, "GAP" if x is GAP else x) for s, x in released]


def test_sequencer_in_order_and_duplicates():
    q = Sequencer(window=4)
    assert q.push(0, "a") == ("accepted", [(0, "a")])
    assert q.push(1, "b") == ("accepted", [(1, "b")])
    assert q.push(1, "b") == ("duplicate", [])
    assert q.push(0, "a") == ("duplicate", [])
    assert q.duplicates == 2 and q.accepted == 2 and q.next == 2


def test_sequencer_reorders_within_window():
    q = Sequencer(window=4)
    assert q.push(2, "c") == ("accepted", [])
    assert q.push(2, "c") == ("duplicate", [])  # duplicate of a buffered item
    assert q.push(1, "b") == ("accepted", [])
    assert q.pending == 2
    assert q.push(0, "a")[1] == [(0, "a"), (1, "b"), (2, "c")]
    assert q.gaps == [] and q.pending == 0


def test_sequencer_declares_gap_when_window_passes_and_rejects_late():
    q = Sequencer(window=3)
    q.push(0, "a")
    assert q.push(2, "c")[1] == []
    assert q.push(3, "d")[1] == []
    # seq 4 is 3 ahead of the missing seq 1: 1 becomes a gap, 2..4 are released
    status, rel = q.push(4, "e")
    assert status == "accepted"
    assert _items(rel) == [(1, "GAP"), (2, "c"), (3, "d"), (4, "e")]
    assert q.gaps == [1]
    assert q.push(1, "b") == ("late", [])
    assert q.late == 1


def test_sequencer_far_ahead_frame_declares_everything_behind():
    q = Sequencer(window=2)
    assert _items(q.push(5, "f")[1]) == [(0, "GAP"), (1, "GAP"), (2, "GAP"), (3, "GAP")]
    assert q.next == 4 and q.pending == 1
    assert _items(q.push(4, "e")[1]) == [(4, "e"), (5, "f")]


def test_sequencer_flush_and_mark_gaps():
    q = Sequencer(window=32)
    q.push(0, "a")
    q.push(3, "d")
    assert _items(q.flush_through(4)) == [(1, "GAP"), (2, "GAP"), (3, "d"), (4, "GAP")]
    assert q.complete_through(4) and q.gaps == [1, 2, 4]
    q2 = Sequencer(window=32)
    q2.push(0, "a")
    q2.push(2, "c")
    assert _items(q2.mark_gaps([1])) == [(1, "GAP"), (2, "c")]


def test_sequencer_is_deterministic_under_bounded_shuffles_and_duplicates():
    """Any arrival order displaced by less than the window, with duplicates, releases
    every item exactly once, in order, without gaps."""
    rng = random.Random(7)
    for _ in range(50):
        n, window = 200, rng.randint(2, 16)
        keys = sorted(range(n), key=lambda i: i + rng.uniform(0, window - 1))
        arrivals = []
        for s in keys:
            arrivals.append(s)
            if rng.random() < 0.2:
                arrivals.append(s)  # duplicate right away
            if rng.random() < 0.05 and arrivals:
                arrivals.append(rng.choice(arrivals))  # an old duplicate
        q = Sequencer(window)
        out = []
        for s in arrivals:
            out += q.push(s, s)[1]
        assert [s for s, _ in out] == list(range(n))
        assert all(x == s for s, x in out)
        assert q.gaps == []


# --------------------------------------------------------------------------- intake


def _frame(k=3, z=((0.1, 100.0), (-0.2, 250.0))):
    return Frame(frame=k, stamp_ns=k * 10**9, sensor="s", kind="bearing_range", z=np.array(z))


def _ev(payload, meta=None, topic="measurements", err=None):
    return Event(topic, payload, meta, 0, err)


def _intake():
    bus = ListSink()
    c = Counters()
    return Intake("tracker", "runA", bus, c, max_payload_bytes=4096), bus, c


def test_intake_accepts_a_valid_sample():
    intake, bus, c = _intake()
    acc = intake.check(_ev(encode(_frame(), "runA"), {"seq": 0, "frame": 3}))
    assert acc is not None and acc.seq == 0 and acc.msg.frame == 3
    assert c.rejected == 0 and bus.published == []


@pytest.mark.parametrize(
    "payload, meta, needle",
    [
        (b"{not json", {"seq": 1}, "measurements"),
        (b'{"v":1,"run":"runA","frame":3,"stamp_ns":0,"sensor":"s","kind":"bearing_range","z":[[NaN,1.0]]}',
         {"seq": 1}, "non-finite"),
        (b'{"v":1,"run":"runA","frame":3,"stamp_ns":0,"sensor":"s","kind":"bearing_range","z":[[1e999,1.0]]}',
         {"seq": 1}, ""),
        (b'{"v":3,"run":"runA","frame":3,"stamp_ns":0,"sensor":"s","kind":"bearing_range","z":[]}',
         {"seq": 1}, "unsupported schema version"),
        (b'{"v":1,"run":"runA","frame":3,"stamp_ns":0,"sensor":"s","kind":"bearing_range","z":[[0.1]]}',
         {"seq": 1}, "$.z"),
        (b'{"v":1,"run":"runA","frame":3,"stamp_ns":0,"sensor":"s","kind":"bearing_range","z":[],"x":1}',
         {"seq": 1}, "x"),
        (None, {"seq": 1}, "run 'runB' is not this run"),
        (None, None, "missing attachment"),
        (None, {"seq": -1}, "seq must be an integer"),
        (None, {"seq": "7"}, "seq must be an integer"),
        (None, {"seq": 1, "frame": 4}, "attachment frame"),
        (b"x" * 5000, {"seq": 1}, "exceeds the limit"),
    ],
)
def test_intake_rejects_bad_samples_with_counter_and_deadletter(payload, meta, needle):
    intake, bus, c = _intake()
    if payload is None:
        payload = encode(_frame(), "runB" if "runB" in needle else "runA")
    assert intake.check(_ev(payload, meta)) is None
    assert c.rejected == 1 and intake.rejected_by_topic == {"measurements": 1}
    [(topic, letter, _)] = bus.published
    assert topic == "deadletter"
    doc = json.loads(letter)
    assert doc["topic"] == "measurements" and doc["stage"] == "tracker" and needle in doc["reason"]
    assert doc["size"] == len(payload)


def test_intake_rejects_an_invalid_attachment():
    intake, bus, c = _intake()
    assert intake.check(_ev(encode(_frame(), "runA"), None, err="attachment is not a JSON object")) is None
    assert "attachment" in json.loads(bus.published[0][1])["reason"]


# --------------------------------------------------------------------------- config


def test_pipeline_config_defaults_overrides_and_errors(tmp_path):
    cfg = default_pipeline()
    assert cfg.source.kind == "synthetic" and cfg.tracker.tracker == "ddp" and cfg.zenoh.embedded_router
    cfg2 = load_pipeline(None, ["source.frames=20", "tracker.tracker='dpyp'", "delivery.window=8"])
    assert (cfg2.source.frames, cfg2.tracker.tracker, cfg2.delivery.window) == (20, "dpyp", 8)
    f = tmp_path / "p.toml"
    f.write_text('run = "abc"\n[source]\nscenario = "dpy5"\nframes = 5\n[zenoh]\nconnect = ["tcp/127.0.0.1:7447"]\n')
    cfg3 = load_pipeline(f)
    assert cfg3.run == "abc" and cfg3.source.scenario == "dpy5" and cfg3.zenoh.connect == ["tcp/127.0.0.1:7447"]
    with pytest.raises(ConfigError, match="nope"):
        load_pipeline(None, ["source.nope=1"])
    with pytest.raises(ConfigError, match="run id"):
        load_pipeline(None, ["run='a/b'"])
    f.write_text("[source]\nframes = -1\n")
    with pytest.raises(ConfigError, match="frames"):
        load_pipeline(f)
    r = resolve_run(cfg2)
    assert r.run.startswith("vo2017-") and r.out == str(Path("recordings") / r.run)


def test_tls_file_fields_are_the_file_fields_of_tls_config():
    from bnptrack.pipeline.config import TLS_FILE_FIELDS, TlsConfig, ZenohConfig

    assert TLS_FILE_FIELDS == tuple(f for f in TlsConfig.__struct_fields__ if f not in ("mtls", "verify_name_on_connect"))
    tls = TlsConfig(root_ca_certificate="ca.pem", connect_private_key="k.pem")
    assert tls.files() == {"root_ca_certificate": "ca.pem", "connect_private_key": "k.pem"}
    assert ZenohConfig(tls=tls).secured and ZenohConfig(tls=TlsConfig(mtls=True)).secured
    assert not ZenohConfig().secured and not TlsConfig().files()


def test_write_atomic_replaces(tmp_path):
    p = tmp_path / "x.bin"
    write_atomic(p, b"one")
    write_atomic(p, b"two")
    assert p.read_bytes() == b"two" and [x.name for x in tmp_path.iterdir()] == ["x.bin"]


def test_background_writer_closes_sync_first_when_submit_raises(tmp_path):
    """A pending write error is raised by the next submit; the descriptors handed to that
    submit (the writer owns them) are closed all the same."""
    import os

    from bnptrack.pipeline.stages import BackgroundWriter

    w = BackgroundWriter()
    w.submit(tmp_path / "missing-dir" / "x.snap", b"data")  # fails on the writer thread
    wait_until(lambda: w._error is not None, 10, "the writer thread's error")
    fd = os.open(tmp_path / "journal", os.O_WRONLY | os.O_CREAT)
    with pytest.raises(OSError):
        w.submit(tmp_path / "x.snap", b"data", (fd,))
    with pytest.raises(OSError):
        os.fstat(fd)  # closed
    w.submit(tmp_path / "x.snap", b"data")  # the error was reported once
    w.flush()
    assert (tmp_path / "x.snap").read_bytes() == b"data"


# --------------------------------------------------------------------------- in-memory pipeline


def test_memory_pipeline_equals_offline(tmp_path):
    cfg = _mem_cfg(tmp_path)
    codes = _run_memory_pipeline(cfg, MemoryNetwork())
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    log = read_log(Path(cfg.out) / "tracks.mcap")
    frames, ests = _offline(cfg)
    assert [f.frame for f in log.frames] == [f.frame for f in frames]
    assert all(np.array_equal(a.z, b.z) for a, b in zip(log.frames, frames))
    assert all(np.array_equal(a.truth.states, b.truth.states) for a, b in zip(log.frames, frames))
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]
    assert log.metadata["tracker"] == "ddp-mb" and log.metadata["run"] == "mem"
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert summary["complete"] and summary["frames_written"] == 12
    snap = read_snapshot(Path(cfg.out) / "tracker.snap")
    assert snap.last_seq == 11 and snap.run == "mem"
    _assert_scores_equal_offline(summary["scores"], frames, ests)
    assert summary["view"] == ""  # sink.rerun = false: no recording to open


def _assert_scores_equal_offline(scores: dict, frames, ests) -> None:
    """sink.json's scores are the means `bnptrack track` would give (OSPA, cardinality
    error: pipeline.offline.frame_metrics; OSPA(2): sinks.metrics.ospa2_series)."""
    from bnptrack.pipeline.offline import frame_metrics
    from bnptrack.sinks.metrics import ospa2_series

    fm = [frame_metrics(f, e) for f, e in zip(frames, ests)]
    o2 = ospa2_series([dict(zip(e.labels, e.positions)) for e in ests],
                      [dict(zip(f.truth.ids, f.truth.positions)) for f in frames], window=10)
    assert scores["frames"] == scores["frames_scored"] == len(frames)
    assert scores["ospa"] == pytest.approx(np.mean([m.ospa for m in fm]), rel=1e-12)
    assert scores["last_ospa"] == pytest.approx(fm[-1].ospa, rel=1e-12)
    assert scores["cardinality_error"] == pytest.approx(np.mean([m.cardinality_error for m in fm]))
    assert scores["ospa2"] == pytest.approx(float(np.mean(o2)), rel=1e-9)
    assert scores["tracks"] == len(ests[-1].tracks)
    assert scores["labels"] == len({lab for e in ests for lab in e.labels})


def test_memory_pipeline_survives_duplicates_reordering_and_garbage(tmp_path):
    """Duplicated, locally reordered and interleaved malformed samples: same output."""
    cfg = _mem_cfg(tmp_path, frames=12)
    net = MemoryNetwork()
    held: dict[str, list] = {}
    rng = random.Random(3)

    def tap(run, topic, payload, att):
        if topic not in ("measurements", "truth", "tracks"):
            return [(payload, att)]
        out = []
        if rng.random() < 0.3:
            out.append((b'{"v":1,"frame":"garbage"', att))
        if rng.random() < 0.3:
            bad = payload.replace(b'"z":[[', b'"z":[[NaN,1.0],[', 1) if topic == "measurements" else b"[]"
            out.append((bad, att))
        held.setdefault(topic, []).append((payload, att))
        if len(held[topic]) >= 3 or json.loads(att or b"{}").get("seq", 0) >= 11 or topic == "tracks":
            batch = held.pop(topic)
            rng.shuffle(batch)  # reordered within 3 (< window)
            out += batch + batch[:1]  # plus a duplicate
        return out

    net.tap = tap
    codes = _run_memory_pipeline(cfg, net)
    assert codes["sink"] == EXIT_OK and codes["tracker"] == EXIT_OK
    log = read_log(Path(cfg.out) / "tracks.mcap")
    _, ests = _offline(cfg)
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert summary["counters"]["rejected"] > 0 and summary["counters"]["duplicates"] > 0
    assert summary["gaps"] == {"measurements": [], "truth": [], "tracks": []}
    letters = ListSink(net).docs("deadletter")
    assert letters and {d["stage"] for d in letters} <= {"tracker", "sink"}


def test_memory_pipeline_reports_a_lost_frame_as_gap_and_predicts_through(tmp_path):
    """A frame lost for good: the tracker and the sink report a gap after the window, and the
    tracks equal an offline run without that frame (the tracker predicts through it)."""
    cfg = _mem_cfg(tmp_path, frames=14, **{"delivery.window": "3"})
    net = MemoryNetwork()
    net.tap = drop_seq([5])
    # the memory network keeps history for late subscribers; drop seq 5 there as well
    codes = _run_memory_pipeline(cfg, net)
    assert codes["sink"] == EXIT_OK
    log = read_log(Path(cfg.out) / "tracks.mcap")
    frames, ests = _offline(cfg, drop=frozenset({5}))
    assert [f.frame for f in log.frames] == [f.frame for f in frames]
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert summary["gaps"]["measurements"] == [5] and summary["gaps"]["tracks"] == [5]
    eos = ListSink(net).docs("eos/tracker", msgspec.json.decode)
    assert eos and eos[-1]["gaps"] == [5]


def test_memory_pipeline_missing_tail_becomes_gap_at_end_of_stream(tmp_path):
    cfg = _mem_cfg(tmp_path, frames=8)
    net = MemoryNetwork()
    net.tap = drop_seq([7])
    _run_memory_pipeline(cfg, net)
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert summary["complete"] and summary["gaps"]["measurements"] == [7]
    assert summary["frames_written"] == 7 and summary["tracks_written"] == 7


def test_sink_drops_a_truth_of_another_frame_like_mismatched_tracks(tmp_path):
    """A /truth sample whose frame (valid, consistent with its attachment) is not the frame
    of the /measurements of the same seq is dropped, logged and counted, the way a /tracks
    mismatch is: the frame is written without truth."""
    cfg = _mem_cfg(tmp_path, frames=8)
    net = MemoryNetwork()
    truths: dict[int, tuple[bytes, dict]] = {}

    def tap(run, topic, payload, att):
        if topic == "truth" and att:
            meta = json.loads(att)
            truths[meta["seq"]] = (payload, meta)
            if meta["seq"] == 4:  # the truth of seq 3 (frame and attachment agree) as seq 4
                old_payload, old_meta = truths[3]
                return [(old_payload, json.dumps({**meta, "frame": old_meta["frame"]}).encode())]
        return [(payload, att)]

    net.tap = tap
    codes = _run_memory_pipeline(cfg, net)
    assert codes["sink"] == EXIT_OK
    log = read_log(Path(cfg.out) / "tracks.mcap")
    frames, ests = _offline(cfg)
    assert [f.frame for f in log.frames] == [f.frame for f in frames]
    assert log.frames[4].truth is None
    assert all(np.array_equal(a.truth.states, b.truth.states)
               for i, (a, b) in enumerate(zip(log.frames, frames)) if i != 4)
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert summary["complete"] and summary["frames_written"] == 8 and summary["tracks_written"] == 8
    assert summary["counters"]["rejected"] == 1 and summary["gaps"]["truth"] == []
    from bnptrack.tracker.messages import TOPIC_TRUTH
    from bnptrack.sources.mcap_log import _Scanner

    truth_frames = [m.frame for _, m in _Scanner(Path(cfg.out) / "tracks.mcap", {TOPIC_TRUTH})]
    assert truth_frames == [f.frame for i, f in enumerate(frames) if i != 4]  # no stray truth of frame 3


def test_tracker_resumes_from_snapshot_without_loss_or_duplicate(tmp_path):
    """A tracker stopped mid-run and started again resumes from tracker.snap: together the
    two runs publish every frame's tracks, equal to an uninterrupted run."""
    cfg = _mem_cfg(tmp_path, frames=16, **{"source.done_by": "['tracker']",
                                           "source.wait_for": "['tracker']",
                                           "tracker.done_by": "[]"})
    net = MemoryNetwork()
    first_stop = threading.Event()
    published = []

    second: list[int] = []  # what the restarted tracker publishes

    def tap(run, topic, payload, att):
        if topic == "tracks":
            published.append(json.loads(att)["seq"])
            if first_done.is_set():
                second.append(published[-1])
            if len(published) == 7:
                first_stop.set()  # stop the first tracker after 7 frames (snapshot at 4)
        return [(payload, att)]

    first_done = threading.Event()

    net.tap = tap
    src_bus = net.bus(cfg.run, "source")
    src = threading.Thread(target=lambda: STAGES["source"](StageContext(cfg, src_bus, name="source")).run(),
                           daemon=True)
    bus1 = net.bus(cfg.run, "tracker")
    t1 = threading.Thread(target=lambda: STAGES["tracker"](StageContext(cfg, bus1, first_stop, "tracker")).run(),
                          daemon=True)
    t1.start()
    src.start()
    t1.join(60)
    bus1.close()
    assert not t1.is_alive()
    snap = read_snapshot(Path(cfg.out) / "tracker.snap")
    assert snap.last_seq >= 3
    first_done.set()
    bus2 = net.bus(cfg.run, "tracker")
    code = STAGES["tracker"](StageContext(cfg, bus2, name="tracker")).run()
    bus2.close()
    src.join(30)
    src_bus.close()
    assert code == EXIT_OK
    assert sorted(set(published)) == list(range(16))
    # the restarted tracker published the journal up to its snapshot first, then the rest:
    # its own cache holds the whole run (a consumer that joins later gets every frame)
    assert second[: snap.last_seq + 1] == list(range(snap.last_seq + 1))
    assert sorted(set(second)) == list(range(16))
    last = {}
    for (r, t, p, a) in net.history:
        if t == "tracks":
            seq = json.loads(a)["seq"]
            from bnptrack.tracker.messages import TOPIC_TRACKS, decode, to_estimate

            est = to_estimate(decode(TOPIC_TRACKS, p))
            if seq in last:
                assert _strip(last[seq]) == _strip(est)  # re-published frames are identical
            last[seq] = est
    _, ests = _offline(cfg)
    assert [_strip(last[s]) for s in range(16)] == [_strip(e) for e in ests]


def test_tracker_refuses_a_snapshot_of_another_run(tmp_path):
    cfg = _mem_cfg(tmp_path, frames=4)
    out = Path(cfg.out)
    out.mkdir(parents=True)
    from bnptrack.pipeline.stages import Snapshot

    write_atomic(out / "tracker.snap", msgspec.msgpack.encode(
        Snapshot(run="other", tracker="ddp", seed=0, last_seq=1, last_frame=2, state=b"")))
    bus = MemoryNetwork().bus(cfg.run, "tracker")
    with pytest.raises(ConfigError, match="does not match"):
        STAGES["tracker"](StageContext(cfg, bus, name="tracker")).run()


# --------------------------------------------------------------------------- docs and CLI


def test_docs_pipeline_file_example_is_the_default():
    """The annotated pipeline file in docs/pipeline.md parses and equals the defaults."""
    import re
    import tomllib

    text = (REPO_ROOT / "docs" / "pipeline.md").read_text()
    blocks = [b for b in re.findall(r"```toml\n(.*?)```", text, re.S) if "[supervisor]" in b]
    assert len(blocks) == 1
    cfg = msgspec.convert(tomllib.loads(blocks[0]), PipelineConfig)
    assert cfg == default_pipeline()


def test_pipeline_commands_have_help():
    from click.testing import CliRunner

    from bnptrack.pipeline.cli import main

    for cmd, words in [
        ("launch", ["PIPELINE.toml", "--set", "--out", "--run", "--connect", "--timeout", "Example"]),
        ("replay", ["LOG", "--rate", "--as-fast-as-possible", "--tracker", "--seed", "--out"]),
        ("stage", ["source|tracker|sink", "--run", "--connect", "--pipeline", "--out", "Example"]),
        ("router", ["--listen", "--pipeline"]),
        ("monitor", ["--run", "--connect"]),
    ]:
        res = CliRunner().invoke(main, [cmd, "--help"])
        assert res.exit_code == 0, res.output
        for w in words:
            assert w in res.output, (cmd, w)


def test_acl_config_gives_each_stage_only_its_keys():
    from bnptrack.pipeline.acl import acl_config

    acl = acl_config()
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert "bnptrack/*/measurements" in rules["publish-source"]["key_exprs"]
    assert "bnptrack/*/measurements/@adv/**" in rules["publish-source"]["key_exprs"]
    assert not any("measurements" in k or "tracks" in k for k in rules["publish-sink"]["key_exprs"])
    assert rules["publish-tracker"]["flows"] == ["ingress"]
    subjects = {s["id"]: s.get("usernames") for s in acl["subjects"]}
    assert subjects["user-tracker"] == ["tracker"]


def _registry_trackers():
    """Every registered tracker; the fast subset runs ``ddp`` (the default) and ``glmb`` (the
    other family), the others are marked slow (a pipeline run each)."""
    from bnptrack.tracker.registry import TRACKERS

    return [name if name in ("ddp", "glmb") else pytest.param(name, marks=pytest.mark.slow) for name in TRACKERS]


@pytest.mark.parametrize("name", _registry_trackers())
def test_every_registered_tracker_runs_in_the_pipeline(tmp_path, name):
    """The tracker stage takes whatever pipeline.resolve.tracker_setup builds (with its
    snapshot/restore), so a tracker added to the registry works in the pipeline unchanged."""
    from bnptrack.tracker.state import restore

    cfg = resolve_run(apply_overrides(
        PipelineConfig(run="reg", out=str(tmp_path / "out")),
        ["source.frames=8", "sink.rerun=false", "tracker.snapshot_every=3", f"tracker.tracker='{name}'",
         "delivery.eos_grace_s=0.3", "supervisor.linger_s=0.5"]))
    codes = _run_memory_pipeline(cfg, MemoryNetwork())
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    log = read_log(Path(cfg.out) / "tracks.mcap")
    _, ests = _offline(cfg)
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]
    from bnptrack.pipeline.resolve import tracker_setup

    tracker = tracker_setup(name, metadata=log.metadata).tracker
    snap = read_snapshot(Path(cfg.out) / "tracker.snap")
    state = restore(snap.state, type(tracker.initial_state()))
    assert snap.last_seq == 7 and snap.tracker == name and state is not None


# --------------------------------------------------------------------------- journal


def _journal_records(n: int, start: int = 0) -> list[tuple[int, bytes, dict]]:
    return [(s, f'{{"frame": {s + 1}}}'.encode() * (s % 3 + 1), {"seq": s, "t": 1000 + s}) for s in range(start, n)]


def _write_journal(path: Path, n: int) -> None:
    from bnptrack.pipeline.journal import TracksJournal

    j = TracksJournal(path, keep=100)
    j.start()
    for rec in _journal_records(n):
        j.append(*rec)
    j.close()


def test_journal_round_trip_and_resume_cuts_back_to_the_snapshot(tmp_path):
    from bnptrack.pipeline.journal import TracksJournal, read_journal

    path = tmp_path / "tracker.journal"
    _write_journal(path, 10)
    assert [(r.seq, r.payload, r.meta) for r in read_journal(path)] == _journal_records(10)
    j = TracksJournal(path, keep=100)
    assert j.resume(5) == _journal_records(6)  # the snapshot covers seq 0..5
    for rec in _journal_records(9, start=6):  # recomputed after the restart
        j.append(*rec)
    j.close()
    assert [(r.seq, r.payload, r.meta) for r in read_journal(path)] == _journal_records(9)
    assert TracksJournal(tmp_path / "none.journal", keep=5).resume(3) == []


def test_journal_reads_the_prefix_of_a_torn_or_damaged_file(tmp_path):
    from bnptrack.pipeline.journal import TracksJournal, read_journal

    path = tmp_path / "tracker.journal"
    _write_journal(path, 6)
    data = path.read_bytes()
    ends = [r.end for r in read_journal(path)]
    path.write_bytes(data[: ends[3] + 5])  # killed in the middle of writing record 4
    assert [r.seq for r in read_journal(path)] == [0, 1, 2, 3]
    broken = bytearray(data)
    broken[ends[1] + 12] ^= 0xFF  # a flipped byte in record 2: its CRC fails
    path.write_bytes(bytes(broken))
    assert [r.seq for r in read_journal(path)] == [0, 1]
    assert TracksJournal(path, keep=100).resume(10) == _journal_records(2)
    assert path.stat().st_size == ends[1]  # the damaged tail is cut


def test_journal_keeps_the_newest_records_when_it_grows(tmp_path):
    from bnptrack.pipeline.journal import TracksJournal, read_journal

    path = tmp_path / "tracker.journal"
    j = TracksJournal(path, keep=4)
    j.start()
    for rec in _journal_records(9):  # compacted at the 9th record (> 2 x keep)
        j.append(*rec)
    assert len(j) == 4
    j.append(*_journal_records(10, start=9)[0])
    j.close()
    assert [r.seq for r in read_journal(path)] == [5, 6, 7, 8, 9]


def test_journal_compacts_right_after_a_resume(tmp_path):
    """The journal keeps each record's end offset itself (no tell() per record): after a
    resume that cut the file back, compaction must still cut exactly at record boundaries."""
    from bnptrack.pipeline.journal import TracksJournal, read_journal

    path = tmp_path / "tracker.journal"
    _write_journal(path, 6)
    j = TracksJournal(path, keep=3)
    assert j.resume(3) == _journal_records(4, start=1)  # the file keeps 0..3, resume returns the newest 3
    for rec in _journal_records(9, start=4):  # the 7th record (> 2 x keep) compacts to 4..6
        j.append(*rec)
    j.close()
    assert [(r.seq, r.payload, r.meta) for r in read_journal(path)] == _journal_records(9, start=4)


def test_journal_resume_returns_at_most_keep_records_the_newest(tmp_path):
    """The file may hold up to 2 x keep records, but no publisher cache holds more than
    ``keep``: resume returns (for publishing again) only the newest ``keep`` of the records
    the snapshot covers; the file itself is cut only after the snapshot."""
    from bnptrack.pipeline.journal import TracksJournal, read_journal

    path = tmp_path / "tracker.journal"
    _write_journal(path, 9)
    j = TracksJournal(path, keep=4)
    assert j.resume(7) == _journal_records(8, start=4)  # the snapshot covers 0..7
    assert len(j) == 8
    j.close()
    assert [r.seq for r in read_journal(path)] == list(range(8))
    assert TracksJournal(path, keep=10).resume(7) == _journal_records(8)  # fewer than keep: all


def test_journal_append_when_not_open_raises_and_keeps_the_file(tmp_path):
    from bnptrack.pipeline.journal import TracksJournal, read_journal

    path = tmp_path / "tracker.journal"
    _write_journal(path, 3)
    rec = _journal_records(4, start=3)[0]
    with pytest.raises(RuntimeError, match="not open"):
        TracksJournal(path, keep=100).append(*rec)  # neither start() nor resume()
    j = TracksJournal(path, keep=100)
    j.resume(2)
    j.close()
    with pytest.raises(RuntimeError, match="not open"):
        j.append(*rec)  # after close
    assert [(r.seq, r.payload, r.meta) for r in read_journal(path)] == _journal_records(3)


def test_sequencer_catching_up_keeps_history_that_arrives_after_live_frames():
    """A restarted consumer gets live frames (here 40..44) before the history (0..39): until
    it has caught up, the window is the cache size, so nothing becomes a gap; afterwards the
    normal window applies again."""
    q = Sequencer(window=4, catch_up=100)
    released = []
    for s in [40, 41, 42, *range(40), 43, 44]:
        status, out = q.push(s, f"f{s}")
        assert status == "accepted"
        released += out
    assert [s for s, _ in released] == list(range(45)) and not q.gaps and q.caught_up
    status, out = q.push(50, "f50")  # caught up: a frame 4 or more ahead declares the hole
    assert [s for s, item in out] == [45, 46] and q.gaps == [45, 46]
    plain = Sequencer(window=4)  # without catch-up the live frames push the history out
    for s in [40, 41, 42, 0]:
        plain.push(s, s)
    assert plain.gaps[:3] == [0, 1, 2]


def test_memory_pipeline_with_a_generated_random_source(tmp_path):
    """A synthetic source of the generated ``random`` scenario: the scene comes from
    source.seed and the scene.* items of source.overrides; the tracker gets no birth regions."""
    from bnptrack.pipeline.offline import parse_crossings
    from bnptrack.pipeline.resolve import resolve_params
    from bnptrack.sources.scenarios import get_scenario

    cfg = _mem_cfg(tmp_path, frames=8, **{"source.scenario": '"random"', "source.seed": "3",
                                          "source.overrides": "['scene.n_objects=22']"})
    codes = _run_memory_pipeline(cfg, MemoryNetwork())
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    log = read_log(Path(cfg.out) / "tracks.mcap")
    sc = get_scenario("random", 3, ("n_objects=22",))
    assert log.metadata["scene_seed"] == "3" and log.metadata["scene"] == "n_objects=22"
    assert parse_crossings(log.metadata["crossings"]) == sc.crossings
    assert resolve_params(None, log.metadata).params.birth == []
    assert [len(f.truth.ids) for f in log.frames] == sc.cardinality()[:8].tolist()
    frames, ests = _offline(cfg)
    assert all(np.array_equal(a.z, b.z) for a, b in zip(log.frames, frames, strict=True))
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]


# --------------------------------------------------------------------------- replay window


def _frames_at(stamps_s: list[float], first: int = 1) -> list[Frame]:
    return [Frame(first + i, int(t * 1e9), "s", "bearing_range", np.zeros((0, 2))) for i, t in enumerate(stamps_s)]


def test_window_frames_in_seconds_of_log_time_and_in_frames():
    from bnptrack.pipeline.config import SourceConfig
    from bnptrack.pipeline.stages import window_frames

    frames = _frames_at([5.0, 6.0, 7.5, 9.0, 10.0, 12.0])  # log time 0, 1, 2.5, 4, 5, 7 s

    def keep(**kw):
        return [f.frame for f in window_frames(iter(frames), SourceConfig(**kw))]

    assert keep() == [1, 2, 3, 4, 5, 6]
    assert keep(start_s=1.0, end_s=5.0) == [2, 3, 4, 5]  # both ends included
    assert keep(start_s=2.6) == [4, 5, 6] and keep(end_s=0.0) == [1]
    assert keep(start_frame=3, end_frame=4) == [3, 4]
    assert keep(start_frame=2, end_s=2.5) == [2, 3]  # seconds at one end, frames at the other
    # the input is not read past the end
    it = iter(frames)
    assert [f.frame for f in window_frames(it, SourceConfig(end_frame=2))] == [1, 2]
    assert next(it).frame == 4  # frame 3 was read (to see that it is past the end), no more
    for bad, msg in (({"start_s": 1.0, "start_frame": 2}, "in seconds or in frames, not both"),
                     ({"start_s": 3.0, "end_s": 2.0}, "is before source.start_s"),
                     ({"start_frame": 5, "end_frame": 4}, "is before source.start_frame")):
        with pytest.raises(ConfigError, match=msg):
            window_frames(iter(frames), SourceConfig(**bad))


def test_memory_pipeline_replays_a_window_of_the_source(tmp_path):
    """start_frame / end_s select frames 4..9 of the simulation (vo2017: frame k at k s, log
    time k - 1): the recording holds those frames and the tracks `track` gives on them."""
    cfg = _mem_cfg(tmp_path, frames=0, **{"source.start_frame": "4", "source.end_s": "8.0",
                                          "sink.score": "false"})
    codes = _run_memory_pipeline(cfg, MemoryNetwork())
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    log = read_log(Path(cfg.out) / "tracks.mcap")
    frames, ests = _offline(cfg)
    assert [f.frame for f in log.frames] == [f.frame for f in frames] == [4, 5, 6, 7, 8, 9]
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]
    # sink.score = false: frames and tracks counted, nothing scored
    scores = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())["scores"]
    assert scores["frames"] == 6 and scores["frames_scored"] == 0 and scores["ospa"] is None
    assert scores["tracks"] == len(ests[-1].tracks)


def test_memory_pipeline_keeps_the_prior_of_an_earlier_run_only_if_asked(tmp_path):
    """tracker.prior_from (replay --loop --keep-prior): the second run starts with no track
    but with the first run's alpha, d and (alpha, d) likelihood; its tracks are those of the
    offline tracker started from that state; without it, those of a fresh tracker."""
    from bnptrack.pipeline.stages import PRIOR_FIELDS, keep_prior
    from bnptrack.tracker.state import run

    first = _mem_cfg(tmp_path / "a", frames=8)
    assert _run_memory_pipeline(first, MemoryNetwork())["tracker"] == EXIT_OK
    snap_path = Path(first.out) / "tracker.snap"
    snap = read_snapshot(snap_path)
    frames, _ = _offline(first)
    second = msgspec.structs.replace(first, run="mem2", out=str(tmp_path / "b"),
                                     tracker=msgspec.structs.replace(first.tracker, prior_from=str(snap_path)))
    assert _run_memory_pipeline(second, MemoryNetwork())["tracker"] == EXIT_OK
    got = read_log(Path(second.out) / "tracks.mcap").tracks

    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.pipeline.stages import source_frames

    meta, _ = source_frames(first)
    tracker = tracker_setup("ddp-mb", overrides=first.tracker.overrides, metadata=meta).tracker
    offline_first = list(run(tracker, frames, 0))
    final = offline_first[-1][2]
    start = keep_prior(tracker.initial_state(), snap, "ddp-mb")
    assert start.n_clusters == 0 and start.frame == -1
    for f in PRIOR_FIELDS:
        assert np.array_equal(getattr(start, f), getattr(final, f))  # the snapshot is the final state
    want = [est for _, est, _ in run(tracker, frames, 0, state=start)]
    assert [_strip(e) for e in got] == [_strip(e) for e in want]
    fresh = [est for _, est, _ in offline_first]
    assert [_strip(e) for e in got] != [_strip(e) for e in fresh]  # the prior changed the run
    with pytest.raises(ConfigError, match="not 'dpyp'"):
        keep_prior(tracker.initial_state(), snap, "dpyp")


# --------------------------------------------------------------------------- injectable clock


def test_hole_watch_is_due_after_its_delay_on_the_injected_clock():
    from bnptrack.pipeline.stages import HoleWatch

    clock = ManualClock()
    seqr = Sequencer(4)
    seqr.push(1, "b")  # seq 0 missing, seq 1 waits in the buffer
    watch = HoleWatch(1.0, clock.monotonic)
    assert not watch.due(seqr)  # the first look starts the delay
    clock.advance(0.5)
    assert not watch.due(seqr)
    clock.advance(0.5)
    assert watch.due(seqr)
    assert not watch.due(seqr)  # then again only after another delay
    clock.advance(1.0)
    assert watch.due(seqr)
    seqr.push(0, "a")  # nothing missing any more
    clock.advance(5.0)
    assert not watch.due(seqr)


def test_source_paces_its_frames_on_the_injected_clock(tmp_path):
    """source.rate = 2: frame k is published (log time of k - log time of frame 0) / 2 after
    the start, on the stage's clock: a manual clock ends exactly there, without waiting."""
    from bnptrack.pipeline.stages import source_frames

    cfg = _mem_cfg(tmp_path, frames=6, **{"source.rate": "2.0", "source.done_by": "[]", "source.wait_for": "[]"})
    clock = ManualClock(start_ns=10**18)
    net = MemoryNetwork()
    bus = net.bus(cfg.run, "source")
    try:
        assert STAGES["source"](StageContext(cfg, bus, name="source", clock=clock)).run() == EXIT_OK
    finally:
        bus.close()
    stamps = [f.stamp_ns for f in source_frames(cfg)[1]]
    assert len(stamps) == 6
    assert clock.monotonic() == pytest.approx((stamps[-1] - stamps[0]) / 1e9 / 2.0, abs=1e-9)
    sent = [json.loads(a)["t"] for _, a in ListSink(net).samples("measurements")]
    assert sent == [10**18 + round((s - stamps[0]) / 2.0) for s in stamps]


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_warm_up_imports_only_the_configured_tracker_through_the_registry():
    """The tracker stage warms up the tracker it runs (its registry entry), not a fixed one:
    warming glmb does not import the BNP tracker, warming ddp does."""
    import subprocess
    import sys

    code = ("import sys; from bnptrack.pipeline.stages.tracker_warmup import warm_tracker_imports; "
            "warm_tracker_imports(sys.argv[1]); print(int('bnptrack.tracker.bnp' in sys.modules), "
            "int('bnptrack.tracker.glmb' in sys.modules))")
    root = REPO_ROOT
    seen = {name: subprocess.run([sys.executable, "-c", code, name], capture_output=True, text=True,
                                 cwd=root, env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"},
                                 check=True).stdout.split()
            for name in ("glmb", "ddp")}
    assert seen == {"glmb": ["0", "1"], "ddp": ["1", "0"]}
