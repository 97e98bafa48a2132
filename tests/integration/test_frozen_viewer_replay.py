"""`bnptrack replay --connect` to a live viewer that stops reading (SIGSTOP) mid-run: the files
are complete and the run ends within seconds of the sink's summary (no stage process is held
at exit by the Rerun SDK's flush to the frozen viewer)."""

from __future__ import annotations

import json
import os
import signal
import time

from test_live_view import Receiver

from testkit import REPO_ROOT, finish, popen_bnptrack, wait_until

LOG = REPO_ROOT / "recordings" / "vo2017-s1.mcap"


def test_replay_to_a_frozen_viewer_ends_soon_after_its_files(tmp_path):
    rec = Receiver(tmp_path / "received.rrd")
    out = tmp_path / "run"
    p = popen_bnptrack("replay", str(LOG), "--rate", "25", "--connect", rec.url, "--out", str(out),
                       "--timeout", "300")
    try:
        wait_until(lambda: (out / "stages.json").exists(), 120, "the stages to start")
        os.kill(rec.proc.pid, signal.SIGSTOP)
        wait_until(lambda: (out / "sink.json").exists(), 240, "the sink's summary")
        t_files = time.monotonic()
        code, text = finish(p, 120)
        after = time.monotonic() - t_files
    finally:
        os.kill(rec.proc.pid, signal.SIGCONT)
        rec.stop()
    assert code == 0, text
    assert after <= 10.0, f"the run ended {after:.1f} s after its files"
    assert json.loads((out / "sink.json").read_text())["output_complete"]
    assert all((out / f).is_file() for f in ("tracks.mcap", "run.rrd"))
