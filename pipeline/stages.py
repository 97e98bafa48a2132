"""The pipeline's stage loops: source, tracker and sink around the pure pieces.

Nothing here imports zenoh.  A stage talks to a *bus* with the interface of
:class:`pipeline.transport.Bus` (``declare``, ``publish``, ``subscribe``, ``recv``,
``declare_alive``, ``alive``, ``wait_alive`` (liveliness tokens ``alive`` and ``ready``),
``dropped``, ``misses``, ``backlog``); the
tests and the benchmark's in-process baseline use :class:`pipeline.membus.MemoryBus`.

Delivery contract (see docs/pipeline.md):

* every data sample carries the codec's JSON payload (its ``run`` must be the stage's run)
  and an attachment ``{"seq": n, "t": publish_ns, "frame": k}``; ``seq`` numbers the
  source's frames 0, 1, 2, ... (``frame`` numbers may skip); ``/tracks`` of frame ``seq``
  carries the same ``seq``;
* a consumer validates each sample (:class:`Intake`: size, attachment, schema, NaN/inf,
  run id), rejects bad ones with a log line, a counter and a copy on ``deadletter``;
* a :class:`Sequencer` per stream drops duplicates, reorders within ``delivery.window``
  sequence numbers and declares a *gap* for a frame still missing when the window has
  moved past it (or after end of stream and ``eos_grace_s`` without progress); a frame
  arriving after its gap was declared is rejected as *late*.  All of this depends only on
  the order in which samples arrive, never on timing, except the end-of-stream grace;
* the tracker processes frames in sequence order (predicting through gaps), snapshots its
  state atomically every ``snapshot_every`` frames and on shutdown, and resumes from the
  snapshot when restarted.
"""

from __future__ import annotations

import base64
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from pipeline.codec import (
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    CodecError,
    decode_msg,
    encode_measurements,
    encode_tracks,
    encode_truth,
    estimate_from_msg,
    frame_from_msg,
    truth_from_msg,
)
from pipeline.journal import JOURNAL_NAME, TracksJournal
from pipeline.pipeline_config import DeliveryConfig, PipelineConfig, SourceConfig, TrackerStageConfig
from tracker.config import ConfigError
from tracker.types import Frame, FrameBounds

__all__ = [
    "EXIT_OK",
    "EXIT_CRASH",
    "EXIT_CONFIG",
    "EXIT_DATA",
    "EXIT_STOPPED",
    "EXIT_IO",
    "StageIOError",
    "GAP",
    "NO_TRUTH",
    "Sequencer",
    "Counters",
    "Intake",
    "Accepted",
    "StageInfo",
    "EndOfStream",
    "StageContext",
    "SourceStage",
    "TrackerStage",
    "SinkStage",
    "STAGES",
    "write_atomic",
    "read_snapshot",
    "SNAPSHOT_NAME",
    "JOURNAL_NAME",
    "SUMMARY_NAME",
]

log = logging.getLogger("bnptrack.stage")

#: Exit codes of a stage process (the launcher restarts only on EXIT_CRASH / signals).
EXIT_OK = 0
EXIT_CRASH = 1
EXIT_CONFIG = 2
EXIT_DATA = 3
EXIT_STOPPED = 130
#: A file could not be written (disk full, I/O error): restarting would not help.
EXIT_IO = 4


class StageIOError(OSError):
    """A stage could not write one of its files: the message names the stage and the file
    (``stage sink: cannot write /x/tracks.mcap: [Errno 28] No space left on device``)."""

    def __init__(self, stage: str, path: str | os.PathLike, exc: OSError) -> None:
        super().__init__(exc.errno, f"stage {stage}: cannot write {path}: {exc}")
        self.path = str(path)

    def __str__(self) -> str:
        return self.strerror

SNAPSHOT_NAME = "tracker.snap"
SUMMARY_NAME = "sink.json"
SNAPSHOT_FORMAT = 2

#: Topic (bus-relative) of each codec topic.
BUS_TOPIC = {TOPIC_MEASUREMENTS: "measurements", TOPIC_TRUTH: "truth", TOPIC_TRACKS: "tracks"}
CODEC_TOPIC = {v: k for k, v in BUS_TOPIC.items()}

#: Largest sequence number accepted (JSON-safe integer).
MAX_SEQ = 2**53
#: Bytes of a rejected payload copied to the dead-letter topic.
DEADLETTER_COPY = 64 * 1024


class _Marker:
    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    def __repr__(self) -> str:
        return self.name


#: A frame declared missing by a :class:`Sequencer`.
GAP = _Marker("GAP")
#: Placeholder in the sink's truth stream for a frame the source sent without truth.
NO_TRUTH = _Marker("NO_TRUTH")


# --------------------------------------------------------------------------- sequencing


class Sequencer:
    """Dedupe, reorder within a window, declare gaps: in-order release of ``seq`` items.

    ``push(seq, item)`` returns ``(status, released)`` where ``status`` is ``"accepted"``,
    ``"duplicate"`` (already released or buffered), ``"late"`` (its gap was declared) or
    ``"far"`` (``max_ahead`` or more past the next expected number: not accepted, nothing
    declared; ``max_ahead`` is at least ``catch_up``, default unbounded) and ``released`` a
    list of ``(seq, item)`` in sequence order, ``item`` being
    :data:`GAP` for a missing frame.  The buffer never spans ``window`` or more sequence
    numbers: a frame arriving ``window`` or more ahead of the next expected one releases
    (or declares missing) everything at least ``window`` behind it.  The result depends
    only on the order of the pushes.

    ``catch_up`` (default: ``window``) is the window used until the stream has *caught up*,
    i.e. until the buffer is empty for the first time and everything up to the publisher's
    announced live head (:meth:`hold_catch_up_through`) is released: a consumer that starts late or
    restarts receives the publishers' history (the frames from ``start`` on) and live frames
    at the same time, in no guaranteed order, and the live frames must not push the history
    out as gaps.  Consumers use the cache size: no history holds more.
    """

    def __init__(self, window: int, start: int = 0, name: str = "", catch_up: int | None = None,
                 max_ahead: int | None = None) -> None:
        if window < 1 or (catch_up is not None and catch_up < window):
            raise ValueError("window must be >= 1 and catch_up >= window")
        self.window = int(window)
        self.catch_up = int(catch_up) if catch_up is not None else self.window
        self.max_ahead = max(int(max_ahead), self.catch_up) if max_ahead is not None else None
        self.far = 0
        self.caught_up = False
        self.next = int(start)
        self.name = name
        self.buf: dict[int, Any] = {}
        self.gaps: list[int] = []
        self._gapset: set[int] = set()
        self.accepted = 0
        self.duplicates = 0
        self.late = 0
        self.max_seen = int(start) - 1
        self.catch_up_through = -1

    @classmethod
    def for_delivery(cls, delivery: DeliveryConfig, start: int, name: str) -> Sequencer:
        """A consumer's sequencer with the pipeline's ``window``, ``catch_up`` and
        ``max_seq_ahead``."""
        return cls(delivery.window, start, name, delivery.catch_up, delivery.max_seq_ahead)

    def push(self, seq: int, item: Any) -> tuple[str, list[tuple[int, Any]]]:
        seq = int(seq)
        if self.max_ahead is not None and seq - self.next >= self.max_ahead:
            # never declare (and allocate) max_ahead or more gaps at once for one sample
            self.far += 1
            return "far", []
        if seq < self.next:
            if seq in self._gapset:
                self.late += 1
                return "late", []
            self.duplicates += 1
            return "duplicate", []
        if seq in self.buf:
            self.duplicates += 1
            return "duplicate", []
        self.accepted += 1
        self.max_seen = max(self.max_seen, seq)
        out: list[tuple[int, Any]] = []
        window = self.window if self.caught_up else self.catch_up
        if seq >= self.next + window:
            out += self._advance_to(seq - window + 1)
        self.buf[seq] = item
        out += self._release()
        self.caught_up = self.caught_up or (not self.buf and self.next > self.catch_up_through)
        return "accepted", out

    def hold_catch_up_through(self, head: int | None) -> None:
        """The publisher's announced live head: the history a (re)joining consumer receives
        ends there, so the catch-up window holds until everything up to ``head`` is released
        (not merely until the buffer is empty once)."""
        if head is None:
            return
        self.catch_up_through = max(self.catch_up_through, int(head))
        if self.next <= self.catch_up_through:
            self.caught_up = False

    def _advance_to(self, target: int) -> list[tuple[int, Any]]:
        out: list[tuple[int, Any]] = []
        while self.next < target:
            s = self.next
            if s in self.buf:
                out.append((s, self.buf.pop(s)))
            else:
                self.gaps.append(s)
                self._gapset.add(s)
                out.append((s, GAP))
            self.next += 1
        return out

    def _release(self) -> list[tuple[int, Any]]:
        out: list[tuple[int, Any]] = []
        while self.next in self.buf:
            out.append((self.next, self.buf.pop(self.next)))
            self.next += 1
        return out

    def mark_gaps(self, seqs: Iterable[int]) -> list[tuple[int, Any]]:
        """Declare ``seqs`` missing now (e.g. the gaps an upstream stage reported)."""
        for s in sorted(set(int(x) for x in seqs)):
            if s >= self.next and s not in self.buf:
                self.buf[s] = GAP
                self.gaps.append(s)
                self._gapset.add(s)
        return self._release()

    def flush_through(self, last: int) -> list[tuple[int, Any]]:
        """Release everything up to ``last`` (inclusive), declaring what is missing."""
        return self._advance_to(int(last) + 1) + self._release()

    def complete_through(self, last: int) -> bool:
        return self.next > last

    @property
    def pending(self) -> int:
        return len(self.buf)


class HoleWatch:
    """Says when to fetch what a stream misses: its next expected seq has not moved for
    ``after`` seconds while later frames wait in the buffer (the transport's history or
    recovery did not bring it); then again every ``after`` seconds."""

    def __init__(self, after: float) -> None:
        self.after = after
        self.next = -1
        self.since = time.monotonic()

    def due(self, seqr: Sequencer) -> bool:
        now = time.monotonic()
        if seqr.next != self.next:
            self.next, self.since = seqr.next, now
            return False
        if seqr.pending and now - self.since >= self.after:
            self.since = now
            return True
        return False


def fetch_holes(bus: Any, topic: str, seqr: Sequencer, upto: int, on_event: Callable[[Any], None]) -> int:
    """Fetch explicitly from the publisher's cache (:meth:`pipeline.transport.Bus.fetch`) the
    frames of ``topic`` that ``seqr`` still misses up to ``upto``, and hand each to
    ``on_event`` (validated like any sample).  Returns how many came back (0 without a
    fetch-capable bus or when nothing is missing)."""
    fetch = getattr(bus, "fetch", None)
    if fetch is None or upto < seqr.next:
        return 0
    hi = next((s for s in range(upto, seqr.next - 1, -1) if s not in seqr.buf), None)
    if hi is None:
        return 0
    events = fetch(topic, seqr.next, hi)
    for ev in events:
        on_event(ev)
    if events:
        log.info("%s: fetched %d %s sample(s) in %d-%d from the publisher's cache", bus.stage, len(events),
                 topic, seqr.next, hi)
    return len(events)


#: Seconds a stream's next frame may be missing, with later ones waiting, before it is fetched.
FETCH_AFTER_S = 1.0


# --------------------------------------------------------------------------- counters


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


# --------------------------------------------------------------------------- control messages


class StageInfo(msgspec.Struct, kw_only=True):
    """``info/<stage>``: what a stage produces (cached for late joiners)."""

    stage: str
    run: str
    kind: str = ""
    metadata: dict[str, str] | None = None
    tracker: str = ""
    seed: int = 0
    pid: int = 0


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


# --------------------------------------------------------------------------- intake


@dataclass(frozen=True)
class Accepted:
    """A validated data sample: sequence number, decoded message, attachment."""

    seq: int
    msg: Any
    meta: dict
    t_recv_ns: int
    payload: bytes


class Intake:
    """Validate incoming data samples; reject with a log line, a counter and a dead letter.

    ``check(event)`` returns :class:`Accepted` or ``None`` (rejected).  Checks, in order:
    payload size (``max_payload_bytes``), attachment (a JSON object with an integer
    ``seq`` in ``[0, 2**53)``), the codec (schema, version, finite values, sizes), the
    message's ``run`` (must be this run).
    """

    def __init__(self, stage: str, run: str, bus: Any, counters: Counters, max_payload_bytes: int) -> None:
        self.stage = stage
        self.run = run
        self.bus = bus
        self.counters = counters
        self.max_payload = max_payload_bytes
        self.rejected_by_topic: dict[str, int] = {}

    def check(self, ev: Any) -> Accepted | None:
        topic = ev.topic
        codec_topic = CODEC_TOPIC.get(topic)
        if codec_topic is None:
            return self.reject(ev, None, f"unexpected topic {topic!r}")
        if len(ev.payload) > self.max_payload:
            return self.reject(
                ev, None, f"payload of {len(ev.payload)} bytes exceeds the limit of {self.max_payload}"
            )
        meta = ev.meta
        if meta is None:
            return self.reject(ev, None, ev.meta_error or "missing attachment (sequence number)")
        seq = meta.get("seq")
        if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq < MAX_SEQ:
            return self.reject(ev, None, f"attachment seq must be an integer in [0, 2**53), got {seq!r}")
        try:
            msg = decode_msg(codec_topic, ev.payload)
        except CodecError as exc:
            return self.reject(ev, seq, str(exc))
        if msg.run != self.run:
            return self.reject(ev, seq, f"{codec_topic} frame {msg.frame}: run {msg.run!r} is not this run {self.run!r}")
        frame = meta.get("frame")
        if frame is not None and frame != msg.frame:
            return self.reject(ev, seq, f"{codec_topic}: attachment frame {frame!r} != payload frame {msg.frame}")
        return Accepted(seq, msg, meta, ev.t_recv_ns, ev.payload)

    def reject(self, ev: Any, seq: int | None, reason: str) -> None:
        self.counters.rejected += 1
        self.rejected_by_topic[ev.topic] = self.rejected_by_topic.get(ev.topic, 0) + 1
        n = self.counters.rejected
        if n <= 20 or n % 100 == 0:
            log.warning("%s: rejected %s sample (seq %s, %d bytes): %s [rejected so far: %d]",
                        self.stage, ev.topic, seq, len(ev.payload), reason, n)
        letter = {
            "stage": self.stage,
            "run": self.run,
            "topic": ev.topic,
            "seq": seq,
            "reason": reason,
            "size": len(ev.payload),
            "truncated": len(ev.payload) > DEADLETTER_COPY,
            "payload_b64": base64.b64encode(bytes(ev.payload[:DEADLETTER_COPY])).decode(),
            "t_ns": time.time_ns(),
        }
        try:
            self.bus.publish("deadletter", _JSON.encode(letter))
        except Exception as exc:  # the dead letter is best effort
            log.error("%s: could not publish a dead letter: %s", self.stage, exc)
        return None


# --------------------------------------------------------------------------- files


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
    ``snap`` (an earlier run of the same tracker); :class:`ConfigError` otherwise."""
    import dataclasses

    from tracker.state import restore

    if snap.tracker != tracker:
        raise ConfigError(f"tracker.prior_from: a snapshot of tracker {snap.tracker!r}, not {tracker!r}")
    if not all(hasattr(initial, f) for f in PRIOR_FIELDS):
        raise ConfigError(f"tracker.prior_from: the {tracker} tracker has no prior to keep "
                          f"({', '.join(PRIOR_FIELDS)})")
    old = restore(snap.state, type(initial))
    return dataclasses.replace(initial, **{f: getattr(old, f) for f in PRIOR_FIELDS})


# --------------------------------------------------------------------------- context


@dataclass
class StageContext:
    """What a stage needs: the (resolved) pipeline, its bus, a stop flag, its name."""

    cfg: PipelineConfig
    bus: Any
    stop: threading.Event = field(default_factory=threading.Event)
    name: str = ""

    @property
    def run(self) -> str:
        return self.cfg.run

    @property
    def out(self) -> Path:
        return Path(self.cfg.out)


class _StageBase:
    role = ""

    def __init__(self, ctx: StageContext) -> None:
        self.ctx = ctx
        self.cfg = ctx.cfg
        self.bus = ctx.bus
        self.name = ctx.name or self.role
        self.run_id = ctx.cfg.run
        self.counters = Counters()
        self.delivery = ctx.cfg.delivery
        self._next_health = 0.0
        self.eos_seen: dict[str, EndOfStream] = {}
        self.eos_time: dict[str, float] = {}  # when each end of stream arrived (monotonic)
        self.infos: dict[str, StageInfo] = {}

    # -- health ----------------------------------------------------------------------
    def health(self, force: bool = False, extra: dict | Callable[[], dict] | None = None) -> None:
        """Publish ``health/<stage>`` if due (every ``delivery.health_period_s``) or ``force``;
        ``extra`` (a dict, or a function returning one, called only when publishing) is
        merged in."""
        now = time.monotonic()
        if not force and now < self._next_health:
            return
        if callable(extra):
            extra = extra()
        self._next_health = now + self.delivery.health_period_s
        doc = {
            "stage": self.name,
            "role": self.role,
            "run": self.run_id,
            "pid": os.getpid(),
            "t_ns": time.time_ns(),
            "counters": self.counters.as_dict(),
            "dropped": int(getattr(self.bus, "dropped", 0)),
            "zenoh_misses": int(getattr(self.bus, "misses", 0)),
            "backlog": int(getattr(self.bus, "backlog", 0)),
        }
        if extra:
            doc.update(extra)
        try:
            self.bus.publish(f"health/{self.name}", _JSON.encode(doc))
        except Exception as exc:
            log.debug("%s: health publish failed: %s", self.name, exc)

    # -- control ---------------------------------------------------------------------
    def on_control(self, ev: Any) -> bool:
        """Handle ``info/*`` and ``eos/*``; True if the event was a control message."""
        kind, _, stage = ev.topic.partition("/")
        decoder = _CONTROL_DEC.get(kind)
        if decoder is None:
            return False
        try:
            msg = decoder.decode(ev.payload)
        except msgspec.DecodeError as exc:
            log.warning("%s: ignoring a malformed %s message: %s", self.name, ev.topic, exc)
            return True
        if msg.run != self.run_id:
            return True
        if kind == "info":
            self.infos[stage] = msg
            return True
        if stage not in self.eos_seen:
            self.eos_time[stage] = time.monotonic()
            log.info("%s: end of stream from %s (last seq %d%s)", self.name, stage, msg.last_seq,
                     f", error: {msg.error}" if msg.error else "")
        self.eos_seen[stage] = msg
        return True

    def publish_control(self, kind: str, obj: msgspec.Struct) -> None:
        self.bus.publish(f"{kind}/{self.name}", _JSON.encode(obj))

    def wait_done(self, stages: Iterable[str], poll: Callable[[Any], None] | None = None) -> bool:
        """Serve (keep the session and caches up) until every stage in ``stages`` has sent
        its end of stream, or stop.  Returns True if they all did."""
        want = set(stages)
        while not self.ctx.stop.is_set():
            if want <= set(self.eos_seen):
                return True
            ev = self.bus.recv(0.1)
            if ev is not None:
                if not self.on_control(ev) and poll is not None:
                    poll(ev)
            self.health()
        return want <= set(self.eos_seen)

    def serve_until_done_or_alone(self, stages: Iterable[str], at_least: float = 1.0) -> None:
        """Like :meth:`wait_done`, but also return once no other stage of the run is alive
        (after ``at_least`` seconds: a new session has not seen the others' tokens yet): a
        stage restarted after the others left has nobody to wait for."""
        want = set(stages)
        t0 = time.monotonic()
        while not self.ctx.stop.is_set() and not want <= set(self.eos_seen):
            if time.monotonic() - t0 >= at_least and not (self.bus.alive() - {self.name}):
                return
            ev = self.bus.recv(0.05)
            if ev is not None:
                self.on_control(ev)
            self.health()

    def linger_until_alone(self, timeout: float, at_least: float = 0.0) -> None:
        """Keep the session open until no other stage of the run is alive (so that our
        last messages are delivered), at most ``timeout`` seconds; ``at_least`` seconds in
        any case (a session just opened has not seen the others' tokens yet)."""
        t0 = time.monotonic()
        deadline = t0 + timeout
        while time.monotonic() < deadline and not self.ctx.stop.is_set():
            if not (self.bus.alive() - {self.name}) and time.monotonic() - t0 >= at_least:
                return
            ev = self.bus.recv(0.05)
            if ev is not None:
                self.on_control(ev)


# --------------------------------------------------------------------------- source


def source_frames(cfg: PipelineConfig) -> tuple[dict[str, str] | None, Iterator[Frame]]:
    """The source's metadata record and its frames (``source.frames`` limits them)."""
    sc = cfg.source
    if sc.kind == "synthetic":
        from pipeline.offline import (
            resolve_scenario,
            resolve_simulation_params,
            simulation_metadata,
        )
        from sources.synthetic import simulate

        try:
            scenario = resolve_scenario(sc.scenario, sc.seed, sc.overrides)
        except (KeyError, ValueError) as exc:
            raise ConfigError(f"source.scenario: {exc}") from None
        params = resolve_simulation_params(sc.scenario, sc.params, sc.overrides, sc.snr_db)
        metadata = simulation_metadata(scenario, sc.params, sc.seed, params, sc.overrides)
        frames: Iterator[Frame] = simulate(scenario, params, sc.seed, sensor=sc.sensor)
    else:
        from sources.mcap_log import McapLogError, iter_frames, read_metadata

        if not sc.log:
            raise ConfigError("source.log: an MCAP log is required when source.kind = 'mcap'")
        if not Path(sc.log).is_file():
            raise ConfigError(f"source.log: {sc.log}: no such file")
        try:
            metadata = read_metadata(sc.log)
        except McapLogError as exc:  # not an MCAP file at all: nothing to replay
            raise ConfigError(f"source.log: {exc}") from None
        frames = iter_frames(sc.log)
    frames = window_frames(frames, sc)
    if sc.frames:
        frames = islice(frames, sc.frames)
    return metadata, frames


def check_window(sc: SourceConfig) -> None:
    """Raise :class:`ConfigError` for a window (``start_*`` / ``end_*``) that mixes seconds and
    frames at one end or ends before it starts."""
    for end in ("start", "end"):
        if getattr(sc, f"{end}_s") is not None and getattr(sc, f"{end}_frame") is not None:
            raise ConfigError(f"source.{end}_s and source.{end}_frame: give the {end} in seconds or in "
                              "frames, not both")
    if sc.start_s is not None and sc.end_s is not None and sc.end_s < sc.start_s:
        raise ConfigError(f"source.end_s = {sc.end_s:g} is before source.start_s = {sc.start_s:g}")
    if sc.start_frame is not None and sc.end_frame is not None and sc.end_frame < sc.start_frame:
        raise ConfigError(f"source.end_frame = {sc.end_frame} is before source.start_frame = {sc.start_frame}")


def window_frames(frames: Iterator[Frame], sc: SourceConfig) -> Iterator[Frame]:
    """The frames of ``frames`` inside the source's window (see :class:`SourceConfig`):
    seconds count from the first frame's time stamp; the input is not read past the end."""
    check_window(sc)
    if sc.start_s is None and sc.end_s is None and sc.start_frame is None and sc.end_frame is None:
        return frames
    return _window(frames, sc)


def _window(frames: Iterator[Frame], sc: SourceConfig) -> Iterator[Frame]:
    stamp0 = None
    for frame in frames:
        if stamp0 is None:
            stamp0 = frame.stamp_ns
        t = (frame.stamp_ns - stamp0) / 1e9
        if (sc.end_s is not None and t > sc.end_s) or (sc.end_frame is not None and frame.frame > sc.end_frame):
            return
        if (sc.start_s is None or t >= sc.start_s) and (sc.start_frame is None or frame.frame >= sc.start_frame):
            yield frame


def build_stage_tracker(tc: TrackerStageConfig, metadata: dict[str, str] | None) -> tuple[Any, Any, Any]:
    """The tracker stage's tracker, as ``bnptrack track`` builds it: model parameters from
    ``tc.params`` or the source's metadata record, the settings preset or file, then the
    ``--set`` items of ``tc.overrides``.  Returns ``(tracker, ParamsChoice, params)``;
    raises :class:`ConfigError` (the launcher calls this before starting any process)."""
    from pipeline.offline import apply_split_overrides, build_tracker, resolve_config, resolve_params

    choice = resolve_params(tc.params or None, metadata)
    config, _desc = resolve_config(tc.tracker, tc.config or None)
    params, config = apply_split_overrides(choice.params, config, tc.overrides)
    return build_tracker(tc.tracker, params, config), choice, params


def _warm_imports(*modules: str) -> None:
    """Import what a stage needs before it declares itself alive, so the first frame is not
    delayed by imports (scipy, rerun: seconds on a busy machine)."""
    import importlib

    for m in modules:
        importlib.import_module(m)


def _warm_up(tracker: Any) -> None:
    """Run a few throw-away steps on dummy frames so that lazily compiled kernels (numba) and
    caches are ready before the first real frame; the tracker is a pure function of its
    inputs, so this changes no result (the real run starts from ``initial_state()``)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    try:
        for kind, base in (("bearing_range", np.array([[0.1, 500.0], [0.2, 800.0], [-0.3, 1200.0], [0.5, 300.0]])),
                           ("range", np.array([[500.0], [800.0], [1200.0]]))):
            state = tracker.initial_state()
            for k in range(1, 4):
                z = base + k * np.where(np.arange(base.shape[1]) == base.shape[1] - 1, 5.0, 0.001)
                state, _ = tracker.step(state, Frame(k, k * 10**9, "warm-up", kind, z), rng)
    except Exception as exc:  # a tracker without a range model, say: warm-up is optional
        log.debug("tracker warm-up skipped: %s", exc)
    log.debug("tracker warm-up took %.2f s", time.perf_counter() - t0)


class SourceStage(_StageBase):
    """Publish frames (``measurements`` + ``truth``), then end of stream; serve the cache
    until the ``done_by`` stages have finished."""

    role = "source"

    def run(self) -> int:
        sc = self.cfg.source
        bus = self.bus
        metadata, frames = source_frames(self.cfg)
        bus.declare(["measurements", "truth", f"info/{self.name}", f"eos/{self.name}"])
        bus.subscribe(["eos/*"])
        bus.declare_alive()
        self.publish_control("info", StageInfo(stage=self.name, run=self.run_id, kind=sc.kind,
                                               metadata=metadata, pid=os.getpid()))
        bus.declare_alive("ready")
        if sc.wait_for:
            log.info("%s: waiting for %s to be ready", self.name, ", ".join(sc.wait_for))
            deadline = time.monotonic() + sc.ready_timeout_s if sc.ready_timeout_s > 0 else math.inf
            missing = set(sc.wait_for)
            while not self.ctx.stop.is_set():
                missing = bus.wait_alive(sc.wait_for, min(0.2, max(0.0, deadline - time.monotonic())), "ready")
                if not missing or time.monotonic() >= deadline:
                    break
            if self.ctx.stop.is_set():
                return EXIT_STOPPED
            if missing:
                log.warning("%s: %s not ready after %.0f s; publishing anyway (they will get the "
                            "cache's history when they join)", self.name, ", ".join(sorted(missing)),
                            sc.ready_timeout_s)
        seq = -1
        error = ""
        t0 = time.monotonic()
        stamp0: int | None = None
        stopped = False
        try:
            for frame in frames:
                if self.ctx.stop.is_set():
                    stopped = True
                    break
                if sc.rate > 0:
                    if stamp0 is None:
                        stamp0 = frame.stamp_ns
                    due = t0 + (frame.stamp_ns - stamp0) / 1e9 / sc.rate
                    wait = due - time.monotonic()
                    if wait > 0 and self.ctx.stop.wait(wait):
                        stopped = True
                        break
                seq += 1
                has_truth = frame.truth is not None
                meas = encode_measurements(frame, self.run_id)
                truth = encode_truth(frame.frame, frame.stamp_ns, frame.truth, self.run_id) if has_truth else None
                t = time.time_ns()
                bus.publish("measurements", meas, {"seq": seq, "t": t, "frame": frame.frame, "truth": has_truth})
                if truth is not None:
                    bus.publish("truth", truth, {"seq": seq, "t": t, "frame": frame.frame})
                self.counters.published += 1
                self.health()
                while True:  # keep up with control messages without blocking
                    ev = bus.recv(0)
                    if ev is None:
                        break
                    self.on_control(ev)
        except Exception as exc:
            from sources.mcap_log import McapLogError

            if not isinstance(exc, McapLogError):
                raise
            error = str(exc)
            log.error("%s: %s", self.name, error)
        if stopped:
            log.info("%s: stopped after %d frame(s)", self.name, seq + 1)
            self.health(force=True)
            return EXIT_STOPPED
        eos = EndOfStream(stage=self.name, run=self.run_id, last_seq=seq, frames=seq + 1, error=error)
        self.publish_control("eos", eos)
        log.info("%s: published %d frame(s) in %.2f s; waiting for %s to finish", self.name, seq + 1,
                 time.monotonic() - t0, ", ".join(sc.done_by) or "nobody")
        self.health(force=True)
        done = self.wait_done(sc.done_by)
        self.health(force=True)
        if not done:
            return EXIT_STOPPED
        return EXIT_DATA if error else EXIT_OK


# --------------------------------------------------------------------------- tracker


class TrackerStage(_StageBase):
    """Track the ``measurements`` stream in sequence order and publish ``tracks``.

    Any tracker :func:`pipeline.offline.build_tracker` builds works (the state class comes
    from ``tracker.initial_state()``).  Frame ``k`` uses ``tracker.state.frame_rng(seed, k)``
    exactly like ``bnptrack track``, so the output depends only on the frames and their order.
    """

    role = "tracker"

    def __init__(self, ctx: StageContext) -> None:
        super().__init__(ctx)
        self.tc = self.cfg.tracker
        self.snap_path = self.ctx.out / SNAPSHOT_NAME
        self.intake = Intake(self.name, self.run_id, self.bus, self.counters, self.delivery.max_payload_bytes)
        self.seq = Sequencer.for_delivery(self.delivery, 0, "measurements")
        self.tracker = None
        self.state = None
        self.last_seq = -1
        self.last_frame = -1
        self.last_stamp_ns: int | None = None
        self.bounds = FrameBounds(self.delivery.max_frame_gap, self.delivery.max_gap_s)
        self.rejected_seqs: list[int] = []
        self.journal = TracksJournal(self.ctx.out / JOURNAL_NAME, self.delivery.cache_frames)
        self.pending: list[Accepted] = []
        self.restored: Snapshot | None = None
        self.since_snapshot = 0
        self.last_progress = time.monotonic()
        self.step_ms: deque = deque(maxlen=10_000)
        self.writer = BackgroundWriter()
        self.finished_eos: EndOfStream | None = None
        self.holes = HoleWatch(FETCH_AFTER_S)

    # -- setup -------------------------------------------------------------------------
    def _restore(self) -> list[tuple[int, bytes, dict]]:
        """Resume from the snapshot when there is one (and ``resume``), and open the journal
        cut back to it; returns its samples, which :meth:`run` publishes again."""
        if not self.tc.resume:
            self.journal.start()
            return []
        if self.snap_path.exists():
            self._apply_snapshot(read_snapshot(self.snap_path))
        return self.journal.resume(self.last_seq)

    def _apply_snapshot(self, snap: Snapshot) -> None:
        if (snap.run, snap.tracker, snap.seed) != (self.run_id, self.tc.tracker, self.tc.seed):
            raise ConfigError(
                f"{self.snap_path}: snapshot of run {snap.run!r}, tracker {snap.tracker!r}, seed "
                f"{snap.seed} does not match this stage (run {self.run_id!r}, tracker "
                f"{self.tc.tracker!r}, seed {self.tc.seed}); delete it or set tracker.resume = false"
            )
        self.restored = snap
        self.last_seq, self.last_frame = snap.last_seq, snap.last_frame
        self.last_stamp_ns = snap.last_stamp_ns
        self.rejected_seqs = list(snap.rejected)
        self.seq = Sequencer.for_delivery(self.delivery, snap.last_seq + 1, "measurements")
        self.seq.gaps = list(snap.gaps)
        self.seq._gapset = set(snap.gaps)
        self.counters.gaps = len(snap.gaps)
        self.counters.processed = snap.counters.get("processed", 0)
        self.counters.restarts_resumed = snap.counters.get("restarts_resumed", 0) + 1
        self.finished_eos = snap.eos
        log.info("%s: resuming from %s (after seq %d, frame %d)", self.name, self.snap_path,
                 snap.last_seq, snap.last_frame)

    def _build(self, info: StageInfo) -> None:
        from pipeline.offline import format_overrides
        from tracker.state import restore

        tc = self.tc
        self.tracker, choice, params = build_stage_tracker(tc, info.metadata)
        initial = self.tracker.initial_state()
        if self.restored is not None:
            self.state = restore(self.restored.state, type(initial))
        elif tc.prior_from:
            self.state = keep_prior(initial, read_snapshot(tc.prior_from), tc.tracker)
            log.info("%s: starting from the prior of %s", self.name, tc.prior_from)
        else:
            self.state = initial
        _warm_up(self.tracker)
        out_meta = dict(info.metadata or {})
        out_meta.update(
            tracker=tc.tracker,
            tracker_seed=str(tc.seed),
            tracker_params=choice.source,
            tracker_config=tc.config or tc.tracker,
        )
        if tc.overrides:
            out_meta["tracker_overrides"] = format_overrides(tc.overrides)
        out_meta["run"] = self.run_id
        self.publish_control("info", StageInfo(stage=self.name, run=self.run_id, kind=tc.tracker,
                                               metadata=out_meta, tracker=tc.tracker, seed=tc.seed,
                                               pid=os.getpid()))
        log.info("%s: %s tracker, params %s, seed %d", self.name, tc.tracker,
                 choice.describe(params), tc.seed)

    # -- per frame ---------------------------------------------------------------------
    def _process(self, released: list[tuple[int, Any]]) -> None:
        from tracker.state import frame_rng

        for s, item in released:
            if item is GAP:
                self.counters.gaps += 1
                log.warning("%s: frame seq %d is missing (gap); predicting through it", self.name, s)
                self.last_seq = s
                continue
            acc: Accepted = item
            frame = frame_from_msg(acc.msg)
            why = self.bounds.violation(self.last_frame, self.last_stamp_ns, frame.frame, frame.stamp_ns)
            if why is not None:  # before the tracker predicts through the jump
                self.intake.reject(_FakeEvent("measurements", acc.payload, acc.t_recv_ns), s, why)
                self.rejected_seqs.append(s)
                self.last_seq = s
                continue
            t0 = time.perf_counter()
            state, est = self.tracker.step(self.state, frame, frame_rng(self.tc.seed, frame.frame))
            self.step_ms.append((time.perf_counter() - t0) * 1e3)
            payload = encode_tracks(est, self.run_id)
            # t: the source's publication time (end-to-end latency); t_in / t_out: when the
            # tracker received the frame and published its tracks (latency breakdown)
            meta = {"seq": s, "t": acc.meta.get("t", 0), "frame": frame.frame,
                    "t_in": acc.t_recv_ns, "t_out": time.time_ns()}
            self.bus.publish("tracks", payload, meta)
            # the state advances only once its output is out (a snapshot is always consistent)
            self.state, self.last_seq, self.last_frame = state, s, frame.frame
            self.last_stamp_ns = frame.stamp_ns
            try:
                self.journal.append(s, payload, meta)
            except OSError as exc:
                raise StageIOError(self.name, self.journal.path, exc) from None
            self.counters.processed += 1
            self.counters.published += 1
            self.since_snapshot += 1
            if self.since_snapshot >= self.tc.snapshot_every:
                self.snapshot()

    def snapshot(self, wait: bool = False) -> None:
        """Snapshot the state (written in the background; ``wait``: until it is on disk)."""
        if self.tracker is None or self.state is None:
            return
        from tracker.state import snapshot

        snap = Snapshot(
            run=self.run_id, tracker=self.tc.tracker, seed=self.tc.seed, last_seq=self.last_seq,
            last_frame=self.last_frame, state=snapshot(self.state), gaps=list(self.seq.gaps),
            last_stamp_ns=self.last_stamp_ns, rejected=list(self.rejected_seqs),
            counters={"processed": self.counters.processed,
                      "restarts_resumed": self.counters.restarts_resumed},
            time_ns=time.time_ns(), eos=self.finished_eos,
        )
        try:
            self.ctx.out.mkdir(parents=True, exist_ok=True)
            fd = self.journal.dup_fd()
            self.writer.submit(self.snap_path, msgspec.msgpack.encode(snap), () if fd is None else (fd,))
            self.since_snapshot = 0
            if wait:
                self.writer.flush()
        except OSError as exc:
            raise StageIOError(self.name, self.snap_path, exc) from None

    def _on_data(self, ev: Any) -> None:
        self.counters.received += 1
        acc = self.intake.check(ev)
        if acc is None:
            return
        t = acc.meta.get("t")
        if isinstance(t, int):
            self.counters.latency_ms.append((acc.t_recv_ns - t) / 1e6)
        if self.tracker is None:
            self.pending.append(acc)
            return
        self._push(acc)

    def _push(self, acc: Accepted) -> None:
        status, released = self.seq.push(acc.seq, acc)
        if status == "accepted":
            self.counters.accepted += 1
            self.last_progress = time.monotonic()
        elif status == "duplicate":
            self.counters.duplicates += 1
        elif status == "far":
            self.intake.reject(_FakeEvent("measurements", acc.payload, acc.t_recv_ns), acc.seq,
                               _far_reason(self.seq, acc.seq))
        else:
            self.counters.late += 1
            log.warning("%s: frame seq %d arrived after its gap was declared: rejected", self.name, acc.seq)
        if released:
            self._process(released)

    def _extra_health(self) -> dict:
        a = np.fromiter(self.step_ms, float) if self.step_ms else np.zeros(0)
        return {
            "last_seq": self.last_seq,
            "last_frame": self.last_frame,
            "step_ms_p50": float(np.median(a)) if a.size else None,
            "pending": self.seq.pending,
        }

    # -- loop --------------------------------------------------------------------------
    def run(self) -> int:
        bus = self.bus
        _warm_imports("pipeline.offline", "tracker.bnp_tracker", "tracker.state")
        history = self._restore()
        bus.declare(["tracks", f"info/{self.name}", f"eos/{self.name}"])
        for s, payload, meta in history:  # the run so far, into the new publisher's cache
            bus.publish("tracks", payload, meta)
        if history:
            log.info("%s: published the %d /tracks sample(s) of the journal again", self.name, len(history))
        del history  # free the payloads (run() lasts as long as the run)
        if self.finished_eos is not None:  # restarted after it had finished the run
            return self._end_again()
        bus.subscribe(["measurements", "info/*", "eos/*"])
        head = getattr(bus, "head", None)
        if head is not None:  # where the history ends: hold the catch-up window until there
            self.seq.hold_catch_up_through(head("measurements"))
        bus.declare_alive()
        finished = False
        src_name = "source"
        try:
            while not self.ctx.stop.is_set():
                ev = bus.recv(0.05)
                if ev is not None:
                    if self.on_control(ev):
                        if self.tracker is None and src_name in self.infos:
                            self._build(self.infos[src_name])
                            bus.declare_alive("ready")
                            for acc in self.pending:
                                self._push(acc)
                            self.pending.clear()
                    elif ev.topic == "measurements":
                        self._on_data(ev)
                    else:
                        log.debug("%s: ignoring %s", self.name, ev.topic)
                self.health(extra=self._extra_health)
                if self.tracker is not None and self.holes.due(self.seq):
                    fetch_holes(bus, "measurements", self.seq, max(self.seq.buf), self._on_data)
                eos = self.eos_seen.get(src_name)
                if eos is not None and self.tracker is not None and not finished:
                    if not self.seq.complete_through(eos.last_seq):
                        # grace counts from the later of the last progress and the end of stream
                        idle = time.monotonic() - max(self.last_progress, self.eos_time[src_name])
                        if idle >= self.delivery.eos_grace_s and bus.backlog == 0 and \
                                not fetch_holes(bus, "measurements", self.seq, eos.last_seq, self._on_data):
                            log.warning("%s: end of stream: frames still missing after %.1f s without "
                                        "progress are gaps", self.name, idle)
                            self._process(self.seq.flush_through(eos.last_seq))
                    if self.seq.complete_through(eos.last_seq):
                        finished = True
                        self.finished_eos = EndOfStream(
                            stage=self.name, run=self.run_id, last_seq=eos.last_seq,
                            frames=self.counters.processed, gaps=list(self.seq.gaps),
                            rejected=list(self.rejected_seqs), error=eos.error)
                        self.snapshot(wait=True)
                        self.publish_control("eos", self.finished_eos)
                        log.info("%s: processed %d frame(s) (%d gap(s)); waiting for %s", self.name,
                                 self.counters.processed, len(self.seq.gaps),
                                 ", ".join(self.tc.done_by) or "nobody")
                        self.health(force=True, extra=self._extra_health)
                if finished and set(self.tc.done_by) <= set(self.eos_seen):
                    return EXIT_OK
            return EXIT_STOPPED
        finally:
            try:
                self.snapshot(wait=True)
            finally:
                self._close_journal()
                self.health(force=True, extra=self._extra_health)

    def _close_journal(self) -> None:
        """Close the journal; a failing final write names the journal (not an anonymous OSError)."""
        try:
            self.journal.close()
        except OSError as exc:
            raise StageIOError(self.name, self.journal.path, exc) from None


    def _end_again(self) -> int:
        """A tracker restarted after it finished: its journal is in the cache again; announce
        the end of stream again and serve until the sink is done (or nobody is left)."""
        log.info("%s: the snapshot records the finished run (last seq %d): announcing its end again",
                 self.name, self.finished_eos.last_seq)
        self.bus.subscribe(["eos/*"])
        self.bus.declare_alive()
        self.publish_control("eos", self.finished_eos)
        try:
            self.serve_until_done_or_alone(self.tc.done_by)
        finally:
            self._close_journal()
        return EXIT_OK


def _far_reason(seq: Sequencer, s: int) -> str:
    return (f"seq {s} is {s - seq.next} past the next expected {seq.next} (the limit is "
            f"delivery.max_seq_ahead = {seq.max_ahead})")


@dataclass(frozen=True)
class _FakeEvent:
    topic: str
    payload: bytes
    t_recv_ns: int
    meta: dict | None = None
    meta_error: str | None = None


# --------------------------------------------------------------------------- sink


def _rerun_sink_module():
    """``sinks.rerun_sink`` when it is installed (with rerun-sdk), else ``None``."""
    try:
        import sinks.rerun_sink as mod  # type: ignore[import-not-found]
    except ImportError:
        return None
    return mod


class SinkStage(_StageBase):
    """Record the run: ``<out>/tracks.mcap`` (``/measurements``, ``/truth``, ``/tracks`` per
    frame, in order, like ``bnptrack track``), ``<out>/run.rrd`` when the Rerun sink is
    available, and ``<out>/sink.json`` (counts, gaps, latency).  Duplicate frames (e.g.
    ``/tracks`` re-published by a restarted tracker) are dropped."""

    role = "sink"

    def __init__(self, ctx: StageContext) -> None:
        super().__init__(ctx)
        self.sc = self.cfg.sink
        d = self.delivery
        self.intake = Intake(self.name, self.run_id, self.bus, self.counters, d.max_payload_bytes)
        self.streams: dict[str, Sequencer] = {
            "measurements": Sequencer.for_delivery(d, 0, "measurements"),
            "truth": Sequencer.for_delivery(d, 0, "truth"),
        }
        if self.sc.tracks:
            self.streams["tracks"] = Sequencer.for_delivery(d, 0, "tracks")
        self.ready: dict[str, dict[int, Any]] = {k: {} for k in self.streams}
        self.holes = {k: HoleWatch(FETCH_AFTER_S) for k in self.streams}
        self.progress: dict[str, float] = {k: time.monotonic() for k in self.streams}
        self.next_write = 0
        self.writer = None
        self.rrd = None
        from sinks.scoring import RunScorer, ScoreTally

        self.scorer = RunScorer()
        self.tally = ScoreTally()
        self.frames_written = 0
        self.tracks_written = 0
        self.e2e_ms: list[float] = []
        self.tracker_ms: list[float] = []
        self.hop_ms: list[tuple[float, float, float]] = []
        self.seq_written: list[int] = []
        self.files: list[str] = []
        self.held: list[tuple[int, Any, Any, Any]] = []
        self.bounds = FrameBounds(d.max_frame_gap, d.max_gap_s)
        self.last_frame = -1
        self.last_stamp_ns: int | None = None
        self.rejected_seqs: list[int] = []
        self.mismatched: dict[str, list[int]] = {}
        self.t_first_ns: int | None = None
        self.t_last_ns: int | None = None
        self.t_first_pub_ns: int | None = None

    # -- output ------------------------------------------------------------------------
    def _metadata(self) -> tuple[bool, dict[str, str] | None]:
        """(known, metadata): the tracker's output record (or the source's when there is
        no tracker stream)."""
        if self.sc.tracks:
            info = self.infos.get("tracker")
        else:
            info = self.infos.get("source")
        if info is None:
            return False, None
        meta = dict(info.metadata) if info.metadata is not None else None
        if meta is not None:
            meta.setdefault("run", self.run_id)
        return True, meta

    def _open(self, force: bool = False) -> bool:
        if self.writer is not None:
            return True
        known, meta = self._metadata()
        if not known and not force:
            return False
        out = self.ctx.out
        out.mkdir(parents=True, exist_ok=True)
        if self.sc.mcap:
            from sources.mcap_log import McapLogWriter

            path = out / self.sc.mcap_name
            self.writer = McapLogWriter(part_path(path), meta if meta is not None else {"run": self.run_id})
            self.files.append(str(path))
        else:
            self.writer = _NullWriter()
        if self.sc.rerun:
            self._open_rrd(out / self.sc.rrd_name, meta)
        self.bus.declare_alive("ready")
        return True

    def _open_rrd(self, path: Path, meta: dict[str, str] | None) -> None:
        """Open ``run.rrd`` with ``sinks.rerun_sink.RerunSink`` when that module is present
        (the hook: nothing else in the pipeline depends on it)."""
        mod = _rerun_sink_module()
        if mod is None:
            log.info("%s: sinks.rerun_sink is not available: no %s", self.name, path.name)
            return
        params = None
        try:
            from pipeline.offline import resolve_params
            from tracker.models.params import load_params

            name = (meta or {}).get("tracker_params")
            params = load_params(name) if name else resolve_params(None, meta).params
        except Exception:  # the viewer falls back to its default field of view
            params = None
        try:
            self.rrd = mod.RerunSink(part_path(path), recording_id=self.run_id, metadata=meta or {}, params=params,
                                     handle_signals=False, live=self.sc.view_url or None)
            self.files.append(str(path))
        except Exception as exc:  # the recording must not die for a viewer file
            log.error("%s: Rerun sink disabled: %s", self.name, exc)
            self.rrd = None

    def _write(self, s: int, meas: Any, truth: Any, tracks: Any) -> None:
        try:
            self._write_frame(s, meas, truth, tracks)
        except OSError as exc:
            raise StageIOError(self.name, self.ctx.out / self.sc.mcap_name, exc) from None

    def _write_frame(self, s: int, meas: Any, truth: Any, tracks: Any) -> None:
        """Record frame ``s``: the payloads go into tracks.mcap as received (they were
        validated on receipt, and they are the codec's bytes: no decoding to numpy and
        re-encoding); the Rerun sink, when on, gets them decoded."""
        has_truth = truth is not GAP and truth is not NO_TRUTH
        if meas is not GAP:
            m = meas.msg
            self.writer.write_encoded_frame(meas.payload, truth.payload if has_truth else None,
                                            m.stamp_ns, m.frame)
            self.frames_written += 1
        if tracks is not None and tracks is not GAP:
            self.writer.write_encoded_tracks(tracks.payload, tracks.msg.stamp_ns, tracks.msg.frame)
            self.tracks_written += 1
            self._note_latency(s, tracks)
        if meas is not GAP and tracks is not None and tracks is not GAP:
            # scored always (progress, sink.json); drawn when the Rerun sink is on
            frame = frame_from_msg(meas.msg, truth_from_msg(truth.msg) if has_truth else None)
            est = estimate_from_msg(tracks.msg)
            scores = self.scorer.update(frame, est) if self.sc.score or self.rrd is not None else _NO_SCORES
            self.tally.add(frame, est, scores)
            if self.rrd is not None:
                self._log_rrd(frame, est, scores)

    def _note_latency(self, s: int, tracks: Accepted) -> None:
        """Per-frame latencies of a written ``/tracks`` (for sink.json and health)."""
        t_pub = tracks.meta.get("t")
        self.t_last_ns = tracks.t_recv_ns
        if not isinstance(t_pub, int) or t_pub <= 0:
            return
        e2e = (tracks.t_recv_ns - t_pub) / 1e6
        self.e2e_ms.append(e2e)
        self.counters.latency_ms.append(e2e)
        self.tracker_ms.append(float(tracks.msg.diagnostics.get("ms", float("nan"))))
        self.seq_written.append(s)
        t_in, t_out = tracks.meta.get("t_in"), tracks.meta.get("t_out")
        if isinstance(t_in, int) and isinstance(t_out, int):
            self.hop_ms.append(((t_in - t_pub) / 1e6, (t_out - t_in) / 1e6, (tracks.t_recv_ns - t_out) / 1e6))
        if self.t_first_pub_ns is None:
            self.t_first_pub_ns = t_pub

    def _log_rrd(self, frame: Frame, est: Any, scores: dict[str, Any]) -> None:
        try:
            self.rrd.log(frame, est, **scores, health=self._health_scalars())
        except Exception as exc:
            log.error("%s: Rerun sink failed, disabling it: %s", self.name, exc)
            self._close_rrd()

    def _sink_health(self) -> dict:
        """The sink's part of its health message: what the launcher's progress line shows
        (frames written, the newest frame seen, the last frame's latency, the scores)."""
        seen = self.streams["measurements"].max_seen
        return {"frames_written": self.frames_written, "next_seq": self.next_write,
                "max_seq_seen": seen, "last_latency_ms": self.e2e_ms[-1] if self.e2e_ms else None,
                "scores": self.tally.as_dict()}

    def _health_scalars(self) -> dict[str, float]:
        c = self.counters
        out = {"received": c.received, "accepted": c.accepted, "rejected": c.rejected,
               "duplicates": c.duplicates, "late": c.late, "gaps": c.gaps,
               "dropped": float(getattr(self.bus, "dropped", 0))}
        if self.e2e_ms:
            out["latency_ms"] = self.e2e_ms[-1]
        return {k: float(v) for k, v in out.items()}

    def _close_rrd(self) -> None:
        rrd, self.rrd = self.rrd, None
        if rrd is not None:
            try:
                rrd.close()
            except Exception as exc:
                log.error("%s: closing the Rerun sink: %s", self.name, exc)

    def _drain_ready(self) -> None:
        """Write every frame for which each stream has released its item (or a gap)."""
        if not self._open():
            return
        ready = self.ready
        has_tracks = "tracks" in ready
        while True:
            s = self.next_write
            if s not in ready["measurements"] or s not in ready["truth"]:
                return
            if has_tracks and s not in ready["tracks"]:
                return
            meas = ready["measurements"].pop(s)
            truth = self._same_frame(s, "truth", ready["truth"].pop(s), meas)
            tracks = self._same_frame(s, "tracks", ready["tracks"].pop(s), meas) if has_tracks else None
            if self._in_bounds(s, meas):
                self._write(s, meas, truth, tracks)
            self.next_write += 1

    def _in_bounds(self, s: int, meas: Any) -> bool:
        """Whether frame ``s`` may be recorded: its frame number and stamp advance within
        the frame bounds (as the tracker checks them); otherwise none of its messages are
        written, and it is rejected and counted."""
        if meas is GAP:
            return True
        m = meas.msg
        why = self.bounds.violation(self.last_frame, self.last_stamp_ns, m.frame, m.stamp_ns)
        if why is not None:
            self.intake.reject(_FakeEvent("measurements", meas.payload, meas.t_recv_ns), s, why)
            self.rejected_seqs.append(s)
            return False
        self.last_frame, self.last_stamp_ns = m.frame, m.stamp_ns
        return True

    def _same_frame(self, s: int, stream: str, item: Any, meas: Any) -> Any:
        """``item`` (of ``stream``, seq ``s``) if it is for the frame of ``meas``, or if
        either is missing; otherwise :data:`GAP` (dropped, logged, counted as rejected)."""
        if item is GAP or item is NO_TRUTH or meas is GAP or item.msg.frame == meas.msg.frame:
            return item
        log.error("%s: seq %d: /%s is for frame %d but /measurements is frame %d; dropping the %s",
                  self.name, s, stream, item.msg.frame, meas.msg.frame, stream)
        self.counters.rejected += 1
        self.mismatched.setdefault(stream, []).append(s)
        return GAP

    # -- intake ------------------------------------------------------------------------
    def _release(self, stream: str, released: list[tuple[int, Any]]) -> None:
        r = self.ready[stream]
        for s, item in released:
            if item is GAP:
                self.counters.gaps += 1
                log.warning("%s: %s of frame seq %d is missing: recorded as a gap", self.name, stream, s)
            r[s] = item

    def _push(self, stream: str, seq: int, item: Any) -> None:
        status, released = self.streams[stream].push(seq, item)
        if status == "accepted":
            if item is not NO_TRUTH:
                self.counters.accepted += 1
            self.progress[stream] = time.monotonic()
        elif status == "duplicate":
            if item is not NO_TRUTH:
                self.counters.duplicates += 1
        elif status == "far":
            if item is not NO_TRUTH:
                self.intake.reject(_FakeEvent(stream, item.payload, item.t_recv_ns), seq,
                                   _far_reason(self.streams[stream], seq))
        else:
            self.counters.late += 1
            log.warning("%s: %s seq %d arrived after its gap was declared: rejected", self.name, stream, seq)
        self._release(stream, released)

    def _on_data(self, ev: Any) -> None:
        if ev.topic not in self.streams:
            return
        self.counters.received += 1
        acc = self.intake.check(ev)
        if acc is None:
            return
        if self.t_first_ns is None:
            self.t_first_ns = acc.t_recv_ns
        self._push(ev.topic, acc.seq, acc)
        if ev.topic == "measurements" and acc.meta.get("truth") is False:
            self._push("truth", acc.seq, NO_TRUTH)

    # -- completion --------------------------------------------------------------------
    def _check_end(self) -> bool:
        """True when everything up to the end of stream is released and written."""
        src = self.eos_seen.get("source")
        if src is None:
            return False
        last = src.last_seq
        now = time.monotonic()
        grace = self.delivery.eos_grace_s
        done = True
        for name, seq in self.streams.items():
            upstream = "source"
            if name == "tracks":
                upstream = "tracker"
                tr = self.eos_seen.get("tracker")
                if tr is None:
                    done = False
                    continue
                if (tr.gaps or tr.rejected) and not getattr(seq, "_marked_upstream", False):
                    self._release(name, seq.mark_gaps([*tr.gaps, *tr.rejected]))
                    seq._marked_upstream = True  # type: ignore[attr-defined]
                end = tr.last_seq
            else:
                end = last
            if not seq.complete_through(end):
                # grace counts from the later of the last progress and the end of stream
                idle = now - max(self.progress[name], self.eos_time[upstream])
                if idle >= grace and self.bus.backlog == 0 and not self._fetch(name, end):
                    log.warning("%s: end of stream: %s still missing after %.1f s without progress "
                                "are gaps", self.name, name, idle)
                    self._release(name, seq.flush_through(end))
                else:
                    done = False
        self._drain_ready()
        return done and self.next_write > last

    def _fetch(self, stream: str, upto: int) -> int:
        """Fetch what ``stream`` misses up to ``upto`` from its publisher's cache.  The truth
        of a frame sent without truth is not in any cache: its /measurements says so."""
        return fetch_holes(self.bus, stream, self.streams[stream], upto, self._on_data)

    def _fetch_due(self) -> None:
        for name, seq in self.streams.items():
            if self.holes[name].due(seq):
                self._fetch(name, max(seq.buf))

    def _finalize_or_abandon(self, complete: bool) -> None:
        try:
            self._finalize(complete)
        except OSError as exc:
            self._abandon()
            if isinstance(exc, StageIOError):
                raise
            raise StageIOError(self.name, exc.filename or self.ctx.out / self.sc.mcap_name, exc) from None

    def _abandon(self) -> None:
        """After a write error (disk full): close what is open, ignoring further errors, and
        remove the unfinished ``.part`` files (no temporary file is left behind)."""
        writer, self.writer = self.writer, None
        for close in (getattr(writer, "close", None), self._close_rrd):
            try:
                if close is not None:
                    close()
            except Exception:  # the disk is full: nothing more can be written
                pass
        for f in self.files:
            part_path(f).unlink(missing_ok=True)

    def _finalize(self, complete: bool) -> None:
        if not complete:
            # write what we have, in order: everything received so far, gaps for the holes
            self._open(force=True)
            top = max([self.next_write - 1] + [s.max_seen for s in self.streams.values()])
            for name, seq in self.streams.items():
                self._release(name, seq.flush_through(top))
            self._drain_ready()
        if self.writer is not None:
            self.writer.close()
        self._close_rrd()
        gaps = {name: list(seq.gaps) for name, seq in self.streams.items()}
        missing = self._missing()
        src = self.eos_seen.get("source")
        fps = None
        if self.t_first_pub_ns is not None and self.t_last_ns is not None and self.tracks_written > 1:
            fps = self.tracks_written / max((self.t_last_ns - self.t_first_pub_ns) / 1e9, 1e-9)
        summary = {
            "run": self.run_id,
            "complete": complete,
            "frames_written": self.frames_written,
            "tracks_written": self.tracks_written,
            "last_seq": self.next_write - 1,
            "gaps": gaps,
            "output_complete": complete and not missing,
            "missing": missing,
            "source_error": src.error if src is not None else "",
            "counters": self.counters.as_dict(),
            "rejected_by_topic": self.intake.rejected_by_topic,
            "dropped": int(getattr(self.bus, "dropped", 0)),
            "zenoh_misses": int(getattr(self.bus, "misses", 0)),
            "files": self.files,
            "scores": self.tally.as_dict(),
            "view": self._view_command(),
            "throughput_fps": fps,
            "t_first_pub_ns": self.t_first_pub_ns,
            "t_last_recv_ns": self.t_last_ns,
            "latency": {"seq": self.seq_written, "e2e_ms": self.e2e_ms, "tracker_ms": self.tracker_ms,
                        "source_to_tracker_ms": [h[0] for h in self.hop_ms],
                        "in_tracker_ms": [h[1] for h in self.hop_ms],
                        "tracker_to_sink_ms": [h[2] for h in self.hop_ms]},
        }
        self.ctx.out.mkdir(parents=True, exist_ok=True)
        path = self.ctx.out / SUMMARY_NAME
        sync_parts(self.files)  # the outputs are on disk before the summary says they are done
        write_atomic(path, msgspec.json.format(_JSON.encode(summary), indent=1))
        commit_parts(self.files)
        self.files.append(str(path))
        log.info("%s: wrote %d frame(s), %d /tracks message(s)%s to %s", self.name, self.frames_written,
                 self.tracks_written,
                 "" if not any(gaps.values()) else f", gaps {gaps}", ", ".join(self.files))

    def _view_command(self) -> str:
        """The command that opens the recording (``""``: no ``run.rrd`` was written)."""
        rrd = self.ctx.out / self.sc.rrd_name
        return f"bnptrack view {rrd}" if str(rrd) in self.files else ""

    def _missing(self) -> list[dict[str, Any]]:
        """What ``tracks.mcap`` lacks, and why: one entry per (topic, reason) with the
        sequence numbers -- for ``sink.json``, the launcher's exit code 3 and its summary."""
        out: list[dict[str, Any]] = []
        tr = self.eos_seen.get("tracker")
        by_tracker = set(tr.rejected) if tr is not None else set()

        def add(topic: str, seqs: Iterable[int], why: str) -> None:
            seqs = sorted(set(seqs))
            if seqs:
                out.append({"topic": f"/{topic}", "seqs": seqs, "why": why})

        for name, seq in self.streams.items():
            add(name, [g for g in seq.gaps if g not in by_tracker],
                "never received (gap)" if name != "tracks" else "no /tracks from the tracker (gap)")
        add("tracks", by_tracker, "the tracker rejected the frame (frame bounds; see the dead letters)")
        add("measurements", self.rejected_seqs,
            "the sink rejected the frame (frame bounds; none of its messages were written)")
        for name, seqs in self.mismatched.items():
            add(name, seqs, "for another frame than its /measurements (dropped)")
        return out

    def finished_before(self) -> dict | None:
        """The ``sink.json`` of this run when an earlier sink process recorded the whole run
        (``complete``): a sink restarted after that (killed while it lingered) must not
        reopen, i.e. truncate, the finished files.  Renames what that process left as
        ``.part`` (killed between ``sink.json`` and the renames)."""
        try:
            summary = msgspec.json.decode((self.ctx.out / SUMMARY_NAME).read_bytes())
        except (OSError, msgspec.DecodeError):
            return None
        if not isinstance(summary, dict) or summary.get("run") != self.run_id or not summary.get("complete"):
            return None
        commit_parts(summary.get("files") or [])
        return summary

    def _end_again(self, summary: dict) -> int:
        """Announce the recorded end of stream again (for stages still waiting for it)."""
        log.info("%s: %s already records the complete run (%d frame(s)); not reopening it",
                 self.name, self.ctx.out / SUMMARY_NAME, summary.get("frames_written", 0))
        self.bus.subscribe(["eos/*"])
        self.bus.declare([f"eos/{self.name}"])
        self.bus.declare_alive()
        gaps = sorted({int(g) for v in (summary.get("gaps") or {}).values() for g in v})
        self.publish_control("eos", EndOfStream(
            stage=self.name, run=self.run_id, last_seq=int(summary.get("last_seq", -1)),
            frames=int(summary.get("frames_written", 0)), gaps=gaps,
            error=summary.get("source_error") or "", files=list(summary.get("files") or [])))
        self.linger_until_alone(self.cfg.supervisor.linger_s, at_least=1.0)
        return EXIT_OK

    def run(self) -> int:
        bus = self.bus
        done = self.finished_before()
        if done is not None:
            return self._end_again(done)
        _warm_imports("sources.mcap_log", "pipeline.offline")
        if self.sc.score or self.sc.rerun:  # the scorer's kernels import scipy on first use
            _warm_imports("scipy.spatial.distance", "scipy.optimize")
        if self.sc.rerun:
            _rerun_sink_module()
        topics = ["measurements", "truth"] + (["tracks"] if self.sc.tracks else [])
        bus.subscribe(topics + ["info/*", "eos/*"])
        head = getattr(bus, "head", None)
        if head is not None:  # where each stream's history ends
            for name, seq in self.streams.items():
                seq.hold_catch_up_through(head(name))
        bus.declare([f"eos/{self.name}"])
        bus.declare_alive()
        complete = False
        failed = False
        try:
            while not self.ctx.stop.is_set():
                ev = bus.recv(0.05)
                if ev is not None:
                    if not self.on_control(ev):
                        self._on_data(ev)
                    # take what is already queued before looking at completion
                    while (ev := bus.recv(0)) is not None:
                        if not self.on_control(ev):
                            self._on_data(ev)
                self._drain_ready()
                self._fetch_due()
                self.health(extra=self._sink_health)
                if self._check_end():
                    complete = True
                    break
        except OSError as exc:
            if isinstance(exc, ConnectionError):  # the transport, not a file
                raise
            failed = True
            self._abandon()
            if isinstance(exc, StageIOError):
                raise
            raise StageIOError(self.name, exc.filename or self.ctx.out / self.sc.mcap_name, exc) from None
        finally:
            if not failed:
                self._finalize_or_abandon(complete)
            self.health(force=True, extra=self._sink_health)
        if not complete:
            return EXIT_STOPPED
        self.publish_control("eos", EndOfStream(
            stage=self.name, run=self.run_id, last_seq=self.next_write - 1, frames=self.frames_written,
            gaps=sorted({g for v in self.streams.values() for g in v.gaps}),
            error=self.eos_seen["source"].error, files=self.files))
        self.linger_until_alone(self.cfg.supervisor.linger_s)
        return EXIT_OK


_NO_SCORES: dict[str, Any] = {"ospa": None, "ospa2": None}


class _NullWriter:
    def write_encoded_frame(self, *a: Any, **k: Any) -> None: ...
    def write_encoded_tracks(self, *a: Any, **k: Any) -> None: ...
    def close(self) -> None: ...


STAGES: dict[str, type[_StageBase]] = {"source": SourceStage, "tracker": TrackerStage, "sink": SinkStage}
