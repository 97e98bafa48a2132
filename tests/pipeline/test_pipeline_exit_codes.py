"""The exit code and the summary tell the truth: a run whose output is
incomplete (a gap, a rejected frame, a stage that gave up) ends with exit code 3 and says
what is missing and where."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bnptrack.pipeline.cli import EXIT_INCOMPLETE, IncompleteError
from bnptrack.pipeline.cli.pipeline_commands import _report_launch
from bnptrack.pipeline.launch import Launcher
from bnptrack.pipeline.outcome import describe_missing, seq_ranges
from bnptrack.pipeline.stages.summary import RunSummary
from bnptrack.pipeline.supervisor import LaunchResult
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, SUMMARY_NAME
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.models.params import load_params

from testkit import REPO_ROOT, drop_seq, wait_until
from testkit import forge_seq as _forge_seq
from testkit import mem_cfg as _mem_cfg
from testkit import run_memory_pipeline as _run_memory_pipeline

ROOT = REPO_ROOT


def _summary(cfg) -> dict:
    return json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())


def test_ranges_and_describe_missing_reference_text():
    assert seq_ranges([1, 2, 3, 7, 9, 10]) == "1-3, 7, 9-10"
    assert seq_ranges(list(range(0, 40, 2)), limit=3) == "0, 2, 4, ... (20 in all)"
    assert describe_missing(RunSummary(complete=True)) == ""
    assert describe_missing(None) == "the sink wrote no sink.json"
    text = describe_missing(RunSummary(complete=False, last_seq=8, missing=[
        {"topic": "/tracks", "seqs": [5, 6], "why": "no /tracks from the tracker (gap)"}]))
    assert text == ("the sink stopped before the end of stream (after seq 8); "
                    "/tracks of 2 frame(s), seq 5-6: no /tracks from the tracker (gap)")


def test_complete_memory_run_has_nothing_missing(tmp_path):
    cfg = _mem_cfg(tmp_path, frames=6)
    assert _run_memory_pipeline(cfg, MemoryNetwork())["sink"] == EXIT_OK
    s = _summary(cfg)
    assert s["output_complete"] is True and s["missing"] == [] and describe_missing(RunSummary.of(s)) == ""


def test_a_lost_frame_is_named_missing_in_every_stream(tmp_path):
    cfg = _mem_cfg(tmp_path, frames=10, **{"delivery.window": "3"})
    net = MemoryNetwork()
    net.tap = drop_seq([5])
    _run_memory_pipeline(cfg, net)
    s = _summary(cfg)
    assert s["complete"] is True and s["output_complete"] is False
    assert s["missing"] == [
        {"topic": "/measurements", "seqs": [5], "why": "never received (gap)"},
        {"topic": "/truth", "seqs": [5], "why": "never received (gap)"},
        {"topic": "/tracks", "seqs": [5], "why": "no /tracks from the tracker (gap)"},
    ]
    assert describe_missing(RunSummary.of(s)).startswith("/measurements of 1 frame(s), seq 5: never received (gap)")


def test_a_rejected_frame_is_named_missing(tmp_path):
    cfg = _mem_cfg(tmp_path, frames=8)
    net = MemoryNetwork()
    net.tap = _forge_seq(4, 10**9)
    _run_memory_pipeline(cfg, net)
    s = _summary(cfg)
    assert s["output_complete"] is False
    topics = {(m["topic"], tuple(m["seqs"]), m["why"].split(" (")[0]) for m in s["missing"]}
    assert topics == {("/tracks", (4,), "the tracker rejected the frame"),
                      ("/measurements", (4,), "the sink rejected the frame"),
                      ("/truth", (4,), "for another frame than its /measurements")}


def test_report_launch_exits_3_naming_what_is_missing(tmp_path, capsys):
    summary = RunSummary(complete=True, frames_written=9, tracks_written=9,
                         missing=[{"topic": "/tracks", "seqs": [5], "why": "no /tracks from the tracker (gap)"}])
    res = LaunchResult(run="r", out=tmp_path, ok=False, summary=summary,
                       incomplete=describe_missing(summary))
    with pytest.raises(IncompleteError) as exc:
        _report_launch(res, quiet=False)
    assert exc.value.exit_code == EXIT_INCOMPLETE == 3
    assert exc.value.message == (f"output incomplete: /tracks of 1 frame(s), seq 5: no /tracks from the "
                                 f"tracker (gap) -- files are in {tmp_path}/")
    assert "missing           /tracks of 1 frame(s), seq 5" in capsys.readouterr().out


def test_a_stage_that_gives_up_makes_the_launch_incomplete(tmp_path):
    """Every stage 'crashes' at once (the stage command is /bin/false): after
    ``max_restarts`` restarts the launcher gives up, and the result is incomplete (exit 3)."""
    from bnptrack.pipeline.config import load_pipeline

    cfg = load_pipeline(None, ["supervisor.max_restarts=1", "supervisor.restart_backoff_s=0",
                               "supervisor.stop_timeout_s=5", f"out='{tmp_path / 'o'}'", "run='gu'"])
    res = Launcher(cfg, python="/bin/false", timeout=60).run()
    assert not res.ok and res.gave_up in ("sink", "tracker", "source")
    assert res.incomplete.startswith(f"stage {res.gave_up} crashed (exit code 1) and was restarted 1 "
                                     "time(s) already; giving up (log: ")
    assert res.incomplete.endswith("; the sink wrote no sink.json")


@pytest.mark.integration  # a real replay: stage processes over Zenoh
def test_replay_of_a_log_with_a_frame_jump_exits_3(tmp_path):
    """A real launch (Zenoh): the tracker and the sink reject frames 10^9 + k after frame 10."""
    frames = simulate_all(get_scenario("vo2017"), load_params("vo2017"), 1)[:13]
    log = tmp_path / "jump.mcap"
    with McapLogWriter(log, {"scenario": "vo2017", "params": "vo2017", "seed": "1"}) as w:
        for f in frames:
            w.write_frame(f if f.frame <= 10 else dataclasses.replace(f, frame=10**9 + f.frame))
    out = tmp_path / "r"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, "-m", "bnptrack", "replay", str(log), "--as-fast-as-possible",
                          "--tracker", "ddp-mb", "--set", "sweeps=8", "--set", "burn_in=2", "--set", "sink.rerun=false",
                          "--out", str(out), "--timeout", "150", "-q"],
                         capture_output=True, text=True, timeout=200, env=env)
    assert res.returncode == 3, res.stderr
    assert res.stderr.splitlines()[-1] == (
        "Error: output incomplete: /tracks of 3 frame(s), seq 10-12: the tracker rejected the frame (frame "
        "bounds; each reason is in health.jsonl); /measurements of 3 frame(s), seq 10-12: the sink rejected the frame "
        f"(frame bounds; none of its messages were written) -- files are in {out}/")
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["frames_written"] == 10 and s["output_complete"] is False


# --------------------------------------------------------------------------- a taken --out


@pytest.mark.integration  # real launches: stage processes over Zenoh
@pytest.mark.slow
def test_a_second_launch_on_a_taken_out_is_refused_unless_overwrite(tmp_path):
    import signal

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = tmp_path / "r"

    def launch(*extra, run="first"):
        return subprocess.run([sys.executable, "-m", "bnptrack", "launch", "--out", str(out), "--run", run,
                               "-q", "--set", "source.frames=3", "--set", "sink.rerun=false",
                               "--set", "tracker.tracker=ddp-mb", "--set", "tracker.overrides=['sweeps=8', 'burn_in=2']", "--timeout", "150",
                               *extra], capture_output=True, text=True, timeout=200, env=env)

    assert launch().returncode == 0
    first = (out / "tracks.mcap").read_bytes()
    res = launch(run="second")
    assert res.returncode == 2 and res.stderr.splitlines() == [
        f"Error: --out {out}: holds run 'first' (pipeline.json, stages.json, sink.json, tracker.snap, "
        "tracker.journal, tracks.mcap, health.jsonl, logs); use another --out, or --overwrite to replace it"]
    assert (out / "tracks.mcap").read_bytes() == first
    res = launch("--overwrite", run="second")
    assert res.returncode == 0, res.stderr
    assert json.loads((out / "pipeline.json").read_text())["run"] == "second"
    assert json.loads((out / "sink.json").read_text())["run"] == "second"
    # a live run: refused even with --overwrite, and its files are left alone
    live = subprocess.Popen([sys.executable, "-m", "bnptrack", "launch", "--out", str(out), "--run", "live",
                             "--overwrite", "-q", "--set", "source.frames=1000", "--set", "source.rate=2",
                             "--set", "sink.rerun=false"], env=env, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: (out / "stages.json").exists()
                   and json.loads((out / "pipeline.json").read_text())["run"] == "live",
                   120, "the live launch to start its stages", abort=lambda: live.poll() is not None)
        res = launch("--overwrite", run="third")
        assert res.returncode == 2 and res.stderr.splitlines() == [
            f"Error: --out {out}: a run is live there (launcher pid {live.pid}); use another --out"]
        assert json.loads((out / "pipeline.json").read_text())["run"] == "live"
    finally:
        live.send_signal(signal.SIGINT)
        live.wait(60)
    assert live.returncode == 130


@pytest.mark.parametrize("text, summary_line", [
    ('{"run": "mem", "complete": true, "output_complete": true, "frames_written": 6, "files": []}', None),
    ('{"run": "mem", "complete": true, "frames_written": "six"}',
     "not a run summary: Expected `int`, got `str` - at `$.frames_written`"),
])
def test_the_launcher_reads_sink_json_typed_and_names_a_malformed_one(tmp_path, capsys, text, summary_line):
    """The launcher's end of a run over a hand-written ``sink.json``: a good one completes the
    run (the frames row comes from it); a malformed one is named on one line and exits 3."""
    launcher = Launcher(_mem_cfg(tmp_path))
    launcher.out.mkdir(parents=True)
    (launcher.out / SUMMARY_NAME).write_text(text)
    res = LaunchResult(run="mem", out=launcher.out, ok=True)
    launcher._conclude(res)
    if summary_line is None:
        assert res.ok and res.incomplete == "" and res.summary.frames_written == 6
        assert res.files == [str(launcher.out / SUMMARY_NAME)]
        _report_launch(res, quiet=False)
        assert "6 (0 /tracks; gaps: none)" in capsys.readouterr().out
        return
    assert res.summary is None and not res.ok
    assert res.incomplete == f"{launcher.out / SUMMARY_NAME}: {summary_line}"
    with pytest.raises(IncompleteError) as exc:
        _report_launch(res, quiet=True)
    assert exc.value.exit_code == 3 and "\n" not in exc.value.message


def test_a_launch_summary_gives_its_gaps_as_sequence_number_ranges(capsys):
    from types import SimpleNamespace

    from bnptrack.pipeline.cli.pipeline_commands import _report_launch

    summary = RunSummary(complete=True, output_complete=True, frames_written=40, tracks_written=37,
                         gaps={"measurements": [], "tracks": [33, 34, 35]})
    res = SimpleNamespace(summary=summary, restarts={}, run="r1", out="o", elapsed_s=1.0, files=[],
                          interrupted=False, incomplete="", ok=True)
    _report_launch(res, quiet=False)
    frames = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("frames"))
    assert frames.split(None, 1)[1] == "40 (37 /tracks; gaps: tracks seq 33-35)"
