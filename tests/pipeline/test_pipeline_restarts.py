"""In memory (pipeline.membus): restarts at any moment leave complete, identical
outputs, and restarted consumers get the history (the stages over real Zenoh sessions:
tests/integration/test_pipeline_faults.py)."""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import msgspec

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.config import PipelineConfig
from bnptrack.pipeline.stages import (
    EXIT_OK,
    STAGES,
    SUMMARY_NAME,
    StageContext,
    commit_parts,
    part_path,
    read_snapshot,
)
from bnptrack.sources.mcap_log import read_log

from testkit import ListSink, drop_seq, mem_cfg
from testkit import run_memory_pipeline as _run_memory_pipeline


def _mem_cfg(tmp_path: Path, frames: int = 8) -> PipelineConfig:
    return mem_cfg(tmp_path, frames)


def _run_stage(cfg: PipelineConfig, net: MemoryNetwork, role: str) -> int:
    bus = net.bus(cfg.run, role)
    try:
        return STAGES[role](StageContext(cfg, bus, name=role)).run()
    finally:
        bus.close()


def _memory_run(cfg: PipelineConfig, net: MemoryNetwork) -> None:
    """The whole pipeline in threads on one manual clock (``testkit.run_memory_pipeline``)."""
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
    eos = ListSink(net).docs("eos/sink", msgspec.json.decode)
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
    eos = ListSink(net).docs("eos/tracker", msgspec.json.decode)
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
    """Frames 3-6 never arrive (neither live nor in the subscribers'
    history), but their publishers still hold them: the tracker and the sink fetch them
    explicitly, so there is no gap and the tracks equal the offline run of every frame."""
    from bnptrack.pipeline.stages import source_frames
    from bnptrack.tracker.state import run as run_offline
    from bnptrack.pipeline.resolve import tracker_setup

    cfg = _mem_cfg(tmp_path, frames=12)
    net = MemoryNetwork()
    net.fetchable = True
    net.tap = drop_seq([3, 4, 5, 6], topics=("measurements", "truth", "tracks"))
    _memory_run(cfg, net)
    s = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert s["gaps"] == {"measurements": [], "truth": [], "tracks": []} and not s["missing"]
    meta, frames = source_frames(cfg)
    tracker = tracker_setup("ddp-mb", overrides=cfg.tracker.overrides, metadata=meta).tracker
    ests = [e for _, e, _ in run_offline(tracker, list(frames), 0)]

    def strip(e):
        d = {k: v for k, v in e.diagnostics.items() if k != "ms"}
        return (e.frame, e.labels, e.assignments, d, [(t.state.tolist(), t.existence) for t in e.tracks])

    assert [strip(e) for e in read_log(Path(cfg.out) / "tracks.mcap").tracks] == [strip(e) for e in ests]


def test_sequencer_catch_up_holds_until_the_announced_live_head():
    """Sequencer(32, 0, catch_up=10000), push(0), push(5000): catch-up does not end when the
    buffer is empty once (that would declare 4,968 gaps and push(1) late).  With the publisher's live head announced (5000), catch-up holds until seq 5000 is
    released: nothing is declared missing and the history 1..4999 is accepted."""
    from bnptrack.pipeline.stages import GAP, Sequencer

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
