"""Health and control: a stage's counters (``health/<stage>``) and the control messages
``info/<stage>`` and ``eos/<stage>``."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import msgspec
import numpy as np

__all__ = ["Counters", "StageInfo", "EndOfStream"]

@dataclass
class Counters:
    """Health counters of one stage (published on ``health/<stage>``)."""

    received: int = 0
    accepted: int = 0
    rejected: int = 0
    duplicates: int = 0
    late: int = 0
    gaps: int = 0
    published: int = 0
    processed: int = 0
    restarts_resumed: int = 0
    latency_ms: deque = field(default_factory=lambda: deque(maxlen=10_000))

    def latency(self) -> dict[str, float | int | None]:
        if not self.latency_ms:
            return {"n": 0, "p50": None, "p99": None}
        a = np.fromiter(self.latency_ms, float)
        return {"n": int(a.size), "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99))}

    def as_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if k != "latency_ms"}
        d["latency_ms"] = self.latency()
        return d


class StageInfo(msgspec.Struct, kw_only=True):
    """``info/<stage>``: what a stage produces (cached for late joiners)."""

    stage: str
    run: str
    kind: str = ""
    metadata: dict[str, str] | None = None
    tracker: str = ""
    seed: int = 0
    pid: int = 0
    params: dict | None = None
    """The tracker's model parameters as resolved by :func:`pipeline.resolve.tracker_setup`
    (``ModelParams`` as builtins), so that a sink draws with exactly what the tracker used."""


class EndOfStream(msgspec.Struct, kw_only=True):
    """``eos/<stage>``: the stage produced (or, for a sink, recorded) everything it will.

    ``last_seq`` is the last sequence number of the stream (-1: empty), ``gaps`` the
    sequence numbers it declared missing, ``rejected`` those whose sample it received but
    refused (the tracker: a frame beyond the frame bounds; no output for them), ``error`` why
    the stream ended early (e.g. a truncated log), ``complete`` false when it was stopped
    before its input ended.
    """

    stage: str
    run: str
    last_seq: int
    frames: int = 0
    gaps: list[int] = []
    rejected: list[int] = []
    error: str = ""
    complete: bool = True
    files: list[str] = []


_INFO_DEC = msgspec.json.Decoder(StageInfo)
_EOS_DEC = msgspec.json.Decoder(EndOfStream)
#: Decoder of each control topic kind (``<kind>/<stage>``).
_CONTROL_DEC = {"eos": _EOS_DEC, "info": _INFO_DEC}
_JSON = msgspec.json.Encoder()


def missing_entries(gaps: Mapping[str, Iterable[int]], tracker_rejected: Iterable[int],
                    sink_rejected: Iterable[int], mismatched: Mapping[str, Iterable[int]]) -> list[dict[str, Any]]:
    """What a sink's ``tracks.mcap`` lacks, and why: one entry per (topic, reason) with the
    sequence numbers -- for ``sink.json``, the launcher's exit code 3 and its summary.
    ``gaps``: each stream's gaps; ``tracker_rejected``: frames the tracker rejected (their
    ``/tracks`` gap is that, not a loss); ``sink_rejected``: frames the sink rejected;
    ``mismatched``: per stream, messages dropped for naming another frame."""
    out: list[dict[str, Any]] = []
    by_tracker = set(tracker_rejected)

    def add(topic: str, seqs: Iterable[int], why: str) -> None:
        seqs = sorted(set(seqs))
        if seqs:
            out.append({"topic": f"/{topic}", "seqs": seqs, "why": why})

    for name, stream_gaps in gaps.items():
        add(name, [g for g in stream_gaps if g not in by_tracker],
            "never received (gap)" if name != "tracks" else "no /tracks from the tracker (gap)")
    add("tracks", by_tracker, "the tracker rejected the frame (frame bounds; each reason is in health.jsonl)")
    add("measurements", sink_rejected, "the sink rejected the frame (frame bounds; none of its messages were written)")
    for name, seqs in mismatched.items():
        add(name, seqs, "for another frame than its /measurements (dropped)")
    return out
