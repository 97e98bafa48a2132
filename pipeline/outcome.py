"""The launcher's view of how a run ended, besides the stages' exit codes: whether the end of
stream the sink ended on is the source process's own (:func:`check_eos`, from the reports
the source sends on its private link, :mod:`pipeline.stage_link`), and how long the sink may
go on once a stage was given up (:class:`SinkWait`: the exit code follows the output)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import msgspec

from bnptrack.pipeline.stage_link import eos_conflict
from bnptrack.pipeline.stages import SUMMARY_NAME, write_atomic
from bnptrack.pipeline.stages.summary import RunSummary
from bnptrack.pipeline.supervisor import StageProcess

__all__ = ["source_reports", "foreign_eos", "unsent_eos", "check_eos", "describe_missing", "seq_ranges", "SinkWait"]


def source_reports(stages: Sequence[StageProcess]) -> tuple[dict | None, dict | None] | None:
    """The source's first reported end of stream and its last report of being stopped before
    its end (``None`` for either it did not send); ``None`` when no source runs here."""
    sources = [sp for sp in stages if sp.role == "source"]
    if not sources:
        return None
    reports = sources[0].poll_reports()
    eos = next((r["eos"] for r in reports if isinstance(r.get("eos"), dict)), None)
    stopped = next((r["stopped"] for r in reversed(reports) if isinstance(r.get("stopped"), dict)), None)
    return eos, stopped


def foreign_eos(stages: Sequence[StageProcess]) -> str:
    """The conflict when this launcher's source saw an end of stream of its own name on the bus
    that none of its processes sent (``""``: none)."""
    reports = [r for sp in stages if sp.role == "source" for r in sp.poll_reports()]
    # a restarted source receives its predecessor's end of stream again: that one is its own
    own = [(r["eos"].get("last_seq"), r["eos"].get("frames")) for r in reports if isinstance(r.get("eos"), dict)]
    seen = next((r["foreign_eos"] for r in reports if isinstance(r.get("foreign_eos"), dict)
                 and (r["foreign_eos"].get("last_seq"), r["foreign_eos"].get("frames")) not in own), None)
    if seen is None:
        return ""
    return (f"end of stream conflict: an end of stream of the source at seq {seen.get('last_seq')} "
            f"({seen.get('frames')} frame(s)) that the source process never sent was put on the bus "
            "(a forged end of stream)")


def unsent_eos(stages: Sequence[StageProcess]) -> bool:
    """Whether the sinks have finished while this launcher's source still runs without having
    sent its end of stream: they ended on one the source never sent."""
    reports = source_reports(stages)
    return (reports is not None and reports[0] is None
            and any(sp.role == "source" and sp.alive() for sp in stages)
            and all(sp.state == "done" for sp in stages if sp.role == "sink"))


def check_eos(out: Path, summary: RunSummary | None,
              stages: Sequence[StageProcess]) -> tuple[str, RunSummary | None]:
    """The conflict between the source's end of stream the sink recorded (``sink.json``'s
    ``source_eos``) and the source process's own reports (``""``: none, or no source here),
    and the summary; on a conflict ``sink.json`` is rewritten to say so (``eos_conflict``,
    ``output_complete`` false, the frames the source published after it as ``missing``)."""
    reports = source_reports(stages)
    if reports is None or summary is None:
        return "", summary
    eos, stopped = reports
    recorded = summary.source_eos
    conflict = eos_conflict(eos, stopped, recorded)
    if not conflict:
        return "", summary
    own = eos or stopped or {}
    first = max(int(recorded["last_seq"]), summary.last_seq) + 1  # the sink may have written more
    seqs = list(range(first, int(own.get("last_seq", -1)) + 1))
    why = "published by the source after the end of stream the sink ended on (end of stream conflict)"
    extra = [{"topic": f"/{t}", "seqs": seqs, "why": why} for t in summary.gaps if seqs]
    summary = msgspec.structs.replace(summary, eos_conflict=conflict, output_complete=False,
                                      missing=[*summary.missing, *extra])
    try:
        write_atomic(out / SUMMARY_NAME, summary.encode())
    except OSError:  # the exit code and the error line say it all the same
        pass
    return conflict, summary


class SinkWait:
    """After a stage other than the sink was given up: the sink goes on recording what is in
    flight, and its output decides the exit code.  :meth:`waiting` is true while a sink runs
    and its health changed within ``idle_s`` seconds (then the launcher stops it: it finalizes
    what it has, and ``sink.json`` says what is missing, if anything)."""

    def __init__(self, idle_s: float) -> None:
        self.idle_s = idle_s
        self.last: Any = None
        self.since = time.monotonic()

    def waiting(self, stages: Sequence[StageProcess], sink_health: dict | None) -> bool:
        if not any(sp.role == "sink" and sp.state in ("running", "restarting") for sp in stages):
            return False
        marker = (sink_health or {}).get("counters"), (sink_health or {}).get("frames_written")
        now = time.monotonic()
        if marker != self.last:
            self.last, self.since = marker, now
        return now - self.since < self.idle_s


def seq_ranges(seqs: Sequence[int], limit: int = 8) -> str:
    """``[1, 2, 3, 7]`` -> ``"1-3, 7"`` (at most ``limit`` ranges, then ``"..."``): sequence
    numbers, seq ``n`` being the source's ``n + 1``-th frame."""
    parts: list[str] = []
    start = prev = None
    for x in [*seqs, None]:
        if x is not None and prev is not None and x == prev + 1:
            prev = x
            continue
        if start is not None:
            parts.append(str(start) if start == prev else f"{start}-{prev}")
        start = prev = x
    more = len(parts) > limit
    return ", ".join(parts[:limit]) + (f", ... ({len(seqs)} in all)" if more else "")


def describe_missing(summary: RunSummary | None) -> str:
    """One line saying what a run's output lacks (``""``: it is complete), from the sink's
    ``sink.json``: no summary, a sink that stopped before the end of stream, and each
    ``missing`` entry (topic, sequence numbers, why)."""
    if summary is None:
        return f"the sink wrote no {SUMMARY_NAME}"
    if summary.output_complete and not summary.missing:
        return ""  # a sink stopped after it had everything (a stage given up after its end of stream)
    parts = []
    if not summary.complete:
        parts.append(f"the sink stopped before the end of stream (after seq {summary.last_seq})")
    for m in summary.missing:
        seqs = m.get("seqs") or []  # none, with from_seq: the rest of a run of unknown length
        where = f"from seq {m['from_seq']} on" if not seqs and m.get("from_seq") is not None else \
            f"of {len(seqs)} frame(s), seq {seq_ranges(seqs)}"
        parts.append(f"{m.get('topic')} {where}: {m.get('why')}")
    return "; ".join(parts)
