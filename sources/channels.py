"""The channels of an MCAP log (:class:`ChannelInfo`: topic, schema, encodings, message count)
and which of them bnptrack can track (:func:`trackable`: a reader of
:data:`sources.readers.READERS`).  :mod:`sources.mcap_log` re-exports :func:`log_channels`."""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, BinaryIO

from mcap.exceptions import InvalidMagic
from mcap.reader import SeekingReader
from mcap.records import Channel, DataEnd, Message, Schema
from mcap.stream_reader import StreamReader

from bnptrack.sources.log_errors import McapLogError
from bnptrack.sources.readers import ReaderEntry, reader_entry
from bnptrack.tracker.messages import TOPIC_MEASUREMENTS

__all__ = ["MCAP_MAGIC", "check_magic", "check_start", "ChannelInfo", "log_channels", "channel_list", "trackable", "trackable_listing", "record_limit"]


def record_limit(size: int) -> int:
    """Largest record length we try to read.

    A valid record never exceeds the file; a length that runs past the end of the file but
    is below this limit is read short and reported as truncation (the usual crash damage);
    absurd lengths (corrupt bytes) are refused without allocating them.
    """
    return max(size, 16 * 2**20)


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of a file: topic, schema name and encoding, message encoding, count and
    the first / last ``log_time`` (ns; ``None`` without messages)."""

    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    messages: int
    first_ns: int | None
    last_ns: int | None


def log_channels(path: str | os.PathLike) -> list[ChannelInfo]:
    """Every channel of an MCAP file with its message count (streams the whole file; a
    damaged tail ends the count).  Raises :class:`McapLogError` if the file cannot be opened
    or is not MCAP."""
    spath = os.fspath(path)
    try:
        f = open(spath, "rb")
    except OSError as exc:
        raise McapLogError(spath, "corrupt", 0, 0, None, f"cannot open: {exc}") from exc
    schemas: dict[int, Any] = {}
    chans: dict[int, Channel] = {}
    counts: dict[int, list] = {}
    with f:
        size = os.fstat(f.fileno()).st_size
        check_start(f, size, spath)
        reader = StreamReader(f, validate_crcs=False, record_size_limit=record_limit(size))
        try:
            for rec in reader.records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    chans[rec.id] = rec
                    counts.setdefault(rec.id, [0, None, None])
                elif isinstance(rec, Message) and rec.channel_id in counts:
                    c = counts[rec.channel_id]
                    c[0] += 1
                    c[1] = rec.log_time if c[1] is None else min(c[1], rec.log_time)
                    c[2] = rec.log_time if c[2] is None else max(c[2], rec.log_time)
                elif isinstance(rec, DataEnd):
                    break
        except InvalidMagic as exc:
            raise McapLogError(spath, "corrupt", 0, 0, None, f"not an MCAP file: {exc}") from exc
        except Exception as exc:  # a damaged tail: report what was read
            if not chans:  # nothing declared before the damage: a file cut short, not a log without channels
                raise McapLogError(spath, "truncated", 0, 0, None,
                                   f"the file ends after {size} bytes, before any channel is declared") from exc
    out = []
    for cid, ch in chans.items():
        sc = schemas.get(ch.schema_id)
        n, first, last = counts[cid]
        out.append(ChannelInfo(ch.topic, sc.name if sc else "", sc.encoding if sc else "",
                               ch.message_encoding, n, first, last))
    return out


def channel_list(path: str | os.PathLike) -> list[ChannelInfo]:
    """The channels of a log, from its summary when it has one (no message is read), else
    by streaming it (:func:`sources.mcap_log.log_channels`)."""
    try:
        with open(path, "rb") as f:
            summary = SeekingReader(f).get_summary()
    except Exception:
        summary = None
    if summary is None or summary.statistics is None:
        return log_channels(path)
    counts = summary.statistics.channel_message_counts
    out = []
    for cid, ch in summary.channels.items():
        sc = summary.schemas.get(ch.schema_id)
        out.append(ChannelInfo(ch.topic, sc.name if sc else "", sc.encoding if sc else "", ch.message_encoding,
                               counts.get(cid, 0), None, None))
    return out


#: The 8 bytes an MCAP file starts with.
MCAP_MAGIC = b"\x89MCAP0\r\n"


#: What a file that is not MCAP probably is, by its first bytes.
OTHER_FORMATS = ((b"RRF2", "a Rerun recording: `bnptrack view` opens it"),)


def check_magic(head: bytes, spath: str) -> None:
    """Raise :class:`McapLogError` ``not an MCAP file`` (kind ``not_mcap``) when ``head`` (the
    file's first bytes) does not start as an MCAP file does; a file cut within the magic is
    left to the reader (it reports it as truncated)."""
    if head[:len(MCAP_MAGIC)] != MCAP_MAGIC[:len(head)]:
        known = [what for magic, what in OTHER_FORMATS if head.startswith(magic)]
        raise McapLogError(spath, "not_mcap", 0, 0, None,
                           f"it starts with {head[:8]!r}, not the MCAP magic {MCAP_MAGIC!r}"
                           + (f" ({known[0]})" if known else ""))


def check_start(f: BinaryIO, size: int, spath: str) -> None:
    """:func:`check_magic` of an open file of ``size`` bytes (an empty file is not an MCAP
    file either), leaving the file at its start."""
    if size == 0:  # the reader would find no record, not a bad magic
        raise McapLogError(spath, "not_mcap", 0, 0, None, "the file is empty (0 bytes)")
    check_magic(f.read(len(MCAP_MAGIC)), spath)
    f.seek(0)


def trackable(channel: ChannelInfo) -> ReaderEntry | None:
    """The reader of a channel's messages, or ``None`` when bnptrack cannot track them."""
    return reader_entry(channel.schema, channel.message_encoding)


def trackable_listing(channels: Iterable[ChannelInfo]) -> str:
    """Every channel ``bnptrack info`` calls trackable, with its ``--topic``:
    ``/radar/scan (radar_msgs/msg/RadarScan -> bearing_range: --topic /radar/scan); ...``."""
    items = []
    for c in channels:
        if (e := trackable(c)) is not None:
            items.append(f"{c.topic} ({c.schema} -> {e.kind}: --topic {c.topic})")
        elif c.topic == TOPIC_MEASUREMENTS:
            items.append(f"{c.topic} (bnptrack measurements, read by default: --topic {c.topic} or no --topic)")
    return "; ".join(items) or "none"
