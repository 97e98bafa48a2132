"""What a run's sink says it recorded: ``<out>/sink.json`` as a typed :class:`RunSummary`,
written by the sink stage and read back by a restarted sink and the supervisor.

The file's bytes are :meth:`RunSummary.encode`: the fields in their declared order, one per
line (``msgspec.json.format(..., indent=1)``), the keys docs/pipeline.md lists.  Every field
has a default, so a file that lacks one (or has one more) still reads.  Every reader decodes it
with the one decoder here: :func:`read_summary` (``None`` for anything but this run's summary:
a restarted sink, the supervisor) and :func:`load_summary` (the launcher: a malformed file is a
:class:`SummaryError` with one line naming the file and the field).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import msgspec

from bnptrack.sinks.run_scorer import RunScores

__all__ = ["RunSummary", "SummaryError", "read_summary", "load_summary"]


class RunSummary(msgspec.Struct, frozen=True, kw_only=True):
    """The sink's account of a run (``sink.json``)."""

    run: str = ""
    #: the sink recorded everything up to the source's end of stream
    complete: bool = False
    frames_written: int = 0
    tracks_written: int = 0
    last_seq: int = -1
    #: per stream (``measurements``, ``truth``, ``tracks``): the sequence numbers recorded as gaps
    gaps: dict[str, list[int]] = {}
    #: complete, and nothing missing
    output_complete: bool = False
    #: what ``tracks.mcap`` lacks: ``{"topic", "seqs", "why"}`` (or ``"from_seq"`` for a tail)
    missing: list[dict[str, Any]] = []
    recovered_frames: int = 0
    source_error: str = ""
    #: the source's end of stream the sink ended on: ``{"last_seq", "frames"}`` (the launcher
    #: checks it against the source process's own reports)
    source_eos: dict[str, int] | None = None
    counters: dict[str, Any] = {}
    #: the counters are this process's (an earlier sink process of the run was killed)
    restarted: bool = False
    rejected_by_topic: dict[str, int] = {}
    dropped: int = 0
    zenoh_misses: int = 0
    files: list[str] = []
    #: the run's scores (``None``: the sink scored nothing)
    scores: RunScores | None = None
    #: the command that opens the recording (``""``: no ``run.rrd``)
    view: str = ""
    throughput_fps: float | None = None
    t_first_pub_ns: int | None = None
    t_last_recv_ns: int | None = None
    latency: dict[str, Any] = {}
    #: the launcher's, when the end of stream the sink ended on is not the source's own (not
    #: written otherwise)
    eos_conflict: str | msgspec.UnsetType = msgspec.UNSET

    @classmethod
    def of(cls, doc: Mapping[str, Any]) -> RunSummary:
        """A summary from a ``sink.json`` document already decoded (``msgspec.ValidationError``
        names a field of the wrong type)."""
        return msgspec.convert(doc, cls)

    def encode(self) -> bytes:
        """``sink.json``'s bytes."""
        return msgspec.json.format(_ENC.encode(self), indent=1)

    def all_gaps(self) -> list[int]:
        """Every stream's gaps, sorted, once each."""
        return sorted({int(g) for v in self.gaps.values() for g in v})


_ENC = msgspec.json.Encoder()
_DEC = msgspec.json.Decoder(RunSummary)


class SummaryError(ValueError):
    """A ``sink.json`` that is there but is not a run summary (one line: the file and why)."""


def load_summary(path: str | Path) -> RunSummary | None:
    """The ``sink.json`` at ``path``; ``None`` when there is none.  A file that cannot be read,
    is not JSON or holds a field of the wrong type raises :class:`SummaryError`."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise SummaryError(f"{path}: cannot read the run summary: {exc.strerror or exc}") from None
    try:
        return _DEC.decode(data)
    except msgspec.DecodeError as exc:  # ValidationError is a DecodeError
        raise SummaryError(f"{path}: not a run summary: {exc}") from None


def read_summary(path: str | Path, run: str | None = None) -> RunSummary | None:
    """The ``sink.json`` at ``path`` (``None``: none, unreadable, or, with ``run``, another run's)."""
    try:
        summary = load_summary(path)
    except SummaryError:
        return None
    return summary if summary is not None and (run is None or summary.run == run) else None
