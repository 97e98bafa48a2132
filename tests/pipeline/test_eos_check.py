"""An end of stream counts only if it is the source's own: the source reports what it published
on its private link to the launcher (never through the bus), the sink records the end of
stream it ended on, and the launcher's check names any conflict (exit 3) and rewrites
``sink.json`` to say what the forged end of stream cut off.  In memory; the same over real
processes and Zenoh: tests/integration/test_stage_keys.py."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import pytest

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.outcome import check_eos, describe_missing, foreign_eos
from bnptrack.pipeline.stage_link import LauncherLink, StageLink, eos_conflict
from bnptrack.pipeline.stages import EXIT_OK, STAGES, SUMMARY_NAME, ManualClock, StageContext
from bnptrack.pipeline.stages.summary import RunSummary, read_summary
from bnptrack.pipeline.supervisor import StageProcess

from testkit import mem_cfg


def _run(cfg, net: MemoryNetwork, reports: list, timeout: float = 120.0) -> dict[str, int]:
    """The sink and the source of ``cfg`` in threads on ``net`` (one ManualClock, which stands
    still until the source has reported its end of stream, then moves one second per poll);
    the source's reports to its launcher go to ``reports``."""
    clock = ManualClock()
    codes: dict[str, int] = {}
    errors: list[BaseException] = []

    def go(role: str) -> None:
        bus = net.bus(cfg.run, role)
        try:
            ctx = StageContext(cfg, bus, name=role, clock=clock)
            if role == "source":
                ctx.report = reports.append
            codes[role] = STAGES[role](ctx).run()
        except BaseException as exc:  # pragma: no cover - surfaced below
            errors.append(exc)
        finally:
            bus.close()

    threads = [threading.Thread(target=go, args=(r,), daemon=True) for r in ("sink", "source")]
    for t in threads:
        t.start()
    deadline = time.monotonic() + timeout
    while any(t.is_alive() for t in threads) and time.monotonic() < deadline:
        if reports:
            clock.advance(1.0)
        threads[0].join(0.02)
    assert not errors, errors
    assert not any(t.is_alive() for t in threads), "a stage did not finish"
    return codes


def _source_process(tmp_path: Path, reports: list) -> StageProcess:
    sp = StageProcess("source", [], tmp_path / "source.log")
    sp.reports = list(reports)
    return sp


def _cfg(tmp_path: Path):
    return mem_cfg(tmp_path, frames=12, **{"sink.tracks": "false", "source.done_by": "['sink']",
                                                  "source.wait_for": "['sink']"})


def test_the_source_reports_its_end_of_stream_and_a_genuine_run_has_no_conflict(tmp_path):
    cfg = _cfg(tmp_path)
    reports: list = []
    assert _run(cfg, MemoryNetwork(), reports) == {"sink": EXIT_OK, "source": EXIT_OK}
    assert reports == [{"eos": {"last_seq": 11, "frames": 12}}]
    summary = read_summary(Path(cfg.out) / SUMMARY_NAME)
    assert summary.source_eos == {"last_seq": 11, "frames": 12}
    assert check_eos(Path(cfg.out), summary, [_source_process(tmp_path, reports)]) == ("", summary)


def test_a_forged_end_of_stream_the_sink_ended_on_is_a_conflict_named_in_sink_json(tmp_path):
    """Another party puts ``eos/source`` at seq 4 while the source's later frames and its own
    end of stream are still on their way (here: never delivered): the sink ends on it (it
    cannot tell), the source's own report says seq 11, and the check names the conflict and
    the 7 frames the forged end of stream cut off."""
    cfg = _cfg(tmp_path)
    net = MemoryNetwork()

    def on_their_way(run, topic, payload, att):
        if topic in ("measurements", "truth") and json.loads(att)["seq"] >= 5:
            return []
        if topic == "eos/source" and json.loads(payload)["last_seq"] == 11:
            return []
        return [(payload, att)]

    net.tap = on_their_way
    forger = net.bus(cfg.run, "forger")
    forger.publish("eos/source", json.dumps({"stage": "source", "run": cfg.run, "last_seq": 4, "frames": 5}).encode())
    reports: list = []
    assert _run(cfg, net, reports) == {"sink": EXIT_OK, "source": EXIT_OK}
    # the source saw the forged one on the bus and told its launcher (which stops the run)
    assert reports == [{"foreign_eos": {"last_seq": 4, "frames": 5}}, {"eos": {"last_seq": 11, "frames": 12}}]
    assert foreign_eos([_source_process(tmp_path, reports)]) == (
        "end of stream conflict: an end of stream of the source at seq 4 (5 frame(s)) that the source process "
        "never sent was put on the bus (a forged end of stream)")
    out = Path(cfg.out)
    summary = read_summary(out / SUMMARY_NAME)
    assert summary.source_eos == {"last_seq": 4, "frames": 5} and summary.output_complete is True
    conflict, marked = check_eos(out, summary, [_source_process(tmp_path, reports)])
    assert conflict == ("end of stream conflict: the sink ended the run on an end of stream of the source at "
                        "seq 4 (5 frame(s)); the source process's own end of stream is at seq 11 (12 frame(s))")
    on_disk = read_summary(out / SUMMARY_NAME)
    assert on_disk == marked and on_disk.eos_conflict == conflict and on_disk.output_complete is False
    assert list(json.loads((out / SUMMARY_NAME).read_text()))[-1] == "eos_conflict"  # after the sink's keys
    why = "published by the source after the end of stream the sink ended on (end of stream conflict)"
    assert on_disk.missing == [{"topic": "/measurements", "seqs": [5, 6, 7, 8, 9, 10, 11], "why": why},
                                  {"topic": "/truth", "seqs": [5, 6, 7, 8, 9, 10, 11], "why": why}]
    assert describe_missing(on_disk).startswith(f"/measurements of 7 frame(s), seq 5-11: {why}")


def test_eos_conflict_reference_texts():
    rec = {"last_seq": 41, "frames": 42}
    assert eos_conflict({"last_seq": 41, "frames": 42}, None, rec) == ""
    assert eos_conflict(None, None, None) == ""
    assert eos_conflict(None, {"last_seq": 59, "frames": 60}, rec) == (
        "end of stream conflict: the sink ended the run on an end of stream of the source at seq 41 "
        "(42 frame(s)) that the source process never sent (a forged end of stream); it had published "
        "60 frame(s), up to seq 59, when it was stopped")
    assert eos_conflict(None, None, rec).endswith("that the source process never sent (a forged end of stream)")


def test_a_restarted_source_that_receives_its_predecessors_end_of_stream_is_no_conflict(tmp_path):
    own = {"eos": {"last_seq": 11, "frames": 12}}
    again = {"foreign_eos": {"last_seq": 11, "frames": 12}}  # the cache's history, to the new process
    assert foreign_eos([_source_process(tmp_path, [own, again])]) == ""
    assert foreign_eos([_source_process(tmp_path, [own, {"foreign_eos": {"last_seq": 3, "frames": 4}}])]) != ""


def test_check_eos_is_silent_without_a_source_here(tmp_path):
    summary = RunSummary(source_eos={"last_seq": 3, "frames": 4})
    sink = StageProcess("sink", [], tmp_path / "sink.log")
    assert check_eos(tmp_path, summary, [sink]) == ("", summary)
    assert not (tmp_path / SUMMARY_NAME).exists()


def test_the_link_carries_the_key_down_and_reports_up_and_is_not_reopenable(tmp_path):
    link = LauncherLink()
    link.send_key("source", "s3cret")
    stage = StageLink(os.dup(link.child_fd()))
    link.closed_in_parent()
    # another process of the same user cannot open the stage's end through /proc
    with pytest.raises(OSError):
        open(f"/proc/self/fd/{stage.sock.fileno()}", "rb")
    assert stage.read_key() == ("source", "s3cret")
    stage.report({"eos": {"last_seq": 2, "frames": 3}})
    stage.report({"stopped": {"last_seq": 2, "frames": 3}})
    for _ in range(100):  # the two lines are in the socket buffer already
        got = link.poll()
        if got:
            break
    assert got == [{"eos": {"last_seq": 2, "frames": 3}}, {"stopped": {"last_seq": 2, "frames": 3}}]
    stage.close()
    link.close()
    r, w = os.pipe()
    try:
        with pytest.raises(ValueError, match="not a socket"):
            StageLink(r)
    finally:
        os.close(r)
        os.close(w)
