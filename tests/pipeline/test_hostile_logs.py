"""One rule for frames beyond the frame bounds (tracker.types.FrameGate), in `bnptrack track`
and in the pipeline's tracker and sink (in memory): a time stamp that goes back once, a genuine
gap of more than 1,000 frames and 1 h after which the log goes on."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import SUMMARY_NAME
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.mcap_log import read_log
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import FrameBounds, FrameGate

from testkit import mem_cfg, run_memory_pipeline, strip

S = 10**9


def test_frame_gate_skips_a_stamp_that_goes_back_once_and_goes_on():
    g = FrameGate(FrameBounds(max_frame_gap=10, max_gap_s=5.0, resync_frames=3))
    assert g.admit(1, 1 * S) is None and g.admit(2, 2 * S) is None
    assert g.admit(3, 1 * S) == f"frame 3: time stamp {S} ns is before that of frame 2 ({2 * S} ns)"
    assert g.admit(4, 4 * S) is None and (g.last_frame, g.chain) == (4, 0)


def test_frame_gate_resynchronises_after_n_consistent_skipped_frames():
    g = FrameGate(FrameBounds(max_frame_gap=10, max_gap_s=5.0, resync_frames=3))
    g.admit(1, 1 * S)
    skipped = [k for k in range(100, 106) if g.admit(k, k * S) is not None]
    assert skipped == [100, 101, 102]  # three in a row agree; the fourth is admitted
    assert (g.last_frame, g.last_stamp_ns, g.chain) == (105, 105 * S, 0)  # 103-105 admitted
    # a lone outlier and then frames that do not agree with it: never a resynchronisation
    g2 = FrameGate(FrameBounds(max_frame_gap=10, max_gap_s=5.0, resync_frames=3))
    g2.admit(1, 1 * S)
    assert [g2.admit(k, k * S) is None for k in (500, 2, 900, 3, 4)] == [False, True, False, True, True]
    never = FrameGate(FrameBounds(max_frame_gap=10, max_gap_s=5.0, resync_frames=0))
    never.admit(1, 1 * S)
    assert all(never.admit(k, k * S) is not None for k in range(100, 150))
    g3 = FrameGate(FrameBounds(resync_frames=3))
    g3.restore(7, 7 * S, (2, 5000, 5000 * S))  # a snapshot's run of skipped frames
    assert g3.admit(5001, 5001 * S) is not None and g3.admit(5002, 5002 * S) is None


def _hostile(tmp_path: Path, kind: str) -> Path:
    frames = simulate_all(get_scenario("vo2017"), load_params("vo2017"), 1)[:40]
    log = tmp_path / f"{kind}.mcap"
    with McapLogWriter(log, {"scenario": "vo2017", "params": "vo2017", "seed": "1"}) as w:
        for i, f in enumerate(frames):
            if kind == "stamp-back" and i == 17:
                f = dataclasses.replace(f, stamp_ns=frames[3].stamp_ns)
            if kind == "long-gap" and i >= 15:  # 2,000 frames and 2 h later, the log goes on
                f = dataclasses.replace(f, frame=f.frame + 2000, stamp_ns=f.stamp_ns + 7200 * S)
            if kind == "repeat" and i == 20:  # numbered like the frame before it
                f = dataclasses.replace(f, frame=frames[19].frame)
            if kind == "jump" and i == 25:  # one frame numbered 10**9, then the numbers go on
                f = dataclasses.replace(f, frame=10**9)
            w.write_frame(f)
    return log


# the fast subset runs the stamp that goes back; the long gap (slow) is also run with a lag below
@pytest.mark.parametrize("kind, skipped", [("stamp-back", [17]),
                                           pytest.param("repeat", [20], marks=pytest.mark.slow),  # stamp-back's path
                                           pytest.param("jump", [25], marks=pytest.mark.slow),  # stamp-back's path
                                           pytest.param("long-gap", list(range(15, 25)), marks=pytest.mark.slow)])
def test_track_and_the_pipeline_give_the_same_output_on_a_hostile_log(tmp_path, kind, skipped):
    log = _hostile(tmp_path, kind)
    out = tmp_path / "track.mcap"
    res = CliRunner().invoke(main, ["track", str(log), "--out", str(out), "-q", "--tracker", "ddp-mb",
                                    "--set", "sweeps=8", "--set", "burn_in=2"])
    assert res.exit_code == 3, res.stderr
    assert res.stderr.startswith(f"Error: output incomplete: {len(skipped)} frame(s) beyond the frame bounds skipped")
    offline = read_log(out)
    assert len(offline.frames) == 40 - len(skipped)
    cfg = mem_cfg(tmp_path, frames=0, **{"source.kind": "'mcap'", "source.log": f"'{log}'"})
    run_memory_pipeline(cfg, MemoryNetwork())
    piped = read_log(Path(cfg.out) / "tracks.mcap")
    assert [f.frame for f in piped.frames] == [f.frame for f in offline.frames]
    assert [strip(e) for e in piped.tracks] == [strip(e) for e in offline.tracks]
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert not summary["output_complete"]  # the launcher's exit 3, as track's
    assert sorted({s for m in summary["missing"] for s in m["seqs"]}) == skipped


def test_a_resynchronised_stream_with_a_lag_keeps_the_tracks_of_the_frames_before_the_jump(tmp_path):
    # the fixed-lag window is published when the stream resynchronises, then the tracker starts afresh
    log = _hostile(tmp_path, "long-gap")
    cfg = mem_cfg(tmp_path, frames=0, **{"source.kind": "'mcap'", "source.log": f"'{log}'", "tracker.lag": "2"})
    run_memory_pipeline(cfg, MemoryNetwork())
    piped = read_log(Path(cfg.out) / "tracks.mcap")
    assert len(piped.frames) == 30 and len(piped.tracks) == 30
    assert [e.frame for e in piped.tracks] == [f.frame for f in piped.frames]
    assert (piped.frames[14].frame, piped.frames[15].frame) == (15, 2026)  # log frames 16-25 skipped
    summary = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())
    assert sorted({s for m in summary["missing"] for s in m["seqs"]}) == list(range(15, 25))
