"""Over real processes and Zenoh on loopback: a sink SIGKILLed in
the middle of a replay is restarted; its successor keeps the first-delivery latencies the killed
process timed and saved, does not time the frames it gets from the caches that nobody timed, and
the summary says how many (docs/pipeline.md, "Latency after a restart").  The logic in memory:
tests/pipeline/test_summary_latency.py."""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import pytest

from bnptrack.pipeline.stages import SUMMARY_NAME
from bnptrack.pipeline.stages.sink_latency import LATENCY_PART

from testkit import REPO_ROOT, finish, popen_bnptrack, wait_until

N = 400


def _saved(out: Path) -> int:
    """How many timed frames the sink has saved (the header line aside)."""
    try:
        return max(len((out / LATENCY_PART).read_bytes().splitlines()) - 1, 0)
    except OSError:
        return 0


@pytest.mark.integration
def test_a_sink_killed_mid_replay_reports_first_delivery_latencies(tmp_path):
    sys.path.insert(0, str(REPO_ROOT / "benchmarks"))
    from faults import make_log

    log = make_log(tmp_path / "vo400.mcap", N)
    out = tmp_path / "run"
    p = popen_bnptrack("replay", str(log), "--rate", "50", "--set", "sink.rerun=false", "--out", str(out),
                       "--timeout", "240")
    try:
        wait_until(lambda: _saved(out) >= 100, 180, "the sink to time and save 100 frames",
                   abort=lambda: p.poll() is not None)
        os.kill(json.loads((out / "stages.json").read_text())["sink"]["pid"], signal.SIGKILL)
    finally:
        code, text = finish(p, 300)
    assert code == 0, text
    assert json.loads((out / "stages.json").read_text())["sink"]["restarts"] == 1
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] and s["frames_written"] == N and s["restarted"]
    lat = s["latency"]
    assert lat["timed_by_earlier_sink"] >= 100 and lat["excluded"]["recovered"] == 0
    cached = [q for a, b in lat["from_caches_seq"] for q in range(a, b + 1)]
    assert len(cached) == lat["excluded"]["from_caches"]
    # every frame is either timed once (by the killed process or its successor) or counted
    assert sorted(lat["seq"] + cached) == list(range(N))
    assert s["counters"]["latency_ms"]["n"] == lat["timed_frames"] == N - len(cached)
    # first deliveries at 50 frames/s: milliseconds, not the seconds a catch-up takes
    assert s["counters"]["latency_ms"]["p50"] < 2000, s["counters"]["latency_ms"]
    assert not (out / LATENCY_PART).exists()
    [row] = [line for line in text.splitlines() if line.startswith("latency ")]
    if cached:
        assert f"(not timed: {len(cached)} from the caches, published before the restarted sink subscribed)" in row
