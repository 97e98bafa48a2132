"""The tracker stage's output journal: every ``/tracks`` sample it published, on disk.

A Zenoh publisher's cache lives and dies with its process.  When the tracker is killed and
restarted, its new publisher starts with an empty cache, so a consumer that (re)joins later
(a sink restarted after the tracker was) could not get the tracks of the frames before the
restart.  The journal closes that hole: the tracker appends each sample it publishes, and a
restarted tracker publishes the journal again (its newest ``keep`` records up to its last
snapshot) before it goes on, so its cache holds what it held before the restart.

File format (``<out>/tracker.journal``): a sequence of records, each
``uint32 length | uint32 crc32(body) | body`` (little endian), ``body`` the msgpack of
``[seq, payload, meta]``.  Reading stops at the first incomplete or damaged record (a
process killed in the middle of a write), so the readable prefix is always usable.

Consistency with the snapshot: for each frame the tracker publishes the sample, then
advances its state, then appends the record (buffered), all before the next frame or snapshot;
:meth:`TracksJournal.dup_fd` flushes the journal and lets the snapshot writer fsync it
before it writes each snapshot, so every frame a snapshot covers is in the journal.  A record
lost with a killed process is after the last snapshot: it is recomputed anyway.  On resume,
:meth:`TracksJournal.resume` cuts the journal back to the snapshot (the frames after it are
recomputed, identically, and appended again).
The journal keeps at most ``2 * keep`` records: it is compacted to the newest ``keep``
(``delivery.cache_frames``: no cache holds more) when it grows past that.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import msgspec

__all__ = ["JOURNAL_NAME", "JournalRecord", "TracksJournal", "read_journal"]

JOURNAL_NAME = "tracker.journal"

_HEAD = struct.Struct("<II")
#: Write buffer of the journal file: records (~6 KB of ``/tracks`` each for vo2017) reach the OS
#: in batches, not one ``write`` system call per record as with the default 8 KiB buffer; a
#: snapshot flushes it first (:meth:`TracksJournal.dup_fd`), so what it covers is never in it.
BUFFER = 256 * 1024
#: Largest record accepted on reading (a damaged length field must not allocate gigabytes).
MAX_RECORD = 64 * 2**20


@dataclass(frozen=True)
class JournalRecord:
    """One published ``/tracks`` sample and where its record ends in the file."""

    seq: int
    payload: bytes
    meta: dict
    end: int


def _encode(seq: int, payload: bytes, meta: dict) -> bytes:
    body = msgspec.msgpack.encode([seq, payload, meta])
    return _HEAD.pack(len(body), zlib.crc32(body)) + body


def _decode(body: bytes) -> tuple[int, bytes, dict] | None:
    try:
        seq, payload, meta = msgspec.msgpack.decode(body)
    except (msgspec.DecodeError, ValueError, TypeError):
        return None
    if not isinstance(seq, int) or not isinstance(payload, bytes) or not isinstance(meta, dict):
        return None
    return seq, payload, meta


def read_journal(path: str | os.PathLike) -> list[JournalRecord]:
    """The readable records of a journal, in file order (``[]`` if there is no file)."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return []
    out: list[JournalRecord] = []
    pos = 0
    while pos + _HEAD.size <= len(data):
        n, crc = _HEAD.unpack_from(data, pos)
        start, end = pos + _HEAD.size, pos + _HEAD.size + n
        if n > MAX_RECORD or end > len(data):
            break
        body = data[start:end]
        rec = _decode(body) if zlib.crc32(body) == crc else None
        if rec is None:
            break
        out.append(JournalRecord(rec[0], rec[1], rec[2], end))
        pos = end
    return out


class TracksJournal:
    """Append-only journal of published ``/tracks`` samples (see the module docstring)."""

    def __init__(self, path: str | os.PathLike, keep: int) -> None:
        if keep < 1:
            raise ValueError("keep must be >= 1")
        self.path = Path(path)
        self.keep = int(keep)
        self._file: BinaryIO | None = None
        self._ends: list[int] = []  # end offset of each record in the file
        self._base = 0  # where the first record starts (the file's size when no record is kept)

    def resume(self, through_seq: int) -> list[tuple[int, bytes, dict]]:
        """Open the journal after a restart: keep the records up to ``through_seq`` (the
        snapshot's last sequence number; -1: none), cut the rest, and return the newest
        ``keep`` of the kept samples (no publisher cache holds more), in sequence order.
        The records in the file are in sequence order with unique ``seq`` by construction:
        a resume cuts everything after the snapshot, and appends only add higher ones."""
        kept = [r for r in read_journal(self.path) if r.seq <= through_seq]
        cut = kept[-1].end if kept else 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "ab") as f:  # create if missing, then cut what the snapshot does not cover
            f.truncate(cut)
        self._ends = [r.end for r in kept]
        self._base = cut
        self._file = open(self.path, "ab", buffering=BUFFER)
        return [(r.seq, r.payload, r.meta) for r in kept[-self.keep:]]

    def start(self) -> None:
        """Open a new, empty journal (a fresh run)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb", buffering=BUFFER)
        self._ends = []
        self._base = 0

    def append(self, seq: int, payload: bytes, meta: dict) -> None:
        """Append one sample (buffered: :meth:`dup_fd` hands everything to the OS before a
        snapshot relies on it; a record lost with the process is after the last snapshot, so
        it is recomputed and appended again on resume).  Raises RuntimeError when the
        journal is not open (:meth:`start` or :meth:`resume` first; never reopened here,
        which would wipe the file)."""
        if self._file is None:
            raise RuntimeError(f"{self.path}: journal is not open (call start() or resume() first)")
        record = _encode(seq, payload, meta)
        self._file.write(record)
        # offsets kept here: BufferedWriter.tell() is an lseek system call per record
        self._ends.append((self._ends[-1] if self._ends else self._base) + len(record))
        if len(self._ends) > 2 * self.keep:
            self._compact()

    def dup_fd(self) -> int | None:
        """Flush the journal to the OS and return a duplicate descriptor of its file, for a
        background thread to fsync before it writes a snapshot that relies on it (then close
        it)."""
        f = self._file
        if f is None or f.closed:
            return None
        f.flush()
        return os.dup(f.fileno())

    def _compact(self) -> None:
        """Keep the newest ``keep`` records (atomic rewrite)."""
        first = self._ends[-self.keep - 1]  # end of the last record dropped
        self._file.close()  # (flushes)
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        with open(self.path, "rb") as src, open(tmp, "wb") as dst:
            src.seek(first)
            dst.write(src.read())
            dst.flush()
            os.fsync(dst.fileno())
        os.replace(tmp, self.path)
        self._ends = [e - first for e in self._ends[-self.keep:]]
        self._file = open(self.path, "ab", buffering=BUFFER)

    def close(self) -> None:
        f, self._file = self._file, None
        if f is not None:
            f.close()

    def __len__(self) -> int:
        return len(self._ends)
