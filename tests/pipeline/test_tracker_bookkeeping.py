"""The tracker stage's bookkeeping of a frame comes right after its /tracks put: the journal's
append, a due snapshot and the next frame's generator, all before the next frame is taken.  What
a snapshot covers is in the journal, and the journal holds every published sample, in order,
byte for byte."""

from __future__ import annotations

import pytest

from bnptrack.pipeline.config import DeliveryConfig, PipelineConfig, TrackerStageConfig, resolve_run
from bnptrack.pipeline.events import Event
from bnptrack.pipeline.journal import read_journal
from bnptrack.pipeline.membus import MemoryBus, MemoryNetwork
from bnptrack.pipeline.stages import StageContext, TrackerStage
from bnptrack.pipeline.stages.recovery import read_snapshot
from bnptrack.pipeline.stages.tracker import build_stage_tracker
from bnptrack.pipeline.stages.tracker_output import StageOutput
from bnptrack.sources.scenarios import get_scenario, scenario_params
from bnptrack.sources.synthetic import simulate
from bnptrack.tracker.messages import encode
from bnptrack.tracker.state import tracker_frame_rng

META = {"scenario": "vo2017", "params": "vo2017"}


@pytest.fixture(scope="module")
def frames():
    return list(simulate(get_scenario("vo2017"), scenario_params("vo2017", "vo2017"), 1))[:6]


def _stage(tmp_path, bus=None, snapshot_every=50):
    """A tracker stage with its ``ddp`` tracker built (no warm-up: not what is tested)."""
    cfg = resolve_run(PipelineConfig(run="r", out=str(tmp_path), delivery=DeliveryConfig(),
                                     tracker=TrackerStageConfig(tracker="ddp", seed=3,
                                                                snapshot_every=snapshot_every)))
    stage = TrackerStage(StageContext(cfg, bus or MemoryNetwork().bus("r", "tracker"), name="tracker"))
    stage._restore()
    setup = build_stage_tracker(stage.tc, META)
    stage.tracker = setup.tracker
    stage.output = StageOutput(setup.tracker, setup.params, 0)
    stage.state = stage.tracker.initial_state()
    return stage


def _event(frame, seq):
    return Event("measurements", encode(frame, "r"), {"seq": seq, "t": 1, "frame": frame.frame}, 2)


def _journal(stage):
    """The journal's records as the file holds them now (flushed, the journal left open)."""
    import os

    fd = stage.journal.dup_fd()
    os.close(fd)
    return read_journal(stage.journal.path)


def test_the_record_follows_the_publication_before_the_next_frame(tmp_path, frames):
    stage = _stage(tmp_path)
    for seq, frame in enumerate(frames[:3]):
        stage._on_data(_event(frame, seq))
        published = [(p, m) for t, p, m in stage.bus.published if t == "tracks"]
        assert len(published) == seq + 1
        # the frame's record is in the journal as soon as its tracks are out
        assert [(r.payload, r.meta) for r in _journal(stage)] == published
        k, rng = stage.next_rng  # and the next frame's generator is built
        assert k == frame.frame + 1
        assert rng.random(3).tolist() == tracker_frame_rng(3, k).random(3).tolist()
        assert stage.core.last_seq == seq and stage.counters.processed == seq + 1
    stage._close_journal()
    published = [(p, m) for t, p, m in stage.bus.published if t == "tracks"]
    assert [(r.payload, r.meta) for r in read_journal(stage.journal.path)] == published


def test_a_snapshot_covers_only_frames_already_in_the_journal(tmp_path, frames):
    stage = _stage(tmp_path, snapshot_every=3)
    for seq, frame in enumerate(frames[:4]):
        stage._on_data(_event(frame, seq))
    # frame seq 2 made the snapshot due: taken right after its record, fsynced with the journal
    stage.writer.flush()
    snap = read_snapshot(stage.snap_path)
    assert snap.last_seq == 2 and snap.counters["processed"] == 3
    assert [r.seq for r in read_journal(stage.journal.path)][:3] == [0, 1, 2]
    stage.snapshot(wait=True)
    assert read_snapshot(stage.snap_path).last_seq == 3
    assert [r.seq for r in read_journal(stage.journal.path)] == [0, 1, 2, 3]
    stage._close_journal()


class _RecordingBus(MemoryBus):
    """Records each ``recv`` timeout with the journal's length at that moment, never waits,
    and stops the stage once the queue is empty."""

    stage: TrackerStage

    def recv(self, timeout=None):
        self.calls.append((timeout, len(self.stage.journal)))
        ev = super().recv(0)
        if ev is None:
            self.stage.ctx.stop.set()
        return ev


def test_the_loop_journals_each_frame_before_it_takes_the_next(tmp_path, frames):
    net = MemoryNetwork()
    bus = _RecordingBus(net, "r", "tracker", 1000)
    bus.calls = []
    net.buses.append(bus)
    stage = _stage(tmp_path, bus=bus)
    bus.stage = stage
    bus.subscribe(["measurements"])
    src = net.bus("r", "source")
    for seq, frame in enumerate(frames[:3]):  # three frames queued at once
        src.publish("measurements", encode(frame, "r"), {"seq": seq, "t": 1, "frame": frame.frame})
    assert stage._loop() == 130  # stopped (EXIT_STOPPED)
    # each recv after a frame finds that frame's record written; the loop's poll is unchanged
    assert bus.calls == [(0.05, 0), (0.05, 1), (0.05, 2), (0.05, 3)]
    stage._close_journal()
    assert [r.seq for r in read_journal(stage.journal.path)] == [0, 1, 2]
