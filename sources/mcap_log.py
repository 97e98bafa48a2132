"""MCAP measurement logs: read frames/truth/tracks back robustly.

The files are written by :class:`sinks.mcap_writer.McapLogWriter` (layout in its module and
in docs/formats.md): one ``Metadata`` record named :data:`METADATA_NAME`
(``"bnptrack.scenario"``), channels ``/measurements``, ``/truth``, ``/tracks`` with JSON
messages of the contract :mod:`tracker.messages`.

Reading streams the file record by record (``mcap.stream_reader.StreamReader``; no index or
footer needed), so a truncated or corrupt file yields every readable frame and *then*
raises :class:`McapLogError`, naming the file, the last good frame, the message count and
the byte offset.  Invalid messages (bad schema, NaN, wrong field) and non-monotonic frame
indices on ``/measurements`` raise :class:`McapLogError` too, wrapping the
:class:`~tracker.messages.CodecError` that names topic and frame.  Unknown topics are ignored;
files without the metadata record and without ``/truth`` read fine.  Reading stops at the
``DataEnd`` record, so a file whose summary section is damaged still reads completely.
"""

from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator

from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.reader import SeekingReader
from mcap.records import Channel, DataEnd, Message, Metadata
from mcap.stream_reader import StreamReader

from bnptrack.tracker.messages import (
    METADATA_NAME,
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    CodecError,
    MeasurementsMsg,
    TruthMsg,
    decode,
    to_estimate,
    to_frame,
    to_truth,
)
from bnptrack.tracker.types import Estimate, Frame
from bnptrack.sources.channels import ChannelInfo, check_start, log_channels, record_limit as _record_limit
from bnptrack.sources.log_errors import McapLogError

__all__ = [
    "METADATA_NAME",
    "McapLogError",
    "LogContents",
    "iter_frames",
    "first_frames",
    "iter_tracks",
    "read_log",
    "read_metadata",
    "ChannelInfo",
    "log_channels",
    "missing_measurements_message",
]

_INPUT_TOPICS = frozenset({TOPIC_MEASUREMENTS, TOPIC_TRUTH})


# --------------------------------------------------------------------------- errors


class _StreamFailure(Exception):
    """Internal: the record stream broke (truncated or corrupt)."""

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(reason)
        self.kind = kind
        self.reason = reason


# --------------------------------------------------------------------------- reading


class _Scanner:
    """Stream the records of one file, decoding messages of the wanted topics.

    Yields ``(topic, msg)`` and, when ``want_metadata``, ``(None, Metadata)``.  Raises
    :class:`CodecError` for an invalid message and :class:`_StreamFailure` when the record
    stream breaks.  ``offset`` / ``n_messages`` describe the progress so far.
    """

    def __init__(self, path: str | os.PathLike, topics: Iterable[str], want_metadata: bool = False,
                 topic_map: dict[str, str] | None = None):
        self.path = os.fspath(path)
        self.topics = frozenset(topics)
        self.topic_map = dict(topic_map or {})
        """Channel topic -> the topic it is read as (``--topic /radar/detections=/measurements``)."""
        self.shadowed = frozenset(self.topic_map.values()) - frozenset(self.topic_map)
        """The log's own channels a mapped channel stands in for (its ``/measurements`` under
        ``--topic /radar/detections=/measurements``): not read."""
        self.want_metadata = want_metadata
        self.offset = 0
        self.n_messages = 0

    def __iter__(self) -> Iterator[tuple[str | None, Any]]:
        try:
            f = open(self.path, "rb")
        except OSError as exc:
            raise McapLogError(self.path, "corrupt", 0, 0, None, f"cannot open: {exc}") from exc
        with f:
            size = os.fstat(f.fileno()).st_size
            check_start(f, size, self.path)
            reader = StreamReader(f, validate_crcs=True, record_size_limit=_record_limit(size))
            records = reader.records
            channels: dict[int, Channel] = {}
            topics = self.topics
            while True:
                self.offset = f.tell()
                try:
                    rec = next(records)
                except StopIteration:
                    return
                except Exception as exc:  # anything the mcap library raises on bad bytes
                    raise self._failure(exc, f, size) from exc
                if isinstance(rec, Message):
                    self.n_messages += 1
                    ch = channels.get(rec.channel_id)
                    if ch is None:
                        raise _StreamFailure(
                            "corrupt", f"message refers to unknown channel id {rec.channel_id}"
                        )
                    topic = self.topic_map.get(ch.topic, ch.topic)
                    if topic not in topics or ch.topic in self.shadowed:
                        continue
                    if ch.message_encoding != "json":
                        raise CodecError(
                            topic,
                            None,
                            f"unsupported message encoding {ch.message_encoding!r} (expected 'json')",
                        )
                    yield topic, decode(topic, rec.data)
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Metadata):
                    if self.want_metadata:
                        yield None, rec
                elif isinstance(rec, DataEnd):
                    self.offset = f.tell()
                    return

    @staticmethod
    def _failure(exc: Exception, f: io.BufferedReader, size: int) -> _StreamFailure:
        at_end = f.tell() >= size
        if isinstance(exc, (EndOfFile, struct.error)) or (at_end and not isinstance(exc, InvalidMagic)):
            detail = "" if isinstance(exc, EndOfFile) else f"; {type(exc).__name__}: {exc}"
            return _StreamFailure(
                "truncated", f"unexpected end of file (file has {size} bytes{detail})"
            )
        return _StreamFailure("corrupt", f"{type(exc).__name__}: {exc}")


class _FramePairer:
    """Pair ``/measurements`` with ``/truth`` of the same frame index, in order.

    A frame is released as soon as both halves are seen, or (without truth) when the next
    frame's measurements arrive or the stream ends.  A truth waits for its measurements until
    measurements of a later frame number arrive; a truth whose frame never comes is dropped.
    A frame number that does not advance (repeated, or back) is passed on all the same: the
    reader of the frames skips it by the frame bounds (:class:`tracker.types.FrameGate`), as a
    stamp that goes back.
    """

    def __init__(self) -> None:
        self.pending: MeasurementsMsg | None = None
        self.truths: dict[int, TruthMsg] = {}
        self.saw_truth = False

    def add_measurements(self, msg: MeasurementsMsg) -> list[tuple[MeasurementsMsg, TruthMsg | None]]:
        out: list[tuple[MeasurementsMsg, TruthMsg | None]] = []
        if self.pending is not None:
            out.append((self.pending, None))
            self.pending = None
        if self.truths:
            truth = self.truths.pop(msg.frame, None)
            for k in [k for k in self.truths if k < msg.frame]:
                del self.truths[k]
        else:
            truth = None
        if truth is not None:
            out.append((msg, truth))
        else:
            self.pending = msg
        return out

    def add_truth(self, msg: TruthMsg) -> list[tuple[MeasurementsMsg, TruthMsg | None]]:
        self.saw_truth = True
        if self.pending is not None and self.pending.frame == msg.frame:
            pair = (self.pending, msg)
            self.pending = None
            return [pair]
        if msg.frame not in self.truths:  # measurements of a later frame number drop it
            self.truths[msg.frame] = msg
        return []

    def finish(self, complete_only: bool) -> list[tuple[MeasurementsMsg, TruthMsg | None]]:
        """Release the pending frame.  With ``complete_only`` (the stream broke), a frame
        whose truth may have been lost (the file has /truth) is dropped instead."""
        pending, self.pending = self.pending, None
        self.truths.clear()
        if pending is None or (complete_only and self.saw_truth):
            return []
        return [(pending, None)]


def _iter_log(
    path: str | os.PathLike, topics: Iterable[str], want_metadata: bool = False,
    topic_map: dict[str, str] | None = None,
) -> Iterator[tuple[str, Any]]:
    """Yield ``("frame", (meas, truth|None))``, ``("tracks", TracksMsg)`` and
    ``("metadata", dict)`` events in file order; raise McapLogError at the first problem."""
    scanner = _Scanner(path, topics, want_metadata, topic_map)
    pairer = _FramePairer()
    want_frames = TOPIC_MEASUREMENTS in scanner.topics
    last_frame: int | None = None
    try:
        for topic, item in scanner:
            if topic == TOPIC_MEASUREMENTS:
                ready = pairer.add_measurements(item)
            elif topic == TOPIC_TRUTH:
                ready = pairer.add_truth(item)
            elif topic == TOPIC_TRACKS:
                if not want_frames:
                    last_frame = item.frame
                yield "tracks", item
                continue
            else:
                if item.name == METADATA_NAME:
                    yield "metadata", dict(item.metadata)
                continue
            for pair in ready:
                last_frame = pair[0].frame
                yield "frame", pair
    except (CodecError, _StreamFailure) as exc:
        for pair in pairer.finish(complete_only=True):
            last_frame = pair[0].frame
            yield "frame", pair
        if isinstance(exc, CodecError):
            raise McapLogError(
                scanner.path, "invalid", scanner.offset, scanner.n_messages, last_frame,
                str(exc), exc.topic, exc.frame,
            ) from exc
        raise McapLogError(
            scanner.path, exc.kind, scanner.offset, scanner.n_messages, last_frame, exc.reason
        ) from exc.__cause__
    for pair in pairer.finish(complete_only=False):
        yield "frame", pair


def _pair_to_frame(pair: tuple[MeasurementsMsg, TruthMsg | None]) -> Frame:
    meas, truth = pair
    return to_frame(meas, to_truth(truth) if truth is not None else None)


def iter_frames(path: str | os.PathLike, topic_map: dict[str, str] | None = None) -> Iterator[Frame]:
    """Yield the frames of a log in order, with ``.truth`` from ``/truth`` when present.

    ``topic_map`` reads a channel as another topic (``{"/radar/detections": "/measurements"}``:
    its payload must still follow the contract).  Raises :class:`McapLogError` after the last
    readable frame if the file is truncated, corrupt, holds an invalid message or a
    non-increasing frame index on ``/measurements``.

    A channel of ``topic_map`` whose messages are of a ROS 2 / Foxglove type of
    :data:`sources.readers.READERS` (``{"/radar/scan": "/measurements"}``) is read by
    :func:`sources.robot_log.iter_robot_frames`; :class:`ValueError` (one line listing the
    trackable channels) for a channel bnptrack cannot read.
    """
    if topic_map:
        from bnptrack.sources.robot_log import iter_robot_frames, robot_topics

        robot = robot_topics(path, topic_map)
        if robot:
            yield from iter_robot_frames(path, robot)
            return
    for _, pair in _iter_log(path, _INPUT_TOPICS, topic_map=topic_map):
        yield _pair_to_frame(pair)


def first_frames(path: str | os.PathLike, topic_map: dict[str, str] | None = None, n: int = 200) -> list[Frame]:
    """Up to the first ``n`` frames of a log (:func:`iter_frames`), read before a run to check
    them.  A log whose first ``/measurements`` message does not decode (e.g. a channel mapped
    with ``--topic SRC=/measurements`` that holds another message type) raises
    :class:`McapLogError` (kind ``"invalid"``); any later problem only ends the list there
    (the run reports it where it stops)."""
    out: list[Frame] = []
    frames = iter_frames(path, topic_map)
    try:
        for frame in frames:
            out.append(frame)
            if len(out) >= n:
                break
    except McapLogError as exc:
        if exc.kind == "invalid" and not out and exc.topic == TOPIC_MEASUREMENTS:
            raise
    finally:
        frames.close()
    return out


def iter_tracks(path: str | os.PathLike) -> Iterator[Estimate]:
    """Yield the ``/tracks`` estimates of a log in file order (errors as :func:`iter_frames`)."""
    for _, msg in _iter_log(path, {TOPIC_TRACKS}):
        yield to_estimate(msg)


@dataclass
class LogContents:
    """Everything :func:`read_log` found in a file."""

    path: str
    metadata: dict[str, str] | None
    frames: list[Frame] = field(default_factory=list)
    tracks: list[Estimate] = field(default_factory=list)
    #: The error that ended reading early (only with ``strict=False``).
    error: McapLogError | None = None


def read_log(path: str | os.PathLike, strict: bool = True) -> LogContents:
    """Read a whole log (metadata, frames with truth, tracks) in one pass.

    With ``strict=False`` a truncated/invalid file returns what was readable, with the
    error in ``.error``, instead of raising.
    """
    out = LogContents(path=os.fspath(path), metadata=None)
    try:
        for kind, item in _iter_log(path, {TOPIC_MEASUREMENTS, TOPIC_TRUTH, TOPIC_TRACKS}, True):
            if kind == "frame":
                out.frames.append(_pair_to_frame(item))
            elif kind == "tracks":
                out.tracks.append(to_estimate(item))
            elif out.metadata is None:
                out.metadata = item
    except McapLogError as exc:
        if strict:
            raise
        out.error = exc
    return out


def read_metadata(path: str | os.PathLike) -> dict[str, str] | None:
    """The ``bnptrack.scenario`` metadata record, or ``None`` when the file has none.

    Uses the summary index when the file has a complete one, else streams the file (without
    decompressing chunks).  A file that is damaged after the record still returns it; a file
    that is damaged before any record is found returns ``None``; a file that is not MCAP at
    all raises :class:`McapLogError`.
    """
    spath = os.fspath(path)
    try:
        f = open(spath, "rb")
    except OSError as exc:
        raise McapLogError(spath, "corrupt", 0, 0, None, f"cannot open: {exc}") from exc
    with f:
        size = os.fstat(f.fileno()).st_size
        limit = _record_limit(size)
        # Fast path: a complete summary that indexes every metadata record.
        try:
            summary = SeekingReader(f, record_size_limit=limit).get_summary()
        except Exception:
            summary = None
        if (
            summary is not None
            and summary.statistics is not None
            and summary.statistics.metadata_count == len(summary.metadata_indexes)
        ):
            try:
                for index in summary.metadata_indexes:
                    if index.name != METADATA_NAME:
                        continue
                    f.seek(index.offset)
                    rec = next(StreamReader(f, skip_magic=True, record_size_limit=limit).records)
                    if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
                        return dict(rec.metadata)
                    break  # index does not point at the record: fall back to streaming
                else:
                    return None
            except Exception:
                pass
        # Slow path: stream the data section.
        f.seek(0)
        records = StreamReader(f, emit_chunks=True, record_size_limit=limit).records
        while True:
            try:
                rec = next(records)
            except StopIteration:
                return None
            except InvalidMagic as exc:
                raise McapLogError(spath, "corrupt", 0, 0, None, f"not an MCAP file: {exc}") from exc
            except Exception:
                return None
            if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
                return dict(rec.metadata)
            if isinstance(rec, DataEnd):
                return None


# --------------------------------------------------------------------------- channels


def missing_measurements_message(path: str | os.PathLike, channels: list[ChannelInfo],
                                 topic_item: str = "--topic {}") -> str:
    """The error for a log without a ``/measurements`` channel: its channels and how to map one
    (``topic_item``: how the caller gives a channel, the command line's ``--topic {}`` or a
    Python call's ``topics=['{}']``).  A log with no channel at all has no frames, and says so."""
    if not channels:
        return f"{os.fspath(path)} has no channels: the log has no frames, so there is nothing to track"
    listing = "; ".join(f"{c.topic} ({c.schema or 'no schema'}, {c.message_encoding}, {c.messages} messages)"
                        for c in channels) or "none"
    from bnptrack.sources.channels import trackable_listing

    robot = trackable_listing(channels)
    if robot != "none":
        return (f"{os.fspath(path)} has no {TOPIC_MEASUREMENTS} channel; choose its measurements with {topic_item.format('CHANNEL')}. "
                f"Trackable channels: {robot}")
    example = next((c.topic for c in channels if c.topic not in (TOPIC_TRUTH, TOPIC_TRACKS)), "/radar/detections")
    return (f"{os.fspath(path)} has no {TOPIC_MEASUREMENTS} channel, so there is nothing to track. "
            f"Its channels: {listing}. To read a channel as the measurements, map it: "
            f"{topic_item.format(f'{example}={TOPIC_MEASUREMENTS}')} (its payload must still follow the "
            f"/measurements contract of docs/formats.md: JSON, frame, stamp_ns, sensor, kind, z)")
