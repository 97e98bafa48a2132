"""What the files say follows the output, whoever stops first: a sink stopped before the end
of stream (its launcher gone) lists every frame it lacks in ``sink.json``, or says the output
is complete when it is; a stage process records its own exit in ``stages.json``, so the file
never shows an exited stage as running after its launcher died.  In memory; the same over
real processes: tests/integration/test_exit_follows_output_processes.py."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import msgspec

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.outcome import SinkWait, describe_missing
from bnptrack.pipeline.stages.summary import RunSummary
from bnptrack.pipeline.stages import EXIT_STOPPED, SUMMARY_NAME, ManualClock, SinkStage, SourceStage, StageContext
from bnptrack.pipeline.stages.base import StopFlag
from bnptrack.pipeline.supervisor import StageProcess, record_exit, write_stages

from testkit import mem_cfg, wait_until

GONE = "its launcher, pid 4321, is gone"


def _stopped_sink(tmp_path: Path, tap) -> tuple[dict, int]:
    """Run a 6-frame source to its end and a sink on a tapped network; once the sink has
    written every frame that reaches it, stop it as its launcher's disappearance does."""
    cfg = mem_cfg(tmp_path, frames=6, **{"sink.tracks": "false", "source.done_by": "[]",
                                          "source.wait_for": "['sink']"})
    net = MemoryNetwork()
    net.tap = tap
    clock = ManualClock()  # stands still: no grace period expires
    stop = StopFlag()
    sink = SinkStage(StageContext(cfg, net.bus(cfg.run, "sink"), stop, "sink", clock))
    codes: dict[str, int] = {}
    t = threading.Thread(target=lambda: codes.setdefault("sink", sink.run()), daemon=True)
    t.start()
    assert SourceStage(StageContext(cfg, net.bus(cfg.run, "source"), name="source", clock=clock)).run() == 0
    reached = sum(1 for r, topic, _, _ in net.history if topic == "measurements")
    wait_until(lambda: sink.frames_written == reached, 60, "the sink to write what reached it")
    stop.stop(GONE)
    t.join(60)
    assert not t.is_alive()
    return json.loads((Path(cfg.out) / SUMMARY_NAME).read_text()), codes["sink"]


def test_a_sink_stopped_before_an_end_of_stream_it_never_saw_names_the_rest_as_missing(tmp_path):
    def no_eos(run, topic, payload, att):
        return [] if topic == "eos/source" else [(payload, att)]

    s, code = _stopped_sink(tmp_path, no_eos)
    assert code == EXIT_STOPPED
    why = f"not received: the sink was stopped ({GONE})"
    assert s["complete"] is False and s["output_complete"] is False and s["frames_written"] == 6
    assert s["missing"] == [{"topic": "/measurements", "seqs": [], "from_seq": 6, "why": why},
                            {"topic": "/truth", "seqs": [], "from_seq": 6, "why": why}]
    assert describe_missing(RunSummary.of(s)) == (f"the sink stopped before the end of stream (after seq 5); "
                                   f"/measurements from seq 6 on: {why}; /truth from seq 6 on: {why}")


def test_a_stopped_sink_that_knows_the_end_of_stream_lists_the_missing_frames(tmp_path):
    def late_frames(run, topic, payload, att):
        if topic in ("measurements", "truth") and json.loads(att)["seq"] >= 4:
            return []
        return [(payload, att)]

    s, code = _stopped_sink(tmp_path, late_frames)
    why = f"not received: the sink was stopped ({GONE})"
    assert code == EXIT_STOPPED and s["frames_written"] == 4 and s["source_eos"] == {"last_seq": 5, "frames": 6}
    assert s["output_complete"] is False
    assert s["missing"] == [{"topic": "/measurements", "seqs": [4, 5], "from_seq": 4, "why": why},
                            {"topic": "/truth", "seqs": [4, 5], "from_seq": 4, "why": why}]


def test_a_summary_with_nothing_missing_is_complete_even_if_the_sink_was_stopped():
    """A sink stopped after it had every frame up to the source's end of stream (waiting for
    the tracker's end of stream, say) writes ``output_complete`` true: nothing is missing."""
    s = RunSummary(complete=False, last_seq=5, output_complete=True)
    assert describe_missing(s) == ""
    assert describe_missing(msgspec.structs.replace(s, output_complete=False)) == "the sink stopped before the end of stream (after seq 5)"


def test_a_stage_records_its_own_exit_and_the_launcher_keeps_that_record(tmp_path):
    me = StageProcess("source", [], tmp_path / "logs" / "source.log", state="running")
    other = StageProcess("sink", [], tmp_path / "logs" / "sink.log", state="running")

    class Proc:  # the launcher's handles on the processes: this one is us
        def __init__(self, pid: int) -> None:
            self.pid = pid

    me.proc, other.proc = Proc(os.getpid()), Proc(os.getpid() + 1)
    write_stages(tmp_path, [me, other])
    record_exit(tmp_path, "source", 0)  # the launcher is gone: the stage says it itself
    record_exit(tmp_path, "sink", 3)  # not this process's entry: untouched
    doc = json.loads((tmp_path / "stages.json").read_text())
    assert (doc["source"]["state"], doc["source"]["returncode"], doc["source"]["exited"]) == ("done", 0, True)
    assert doc["sink"]["state"] == "running" and doc["sink"]["returncode"] is None
    # a launcher that writes before it has seen the exit does not bring "running" back
    write_stages(tmp_path, [me, other])
    doc = json.loads((tmp_path / "stages.json").read_text())
    assert doc["source"]["state"] == "done" and doc["source"]["returncode"] == 0
    record_exit(tmp_path, "source", 130)
    assert json.loads((tmp_path / "stages.json").read_text())["source"]["state"] == "stopped"
    assert not list(tmp_path.glob(".stages.json.*.tmp"))


def test_after_a_stage_is_given_up_the_launcher_waits_while_the_sink_makes_progress(tmp_path):
    sink = StageProcess("sink", [], tmp_path / "sink.log", state="running")
    wait = SinkWait(idle_s=0.3)
    assert wait.waiting([sink], {"counters": {"accepted": 1}})
    wait_until(lambda: not wait.waiting([sink], {"counters": {"accepted": 1}}), 10, "the sink to be idle for 0.3 s")
    assert wait.waiting([sink], {"counters": {"accepted": 2}})  # progress: the wait starts again
    sink.state = "done"
    assert not wait.waiting([sink], {"counters": {"accepted": 3}})
