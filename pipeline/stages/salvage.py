"""What a restarted stage does when its upstream is gone: :class:`UpstreamWatch` says when
(no live upstream stage for ``delivery.upstream_gone_s`` seconds and no publisher's cache
answers), :func:`salvage_part` recovers the frames an earlier sink process wrote to its
``.tracks.mcap.part`` before it was killed, and :class:`UpstreamGone` is the stage's error
when it has nothing at all (docs/pipeline.md, "Restart at any moment")."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bnptrack.pipeline.stages.delivery import GAP, NO_TRUTH, Accepted
from bnptrack.tracker.messages import TOPIC_MEASUREMENTS, TOPIC_TRACKS, TOPIC_TRUTH, CodecError, decode

__all__ = ["UpstreamGone", "UpstreamWatch", "SalvagedFrame", "Salvage", "salvage_part", "missing_tail"]

log = logging.getLogger("bnptrack.stage")


class UpstreamGone(Exception):
    """A restarted stage found its upstream gone and has nothing to finalize: the stage
    exits 2 with this one line (it names the run and the missing upstream)."""


class UpstreamWatch:
    """Whether a restarted stage is alone: none of the stages ``upstream`` (names of
    liveliness tokens) has been alive for ``after`` seconds on the stage's clock, and no
    publisher's cache answers for ``topics`` (``Bus.head``; asked only once the time is up).
    The count starts at the first call that finds no upstream alive (or at construction), not
    at the last call that found one: a stage whose polls lag never stops waiting early.  Any
    live upstream, or a cache that answers, starts the count again."""

    def __init__(self, bus: Any, upstream: Iterable[str], topics: Iterable[str], after: float,
                 monotonic: Callable[[], float]) -> None:
        self.bus = bus
        self.upstream = tuple(upstream)
        self.topics = tuple(topics)
        self.after = float(after)
        self._monotonic = monotonic
        self.since: float | None = monotonic()  # absent since (None: an upstream is alive)

    def gone(self) -> bool:
        now = self._monotonic()
        if set(self.upstream) & self.bus.alive():
            self.since = None
            return False
        if self.since is None:
            self.since = now
        if now - self.since < self.after:
            return False
        if any(self.bus.head(t) is not None for t in self.topics):  # a cache still holds the run
            self.since = now
            return False
        return True

    def reason(self) -> str:
        """Why the stage stops waiting (the ``why`` of what it lacks)."""
        return (f"upstream gone before the end of stream: no live {' or '.join(self.upstream)} for "
                f"{self.after:g} s and no cache holds the rest of the run")


def missing_tail(streams: Iterable[str], first: int, source_eos: Any, why: str) -> list[dict[str, Any]]:
    """What a sink that stopped waiting (its upstream gone) lacks: each stream's frames from
    ``first`` (the first one not written) on -- every seq up to the source's end of stream
    when it is known; else ``seqs`` is empty and ``from_seq`` says where the rest of the run,
    of unknown length, starts (``missing`` entries of ``sink.json``)."""
    seqs = list(range(first, source_eos.last_seq + 1)) if source_eos is not None else []
    if source_eos is not None and not seqs:
        return []
    return [{"topic": f"/{name}", "seqs": seqs, "from_seq": first, "why": why} for name in streams]


@dataclass
class SalvagedFrame:
    """One frame recovered from a ``.part`` MCAP file: each topic's payload as written
    (``None``: not in the file) and the frame number and time stamp."""

    frame: int
    stamp_ns: int
    payloads: dict[str, bytes] = field(default_factory=dict)

    def items(self, seq: int, tracks: bool) -> tuple[Any, Any, Any]:
        """The frame as the sink's (measurements, truth, tracks) items of sequence number
        ``seq`` (:data:`GAP` / :data:`NO_TRUTH` for what the file lacks; tracks ``None``
        when the sink records none)."""
        def item(topic: str, missing: Any) -> Any:
            if topic not in self.payloads:
                return missing
            return Accepted(seq, decode(topic, self.payloads[topic]), {}, 0, self.payloads[topic])

        return (item(TOPIC_MEASUREMENTS, GAP), item(TOPIC_TRUTH, NO_TRUTH),
                item(TOPIC_TRACKS, GAP) if tracks else None)


@dataclass
class Salvage:
    """What :func:`salvage_part` recovered: the file's metadata record and its complete frames."""

    metadata: dict[str, str] | None
    frames: list[SalvagedFrame]


def _records(path: Path) -> Iterator[Any]:
    """The MCAP records of ``path`` (CRCs checked) up to the first damaged one: a file cut
    by a killed writer ends there."""
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as f:
        records = StreamReader(f, validate_crcs=True).records
        while True:
            try:
                yield next(records)
            except StopIteration:
                return
            except Exception as exc:  # the cut (or damaged) end of the file
                log.info("salvage: %s ends after %d bytes: %s", path, f.tell(), type(exc).__name__)
                return


def salvage_part(path: str | Path, run: str) -> Salvage | None:
    """The frames of run ``run`` that an earlier (killed) sink process wrote to the ``.part``
    MCAP file ``path``, in order, each as the payloads it wrote (``None``: no such file, or a
    file of another run).  The sink writes a frame's ``/tracks`` last, so the last frame read
    is dropped when it has none, unless the file ended cleanly: the cut may have fallen
    between its messages.  Payloads that do not decode end the salvage."""
    from mcap.records import Channel, DataEnd, Message, Metadata

    from bnptrack.tracker.messages import METADATA_NAME

    path = Path(path)
    if not path.is_file():
        return None
    topics: dict[int, str] = {}
    metadata: dict[str, str] | None = None
    frames: list[SalvagedFrame] = []
    clean = False
    for rec in _records(path):
        if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
            metadata = dict(rec.metadata)
        elif isinstance(rec, Channel):
            topics[rec.id] = rec.topic
        elif isinstance(rec, Message) and topics.get(rec.channel_id) in _TOPICS:
            if not _add(frames, topics[rec.channel_id], rec):
                break
        elif isinstance(rec, DataEnd):
            clean = True
            break
    if metadata is not None and metadata.get("run", run) != run:
        log.warning("salvage: %s is of run %r, not %r: not recovered", path, metadata.get("run"), run)
        return None
    if frames and not clean and TOPIC_TRACKS not in frames[-1].payloads:
        frames.pop()  # the cut may have fallen between its messages (its /tracks come last)
    return Salvage(metadata, frames)


_TOPICS = (TOPIC_MEASUREMENTS, TOPIC_TRUTH, TOPIC_TRACKS)


def _add(frames: list[SalvagedFrame], topic: str, rec: Any) -> bool:
    """Add message ``rec`` of ``topic`` to its frame (a new one when its frame number
    differs from the last frame's); False when its payload does not decode."""
    try:
        msg = decode(topic, rec.data)
    except (CodecError, ValueError):
        return False
    if not frames or frames[-1].frame != msg.frame or topic in frames[-1].payloads:
        frames.append(SalvagedFrame(msg.frame, msg.stamp_ns))
    frames[-1].payloads[topic] = bytes(rec.data)
    return True
