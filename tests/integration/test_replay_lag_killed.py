"""``bnptrack replay --lag N`` over real Zenoh on loopback: the tracker killed (SIGKILL) mid-run
resumes with its fixed-lag window, and the recording equals ``bnptrack track --lag N``."""

from __future__ import annotations

import json
import os
import signal

import pytest

import bnptrack
from bnptrack.pipeline.stages import SUMMARY_NAME, read_snapshot

from testkit import finish, popen_bnptrack, wait_until


def _strip(e):
    d = {k: v for k, v in e.diagnostics.items() if k != "ms"}
    return (e.frame, e.lag, e.labels, e.assignments, d, [(t.state.tolist(), t.existence) for t in e.tracks])


def test_replay_lag_with_the_tracker_killed_equals_track_lag(tmp_path):
    log = tmp_path / "vo.mcap"
    bnptrack.simulate("vo2017", seed=3, out=log)
    expected = [_strip(e) for e in bnptrack.track(log, tracker="ddp", seed=0, lag=2).estimates]
    out = tmp_path / "run"
    p = popen_bnptrack("replay", str(log), "--rate", "20", "--lag", "2", "--set", "sink.rerun=false",
                       "--set", "tracker.snapshot_every=10", "--out", str(out), "--timeout", "240")

    def progress() -> int:
        try:
            return read_snapshot(out / "tracker.snap").last_seq
        except Exception:
            return -1

    try:
        wait_until(lambda: progress() >= 30, 150, "the tracker never reached its kill point", interval=0.01,
                   abort=lambda: p.poll() is not None)
        snap = read_snapshot(out / "tracker.snap")
        assert snap.lag == 2 and snap.published_seq == snap.last_seq - 2  # its window is in the snapshot
        os.kill(json.loads((out / "stages.json").read_text())["tracker"]["pid"], signal.SIGKILL)
    finally:
        code, text = finish(p, 260)
    assert code == 0, text
    assert json.loads((out / "stages.json").read_text())["tracker"]["restarts"] == 1
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] and s["gaps"] == {"measurements": [], "truth": [], "tracks": []} and not s["missing"]
    got = [_strip(e) for e in bnptrack.read_log(out / "tracks.mcap").tracks]
    assert len(got) == 100 and got == expected
