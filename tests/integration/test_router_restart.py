"""An external router SIGKILLed in the middle of a replay and restarted on the same port: the
stages reconnect, fetch what they missed from the live publishers, and the output equals
offline `bnptrack track` (no gap declared while the router was away)."""

from __future__ import annotations

import json
import os
import signal
import socket
from pathlib import Path

from bnptrack.pipeline.ports import free_port
from bnptrack.sources.mcap_log import read_log

from testkit import REPO_ROOT, finish, popen_bnptrack, strip, wait_until

LOG = REPO_ROOT / "recordings" / "vo2017-s1.mcap"


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _router(port: int, log: Path):
    p = popen_bnptrack("router", "--listen", f"tcp/127.0.0.1:{port}", log=log)
    wait_until(lambda: _listening(port), 60, "the router to listen")
    return p


def _processed(out: Path) -> int:
    from bnptrack.pipeline.stages import read_snapshot

    try:
        return read_snapshot(out / "tracker.snap").last_seq
    except Exception:  # noqa: BLE001 - not written yet
        return -1


def test_a_router_killed_and_restarted_mid_run_loses_nothing(tmp_path):
    port = free_port()
    router = _router(port, tmp_path / "router.log")
    out = tmp_path / "run"
    p = popen_bnptrack("replay", str(LOG), "--rate", "10", "--set", "sink.rerun=false",
                       "--set", "tracker.snapshot_every=5", "--set", "zenoh.embedded_router=false",
                       "--set", f"zenoh.connect=['tcp/127.0.0.1:{port}']", "--out", str(out), "--timeout", "400")
    try:
        wait_until(lambda: _processed(out) >= 30, 300, "the tracker to pass frame seq 30")
        os.killpg(router.pid, signal.SIGKILL)
        router.wait()
        # the source keeps publishing into its cache while no router carries its samples
        wait_until(lambda: not _listening(port), 10, "the port to close")
        router = _router(port, tmp_path / "router.log")
        code, text = finish(p, 420)
    finally:
        os.killpg(router.pid, signal.SIGKILL)
        router.wait()
    assert code == 0, text
    summary = json.loads((out / "sink.json").read_text())
    assert summary["gaps"] == {"measurements": [], "truth": [], "tracks": []}
    off = tmp_path / "off.mcap"
    code, text = finish(popen_bnptrack("track", str(LOG), "--out", str(off), "-q"), 300)
    assert code == 0, text
    assert [strip(e) for e in read_log(out / "tracks.mcap").tracks] == [strip(e) for e in read_log(off).tracks]
