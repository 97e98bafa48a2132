"""Recovery: the tracker's snapshot, the journal it relies on, the sink's ``.part`` files and
atomic writes (:func:`write_atomic`, on a thread: :class:`BackgroundWriter`)."""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import msgspec

from bnptrack.pipeline.journal import JOURNAL_NAME
from bnptrack.pipeline.stages.health import EndOfStream
from bnptrack.tracker.config import ConfigError

__all__ = ["SNAPSHOT_NAME", "SUMMARY_NAME", "JOURNAL_NAME", "Snapshot", "read_snapshot", "write_atomic",
           "BackgroundWriter", "part_path", "sync_parts", "commit_parts", "PRIOR_FIELDS", "keep_prior"]

log = logging.getLogger("bnptrack.stage")

SNAPSHOT_NAME = "tracker.snap"
SUMMARY_NAME = "sink.json"
SNAPSHOT_FORMAT = 2


def write_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: temp file in the same directory, fsync,
    ``os.replace``, fsync of the directory."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # disk full, I/O error: leave no temporary file behind
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _fsync_and_close(fds: Iterable[int]) -> None:
    """fsync then close each descriptor (all of them are closed, the first error raised)."""
    error: OSError | None = None
    for fd in fds:
        try:
            os.fsync(fd)
        except OSError as exc:
            error = error or exc
        finally:
            os.close(fd)
    if error is not None:
        raise error


def _close_all(fds: Iterable[int]) -> None:
    """Close each descriptor (errors ignored: nothing is left to do with them)."""
    for fd in fds:
        try:
            os.close(fd)
        except OSError:
            pass


class BackgroundWriter:
    """Write files atomically (:func:`write_atomic`) on a background thread, so that fsync
    stalls stay out of the frame loop.  ``submit`` replaces a pending write of the same path
    (only the newest snapshot matters); ``sync_first`` are file descriptors to fsync (and
    close) before the write, e.g. of a journal the snapshot relies on (the writer owns them
    from the call on: they are closed even when ``submit`` raises); ``flush`` waits until
    everything submitted is on disk and re-raises a write error."""

    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._pending: dict[Path, tuple[bytes, list[int]]] = {}
        self._busy = False
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self.writes = 0

    def submit(self, path: Path, data: bytes, sync_first: Iterable[int] = ()) -> None:
        new_fds = list(sync_first)  # ours from here on: closed on every path
        with self._cv:
            if self._error is not None:
                err, self._error = self._error, None
                _close_all(new_fds)
                raise err
            fds = self._pending[path][1] if path in self._pending else []
            self._pending[path] = (data, fds + new_fds)
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name="snapshot-writer", daemon=True)
                self._thread.start()
            self._cv.notify_all()

    def _loop(self) -> None:
        while True:
            with self._cv:
                while not self._pending:
                    self._cv.wait()
                path, (data, fds) = self._pending.popitem()
                self._busy = True
            try:
                _fsync_and_close(fds)
                write_atomic(path, data)
                self.writes += 1
            except BaseException as exc:  # surfaced by the next submit/flush
                log.error("could not write %s: %s", path, exc)
                with self._cv:
                    self._error = exc
            finally:
                with self._cv:
                    self._busy = False
                    self._cv.notify_all()

    def flush(self, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        with self._cv:
            while (self._pending or self._busy) and time.monotonic() < deadline:
                self._cv.wait(0.05)
            if self._error is not None:
                err, self._error = self._error, None
                raise err


class Snapshot(msgspec.Struct, kw_only=True):
    """``<out>/tracker.snap`` (msgpack): the tracker state after ``last_seq``.  The
    ``/tracks`` samples published up to then are in the journal (:mod:`pipeline.journal`),
    which a resumed tracker publishes again."""

    format: int = SNAPSHOT_FORMAT
    run: str
    tracker: str
    seed: int
    last_seq: int
    last_frame: int
    state: bytes
    gaps: list[int] = []
    counters: dict[str, int] = {}
    time_ns: int = 0
    last_stamp_ns: int | None = None
    rejected: list[int] = []
    eos: EndOfStream | None = None  # set once the tracker has finished the run
    frame_gate: tuple[int, int, int | None] = (0, -1, None)  # FrameGate.state(): skipped frames in a row
    lag: int = 0
    """The stage's ``tracker.lag``: ``state`` holds the fixed-lag window too
    (:mod:`pipeline.stages.tracker_output`)."""
    published_seq: int | None = None
    """The last ``/tracks`` sequence number published (``None``: ``last_seq``; with a lag, the
    one before the window's first frame): the journal is cut back to it on resume."""


def read_snapshot(path: str | os.PathLike) -> Snapshot:
    """Load a tracker snapshot (raises ConfigError on a damaged file)."""
    try:
        data = Path(path).read_bytes()
        snap = msgspec.msgpack.decode(data, type=Snapshot)
    except (OSError, msgspec.DecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the tracker snapshot: {exc}") from None
    if snap.format != SNAPSHOT_FORMAT:
        raise ConfigError(f"{path}: snapshot format {snap.format} is not supported ({SNAPSHOT_FORMAT})")
    return snap


def part_path(path: str | os.PathLike) -> Path:
    """Where the sink writes the output ``path`` until the run ends: ``.<name>.part`` beside
    it.  The final name appears only by :func:`commit_parts`, after ``sink.json``, so a
    finished output is never reopened (truncated) by a restarted sink."""
    path = Path(path)
    return path.with_name(f".{path.name}.part")


def sync_parts(paths: Iterable[str | os.PathLike]) -> None:
    """fsync the ``.part`` file of each output that has one."""
    for p in paths:
        try:
            fd = os.open(part_path(p), os.O_RDONLY)
        except FileNotFoundError:
            continue
        _fsync_and_close([fd])


def commit_parts(paths: Iterable[str | os.PathLike]) -> None:
    """Rename each output's ``.part`` file (closed, on disk) to its final name (atomic)."""
    paths = list(paths)
    done = False
    for p in paths:
        part = part_path(p)
        if part.exists():
            os.replace(part, p)
            done = True
    if done:
        _fsync_dir(Path(next(iter(paths))).parent)


def _fsync_dir(path: Path) -> None:
    try:
        dfd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


#: The fields of a tracker state that make its prior (kept by ``tracker.prior_from``): the
#: BNP trackers' concentration, discount and their accumulated (alpha, d) log-likelihood.
PRIOR_FIELDS = ("alpha", "d", "hyper_loglik")


def keep_prior(initial: Any, snap: Snapshot, tracker: str) -> Any:
    """``initial`` (a fresh state: no track) with the :data:`PRIOR_FIELDS` of the state in
    ``snap`` (an earlier run of the same tracker, with or without a lag); :class:`ConfigError`
    otherwise."""
    from bnptrack.pipeline.stages.tracker_output import inner_snapshot

    import dataclasses

    from bnptrack.tracker.state import restore

    if snap.tracker != tracker:
        raise ConfigError(f"tracker.prior_from: a snapshot of tracker {snap.tracker!r}, not {tracker!r}")
    if not all(hasattr(initial, f) for f in PRIOR_FIELDS):
        raise ConfigError(f"tracker.prior_from: the {tracker} tracker has no prior to keep "
                          f"({', '.join(PRIOR_FIELDS)})")
    old = restore(inner_snapshot(snap.state, snap.lag), type(initial))
    return dataclasses.replace(initial, **{f: getattr(old, f) for f in PRIOR_FIELDS})
