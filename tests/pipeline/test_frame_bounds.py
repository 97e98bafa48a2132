"""Bounds on what a valid-looking frame or sample can do: frame-number and
time-stamp jumps (tracker.types.FrameBounds), offline (`bnptrack track`) and in the pipeline
(tracker and sink stages over the in-memory bus), and sequence numbers far ahead of a
Sequencer's window."""

from __future__ import annotations

import dataclasses
import json
import tracemalloc
from pathlib import Path

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, SUMMARY_NAME, Sequencer
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.mcap_log import iter_tracks, read_log
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import FrameBoundError, FrameBounds, bounded_frames

from testkit import ListSink
from testkit import forge_seq as _forge_seq
from testkit import mem_cfg as _mem_cfg
from testkit import offline as _offline
from testkit import run_memory_pipeline as _run_memory_pipeline
from testkit import strip as _strip



# --------------------------------------------------------------------------- FrameBounds


def test_frame_bounds_reference_cases():
    b = FrameBounds(max_frame_gap=10, max_gap_s=5.0)
    s = 10**9
    assert b.violation(-1, None, 10**12, 0) is None  # the first frame is not bounded
    assert b.violation(3, 3 * s, 13, 8 * s) is None  # exactly 10 frames and 5 s: allowed
    assert b.violation(3, 3 * s, 14, 4 * s) == "frame 14 jumps 11 frames after frame 3 (more than max_frame_gap = 10)"
    assert b.violation(3, 3 * s, 4, 8 * s + 1) == "frame 4: time stamp 5 s after frame 3 (more than max_gap_s = 5)"
    assert b.violation(3, 3 * s, 4, 3 * s - 1) == (
        f"frame 4: time stamp {3 * s - 1} ns is before that of frame 3 ({3 * s} ns)")
    assert b.violation(3, 3 * s, 3, 3 * s) == "frame 3 is not after the last processed frame 3"
    assert b.violation(3, None, 4, 0) is None  # unknown previous stamp: frame numbers only
    assert FrameBounds() == FrameBounds(1000, 3600.0)
    with pytest.raises(ValueError):
        FrameBounds(0, 1.0)


def _frames(n=12):
    return simulate_all(get_scenario("vo2017"), load_params("vo2017"), 1)[:n]


def test_bounded_frames_stops_before_the_jump():
    frames = _frames()
    frames[7] = dataclasses.replace(frames[7], frame=10**9)
    got = []
    with pytest.raises(FrameBoundError, match=r"frame 1000000000 jumps 999999993 frames after frame 7 "):
        for f in bounded_frames(frames):
            got.append(f.frame)
    assert got == [1, 2, 3, 4, 5, 6, 7]


# --------------------------------------------------------------------------- offline


def test_track_skips_frames_jumping_10_9_and_exits_3_naming_them(tmp_path):
    frames = _frames(15)
    log = tmp_path / "jump.mcap"
    with McapLogWriter(log, {"scenario": "vo2017", "params": "vo2017", "seed": "1"}) as w:
        for f in frames[:10]:
            w.write_frame(f)
        for f in frames[10:]:
            w.write_frame(dataclasses.replace(f, frame=10**9 + f.frame))
    out = tmp_path / "out.mcap"
    track = ["track", str(log), "--out", str(out), "-q", "--tracker", "ddp-mb", "--set", "sweeps=8",
             "--set", "burn_in=2"]
    res = CliRunner().invoke(main, track)
    assert res.exit_code == 3  # five frames skipped (fewer than --resync-frames 10 in a row)
    assert res.stderr.splitlines() == [
        "Error: output incomplete: 5 frame(s) beyond the frame bounds skipped (frame 1000000011 jumps "
        "1000000001 frames after frame 10 (more than max_frame_gap = 1000); frame 1000000012 jumps 1000000002 "
        "frames after frame 10 (more than max_frame_gap = 1000); frame 1000000013 jumps 1000000003 frames after "
        f"frame 10 (more than max_frame_gap = 1000); ...) -- wrote the other 10 frame(s) to {out}"]
    written = read_log(out)
    assert [f.frame for f in written.frames] == list(range(1, 11)) and len(written.tracks) == 10
    # a jump of 1,501 frames: over the default bound, within --max-frame-gap 1501
    with McapLogWriter(log, {"scenario": "vo2017", "params": "vo2017", "seed": "1"}) as w:
        for f in frames[:12]:
            w.write_frame(f if f.frame <= 10 else dataclasses.replace(f, frame=f.frame + 1490))
    res = CliRunner().invoke(main, [*track, "--overwrite"])
    assert res.exit_code == 3 and "frame 1501 jumps 1491 frames after frame 10" in res.stderr
    res = CliRunner().invoke(main, [*track, "--overwrite", "--max-frame-gap", "1491"])
    assert res.exit_code == 0, res.stderr
    assert [f.frame for f in read_log(out).frames] == [*range(1, 11), 1501, 1502]


# --------------------------------------------------------------------------- pipeline


def test_pipeline_tracker_and_sink_reject_a_frame_jump_and_do_not_hang(tmp_path):
    """/measurements of seq 5 forged to frame 10^9: the tracker rejects and counts it (no
    prediction through 10^9 frames), the sink records neither it nor tracks for it, and the
    tracks equal an offline run without that frame."""
    cfg = _mem_cfg(tmp_path, frames=10)
    net = MemoryNetwork()
    net.tap = _forge_seq(5, 10**9)
    codes = _run_memory_pipeline(cfg, net, timeout=120)
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    frames, ests = _offline(cfg, drop=frozenset({5}))
    log = read_log(Path(cfg.out) / "tracks.mcap")
    assert [f.frame for f in log.frames] == [f.frame for f in frames] == [1, 2, 3, 4, 5, 7, 8, 9, 10]
    assert [_strip(e) for e in log.tracks] == [_strip(e) for e in ests]
    eos = ListSink(net).docs("eos/tracker")
    assert eos[-1]["rejected"] == [5] and eos[-1]["gaps"] == []
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert summary["frames_written"] == 9 and summary["tracks_written"] == 9
    letters = ListSink(net).docs("deadletter")
    why = "frame 1000000000 jumps 999999995 frames after frame 5 (more than max_frame_gap = 1000)"
    assert {(d["stage"], d["seq"], d["reason"]) for d in letters} >= {("tracker", 5, why), ("sink", 5, why)}


def test_pipeline_rejects_a_sequence_number_far_ahead(tmp_path):
    """A copy of seq 3 re-sent with seq = live + 200,000: rejected and counted by the tracker
    and the sink, no gap declared, the output equals offline."""
    cfg = _mem_cfg(tmp_path, frames=10)
    net = MemoryNetwork()

    def tap(run, topic, payload, att):
        out = [(payload, att)]
        if topic in ("measurements", "truth") and att and json.loads(att)["seq"] == 3:
            meta = json.loads(att)
            meta["seq"] = 200_003
            out.append((payload, json.dumps(meta).encode()))
        return out

    net.tap = tap
    codes = _run_memory_pipeline(cfg, net, timeout=120)
    assert codes["sink"] == EXIT_OK and codes["tracker"] == EXIT_OK
    _, ests = _offline(cfg)
    assert [_strip(e) for e in iter_tracks(Path(cfg.out) / "tracks.mcap")] == [_strip(e) for e in ests]
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert summary["gaps"] == {"measurements": [], "truth": [], "tracks": []}
    assert summary["counters"]["rejected"] == 2  # the sink's copies on /measurements and /truth
    letters = ListSink(net).docs("deadletter")
    assert {(d["stage"], d["topic"], d["seq"]) for d in letters} == {
        ("tracker", "measurements", 200_003), ("sink", "measurements", 200_003), ("sink", "truth", 200_003)}
    assert all("past the next expected" in d["reason"] and "max_seq_ahead = 100000" in d["reason"]
               for d in letters)


def test_sequencer_far_ahead_is_rejected_without_allocating():
    seq = Sequencer(32, 0, "m", catch_up=10_000, max_ahead=100_000)
    tracemalloc.start()
    status = [seq.push(s, s)[0] for s in (0, 10**9, 2**53 - 1, 100_001)]
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert status == ["accepted", "far", "far", "far"]
    assert seq.far == 3 and seq.gaps == [] and seq.next == 1 and peak < 1_000_000
    assert seq.push(100_000, "x")[0] == "accepted"  # 99,999 past next = 1: inside the bound
    # caught up after seq 0: everything but the last window (32) behind it is a gap
    assert seq.gaps == list(range(1, 100_000 - 31)) and seq.next == 100_000 - 31
    # max_ahead is never below the catch-up window (history must not be rejected)
    assert Sequencer(32, 0, "m", catch_up=10_000, max_ahead=50).max_ahead == 10_000
    # without max_ahead nothing is far: twice the pipeline's bound (delivery.max_seq_ahead) is accepted
    assert Sequencer(32).push(200_000, 1)[0] == "accepted"
