"""Over real processes: a sink started by hand (`bnptrack stage sink`) after
a run whose sink was SIGKILLed mid-run and whose source and tracker have exited ends within
a bound with exit 3, a sink.json naming what is missing, and the frames the killed sink had
written intact (the in-memory cases: tests/pipeline/test_restart_alone.py)."""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path


from bnptrack.pipeline.config import ZenohConfig
from bnptrack.pipeline.stages import SUMMARY_NAME, part_path, read_snapshot, salvage_part
from bnptrack.sources.mcap_log import read_log

from testkit import REPO_ROOT, finish, popen_bnptrack, wait_until

#: seconds within which the hand-started sink must end: start-up, delivery.upstream_gone_s
#: (5 s) and the cache queries, on a busy 2-core machine
BOUND_S = 60.0


_popen, _finish = popen_bnptrack, finish


def _snapshot_seq(out: Path) -> int:
    try:
        return read_snapshot(out / "tracker.snap").last_seq
    except Exception:
        return -1


def _kill_sink_mid_run(tmp_path: Path) -> Path:
    """A 100-frame replay at 25 frames/s whose sink is SIGKILLed once the tracker has passed
    seq 40; with max_restarts = 0 the launcher gives up (exit 3) and stops the others."""
    sys.path.insert(0, str(REPO_ROOT / "benchmarks"))
    from faults import make_log

    log = make_log(tmp_path / "vo100.mcap", 100)
    out = tmp_path / "run"
    p = _popen("replay", str(log), "--rate", "25", "--set", "sink.rerun=false", "--set",
               "tracker.snapshot_every=10", "--set", "supervisor.max_restarts=0", "--out", str(out),
               "--timeout", "120")
    try:
        wait_until(lambda: _snapshot_seq(out) >= 40, 90, "the tracker to pass seq 40", abort=lambda: p.poll() is not None)
        os.kill(json.loads((out / "stages.json").read_text())["sink"]["pid"], signal.SIGKILL)
    finally:
        code, text = _finish(p, 150)
    assert code == 3 and "stage sink crashed (killed by SIGKILL)" in text, text
    stages = json.loads((out / "stages.json").read_text())
    assert stages["source"]["returncode"] is not None and stages["tracker"]["returncode"] is not None
    return out


def test_a_sink_started_by_hand_after_the_others_left_finalizes_the_killed_sinks_frames(tmp_path):
    from bnptrack.pipeline.transport import Router

    out = _kill_sink_mid_run(tmp_path)
    run = json.loads((out / "pipeline.json").read_text())["run"]
    part = part_path(out / "tracks.mcap")
    written = salvage_part(part, run)  # what the killed sink had written, read before the restart
    assert written is not None and len(written.frames) >= 10
    k = len(written.frames)
    before = read_log(part, strict=False)
    assert before.error is not None  # a cut file: no summary, no footer
    with Router(ZenohConfig()) as router:
        p = _popen("stage", "sink", "--run", run, "--connect", router.endpoints[0], "--out", str(out),
                   "--set", "sink.rerun=false")
        code, text = _finish(p, BOUND_S)
    assert code == 3, text
    assert f"sink: run {run}: upstream gone before the end of stream: no live source or tracker for 5 s" in text
    assert not part.exists()
    # the frames the killed sink had written are intact: the same payloads, byte for byte
    assert [f.payloads for f in salvage_part(out / "tracks.mcap", run).frames] == [f.payloads for f in written.frames]
    after = read_log(out / "tracks.mcap")  # a finished file now
    assert [e.frame for e in after.tracks] == [e.frame for e in before.tracks[:k]]
    assert len(after.frames) == k
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["run"] == run and s["complete"] is False and s["output_complete"] is False
    assert s["recovered_frames"] == k and s["frames_written"] == k
    assert {m["topic"] for m in s["missing"]} == {"/measurements", "/truth", "/tracks"}
    assert all(m["from_seq"] == k and m["why"].startswith("upstream gone before the end of stream")
               for m in s["missing"])


def test_a_launch_restarts_a_sink_killed_after_the_others_left_and_it_finalizes_their_frames(tmp_path):
    """The launcher's side: source and tracker leave without waiting for the sink
    (``done_by = []``); the sink, paused meanwhile, is SIGKILLed once both are done.  The
    launcher restarts it (its .part holds frames), the restarted sink finalizes them alone
    (exit 3), and the launch exits 3 naming the missing rest, no .part left behind."""
    sys.path.insert(0, str(REPO_ROOT / "benchmarks"))
    from faults import make_log

    log = make_log(tmp_path / "vo100.mcap", 100)
    out = tmp_path / "run"
    p = _popen("replay", str(log), "--rate", "25", "--set", "sink.rerun=false", "--set", "tracker.snapshot_every=10",
               "--set", "source.done_by=[]", "--set", "tracker.done_by=[]", "--out", str(out), "--timeout", "120")

    def stages() -> dict:
        try:
            return json.loads((out / "stages.json").read_text())
        except (OSError, ValueError):
            return {}

    try:
        wait_until(lambda: _snapshot_seq(out) >= 20, 90, "the tracker to pass seq 20", abort=lambda: p.poll() is not None)
        sink = stages()["sink"]["pid"]
        os.kill(sink, signal.SIGSTOP)
        wait_until(lambda: stages().get("source", {}).get("state") == "done" == stages().get("tracker", {}).get("state"),
                   90, "the source and the tracker to finish", abort=lambda: p.poll() is not None)
        os.kill(sink, signal.SIGKILL)
    finally:
        code, text = _finish(p, 150)
    assert code == 3, text
    assert "upstream gone before the end of stream" in text and "giving up" not in text
    assert stages()["sink"]["restarts"] == 1 and stages()["sink"]["returncode"] == 3
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["recovered_frames"] >= 1 and s["frames_written"] == s["recovered_frames"] and not s["output_complete"]
    assert len(read_log(out / "tracks.mcap").tracks) == s["recovered_frames"]
    assert not list(out.glob(".*.part"))
