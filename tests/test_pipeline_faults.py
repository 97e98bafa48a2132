"""Issue 17: nothing lost, nothing forged -- restarts at any moment, history for restarted
consumers, a pipeline closed to other local processes, bounded resources.

The in-memory tests (pipeline.membus) run in seconds; the tests over real Zenoh sessions
(loopback only, every wait bounded) take a few seconds each; those marked ``slow`` run
2,000-frame pipelines (minutes)."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest

from pipeline.membus import MemoryNetwork
from pipeline.pipeline_config import PipelineConfig, resolve_run
from pipeline.stages import (
    EXIT_OK,
    STAGES,
    SUMMARY_NAME,
    StageContext,
    commit_parts,
    part_path,
    read_snapshot,
)
from sources.mcap_log import read_log
from tracker.config import apply_overrides

ROOT = Path(__file__).resolve().parent.parent


def _mem_cfg(tmp_path: Path, frames: int = 8) -> PipelineConfig:
    overrides = [f"source.frames={frames}", "tracker.overrides=['sweeps=8', 'burn_in=2']",
                 "sink.rerun=false", "tracker.snapshot_every=4", "delivery.eos_grace_s=0.3",
                 "supervisor.linger_s=0.5"]
    return resolve_run(apply_overrides(PipelineConfig(run="mem", out=str(tmp_path / "out")), overrides))


def _run_stage(cfg: PipelineConfig, net: MemoryNetwork, role: str) -> int:
    bus = net.bus(cfg.run, role)
    try:
        return STAGES[role](StageContext(cfg, bus, name=role)).run()
    finally:
        bus.close()


def _memory_run(cfg: PipelineConfig, net: MemoryNetwork) -> None:
    import threading

    codes = {}
    threads = [threading.Thread(target=lambda r=r: codes.__setitem__(r, _run_stage(cfg, net, r)), daemon=True)
               for r in ("sink", "tracker", "source")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
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
    eos = [msgspec.json.decode(p) for r, t, p, a in net.history if t == "eos/sink"]
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
    eos = [msgspec.json.decode(p) for r, t, p, a in net.history if t == "eos/tracker"]
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


# --------------------------------------------------------------------------- over Zenoh


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["RERUN_ANALYTICS"] = "0"
    return env


def _popen(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pipeline", *args], cwd=ROOT, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)


def _wait(p: subprocess.Popen, timeout: float) -> tuple[int, str]:
    try:
        out, _ = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, _ = p.communicate(timeout=10)
        pytest.fail(f"{p.args} did not finish in {timeout} s:\n{out.decode()}")
    return p.returncode, out.decode()


def _wait_for(what: str, cond, p: subprocess.Popen, timeout: float = 90) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline and p.poll() is None, what
        time.sleep(0.01)


def _offline_tracks(log: Path, out: Path) -> list:
    from pipeline.offline import build_tracker, resolve_config, resolve_params, track_log
    from sources.mcap_log import read_metadata

    meta = read_metadata(log)
    config, _ = resolve_config("ddp", None)
    track_log(log, out, build_tracker("ddp", resolve_params(None, meta).params, config), 0, meta)
    return _tracks(out)


def _tracks(path: Path) -> list:
    def strip(e):
        d = {k: v for k, v in e.diagnostics.items() if k != "ms"}
        return (e.frame, e.labels, e.assignments, d, [(t.state.tolist(), t.existence) for t in e.tracks])

    return [strip(e) for e in read_log(path).tracks]


@pytest.mark.parametrize("role", ["sink", "tracker"])
def test_a_stage_killed_just_after_the_run_was_recorded_leaves_it_complete(tmp_path, role):
    """Issue 17, failure 1 and 11: SIGKILL of the sink (or the tracker) the moment sink.json
    appears.  The recording stays complete (30 frames, equal to offline `track`), the launch
    ends with exit 0, and no stage records anything again."""
    out = tmp_path / "run"
    p = _popen("launch", "--set", "source.frames=30", "--set", "sink.rerun=false", "--run", f"fin-{role}",
               "--out", str(out), "--timeout", "120")
    try:
        _wait_for("the sink never wrote sink.json", (out / SUMMARY_NAME).exists, p)
        pid = json.loads((out / "stages.json").read_text())[role]["pid"]
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:  # already gone: the case still holds
            pass
    finally:
        code, text = _wait(p, 150)
    assert code == 0, text
    assert len(read_log(out / "tracks.mcap").tracks) == 30
    assert _tracks(out / "tracks.mcap") == _offline_tracks(out / "tracks.mcap", tmp_path / "off.mcap")
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] and s["frames_written"] == 30 and not s["missing"]
    assert not list(out.glob(".*.part"))
