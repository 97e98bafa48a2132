"""The tracker stage with ``tracker.lag = N`` (``replay`` / ``launch --lag N``) on the in-memory
bus: each frame's fixed-lag tracks under its own sequence number, equal to ``bnptrack track
--lag N``; a stage stopped mid-run and started again resumes with its window (snapshot and
journal), publishing what an uninterrupted run publishes."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import msgspec
import pytest

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, STAGES, StageContext, read_snapshot, write_atomic
from bnptrack.sources.mcap_log import read_log
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.lag import FixedLag, run_lagged
from bnptrack.tracker.messages import TOPIC_TRACKS, decode, to_estimate

from testkit import mem_cfg, run_memory_pipeline, strip


def _offline_lagged(cfg, lag: int):
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.pipeline.stages import source_frames

    meta, frames = source_frames(cfg)
    tracker = tracker_setup(cfg.tracker.tracker, overrides=cfg.tracker.overrides, metadata=meta).tracker
    return [e for _f, e, _s in run_lagged(FixedLag(tracker, tracker.params, lag), frames, cfg.tracker.seed)]


def test_a_lagged_stage_records_what_track_lag_gives(tmp_path):
    cfg = mem_cfg(tmp_path, frames=12, **{"tracker.lag": "2"})
    codes = run_memory_pipeline(cfg, MemoryNetwork())
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    log = read_log(Path(cfg.out) / "tracks.mcap")
    expected = _offline_lagged(cfg, 2)
    assert len(log.tracks) == 12 and all(e.lag == 2 for e in log.tracks)
    assert [strip(e) for e in log.tracks] == [strip(e) for e in expected]
    snap = read_snapshot(Path(cfg.out) / "tracker.snap")
    assert snap.lag == 2 and snap.last_seq == 11 and snap.published_seq == 11  # the window was flushed


def test_a_lagged_stage_stopped_and_restarted_publishes_the_uninterrupted_run(tmp_path):
    cfg = mem_cfg(tmp_path, frames=16, **{"tracker.lag": "3", "source.done_by": "['tracker']",
                                          "source.wait_for": "['tracker']", "tracker.done_by": "[]"})
    net = MemoryNetwork()
    first_stop, first_done = threading.Event(), threading.Event()
    published: list[int] = []
    second: list[int] = []

    def tap(run, topic, payload, att):
        if topic == "tracks":
            published.append(json.loads(att)["seq"])
            if first_done.is_set():
                second.append(published[-1])
            if len(published) == 6:
                first_stop.set()  # after 6 published (9 tracked; snapshot every 4)
        return [(payload, att)]

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
    # stopped with frames in its window: the snapshot holds them, the journal what was published
    assert snap.lag == 3 and snap.published_seq == snap.last_seq - 3 >= 3
    first_done.set()
    bus2 = net.bus(cfg.run, "tracker")
    code = STAGES["tracker"](StageContext(cfg, bus2, name="tracker")).run()
    bus2.close()
    src.join(30)
    src_bus.close()
    assert code == EXIT_OK
    assert second[: snap.published_seq + 1] == list(range(snap.published_seq + 1))  # the journal again
    assert sorted(set(second)) == list(range(16))
    last = {}
    for (_r, t, p, a) in net.history:
        if t == "tracks":
            seq = json.loads(a)["seq"]
            est = to_estimate(decode(TOPIC_TRACKS, p))
            if seq in last:
                assert strip(last[seq]) == strip(est)  # re-published frames are identical
            last[seq] = est
    expected = _offline_lagged(cfg, 3)
    assert [strip(last[s]) for s in range(16)] == [strip(e) for e in expected]
    assert all(last[s].lag == 3 for s in range(16))


def test_a_stage_refuses_a_snapshot_of_another_lag(tmp_path):
    cfg = mem_cfg(tmp_path, frames=4, **{"tracker.lag": "1"})
    out = Path(cfg.out)
    out.mkdir(parents=True)
    from bnptrack.pipeline.stages import Snapshot

    write_atomic(out / "tracker.snap", msgspec.msgpack.encode(
        Snapshot(run="mem", tracker="ddp-mb", seed=0, last_seq=1, last_frame=2, state=b"")))
    bus = MemoryNetwork().bus(cfg.run, "tracker")
    with pytest.raises(ConfigError, match="lag 0 does not match.*lag 1"):
        STAGES["tracker"](StageContext(cfg, bus, name="tracker")).run()


def test_the_glmb_stage_takes_a_lag_too(tmp_path):
    cfg = mem_cfg(tmp_path, frames=8, **{"tracker.lag": "1", "tracker.tracker": "glmb", "tracker.overrides": "[]"})
    codes = run_memory_pipeline(cfg, MemoryNetwork())
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    log = read_log(Path(cfg.out) / "tracks.mcap")
    assert len(log.tracks) == 8 and all(e.lag == 1 for e in log.tracks)
    assert [strip(e) for e in log.tracks] == [strip(e) for e in _offline_lagged(cfg, 1)]
