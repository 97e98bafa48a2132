"""The stage base: exit codes, the injectable clock, :class:`StageContext` and
:class:`StageBase` (health, control messages, serving until the others are done)."""

from __future__ import annotations

import gc
import importlib
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import msgspec

from bnptrack.pipeline.config import PipelineConfig
from bnptrack.pipeline.stages.health import _CONTROL_DEC, _JSON, Counters, EndOfStream, StageInfo

__all__ = ["EXIT_OK", "EXIT_CRASH", "EXIT_CONFIG", "EXIT_DATA", "EXIT_STOPPED", "EXIT_IO", "StageIOError",
           "Clock", "SystemClock", "ManualClock", "StageContext", "StageBase", "warm_imports",
           "settle_heap"]

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


class Clock(Protocol):
    """Where a stage reads the time: every timeout, grace period, pacing and time stamp of
    the stage loops goes through it (the tests drive a :class:`ManualClock`)."""

    def monotonic(self) -> float:
        """Seconds on a clock that never goes back (timeouts, grace periods)."""

    def time_ns(self) -> int:
        """Wall-clock nanoseconds (time stamps in attachments, dead letters, health)."""

    def perf_counter(self) -> float:
        """Seconds for measuring short durations (the tracker's step time)."""

    def wait(self, stop: threading.Event, seconds: float) -> bool:
        """Wait ``seconds`` or until ``stop`` is set; True if it is set."""


class SystemClock:
    """The real clock (the default)."""

    monotonic = staticmethod(time.monotonic)
    time_ns = staticmethod(time.time_ns)
    perf_counter = staticmethod(time.perf_counter)

    @staticmethod
    def wait(stop: threading.Event, seconds: float) -> bool:
        return stop.wait(seconds)


class ManualClock:
    """A clock that moves only when told (:meth:`advance`; :meth:`wait` advances it by the
    time waited): grace periods and timeouts of a stage then depend on the test, not on the
    machine's speed.  Thread-safe; ``time_ns`` starts at ``start_ns``."""

    def __init__(self, start: float = 0.0, start_ns: int = 1_700_000_000 * 10**9) -> None:
        self._t = float(start)
        self._ns0 = int(start_ns) - int(round(start * 1e9))
        self._lock = threading.Lock()

    def advance(self, seconds: float) -> None:
        with self._lock:
            self._t += float(seconds)

    def monotonic(self) -> float:
        with self._lock:
            return self._t

    def time_ns(self) -> int:
        with self._lock:
            return self._ns0 + int(round(self._t * 1e9))

    perf_counter = monotonic

    def wait(self, stop: threading.Event, seconds: float) -> bool:
        if not stop.is_set():
            self.advance(max(0.0, seconds))
        return stop.is_set()


class StopFlag(threading.Event):
    """A stage's stop flag that remembers why it was first set (:meth:`stop`)."""

    def __init__(self) -> None:
        super().__init__()
        self.reason = ""

    def stop(self, reason: str) -> None:
        if not self.is_set():
            self.reason = reason
        self.set()


def stop_reason(stop: threading.Event) -> str:
    """Why ``stop`` was set (``""``: not said)."""
    return stop.reason if isinstance(stop, StopFlag) else ""


def set_stop(stop: threading.Event, reason: str) -> None:
    """Set ``stop``, saying why when it is a :class:`StopFlag`."""
    if isinstance(stop, StopFlag):
        stop.stop(reason)
    else:
        stop.set()


@dataclass
class StageContext:
    """What a stage needs: the (resolved) pipeline, its bus, a stop flag, its name, the
    clock it reads the time from (default: the real one) and where it reports to its
    launcher (``report``: the source's published count and last seq; default: nowhere)."""

    cfg: PipelineConfig
    bus: Any
    stop: threading.Event = field(default_factory=threading.Event)
    name: str = ""
    clock: Clock = field(default_factory=SystemClock)
    report: Callable[[dict], None] = field(default=lambda msg: None)

    @property
    def run(self) -> str:
        return self.cfg.run

    @property
    def out(self) -> Path:
        return Path(self.cfg.out)


def warm_imports(*modules: str) -> None:
    """Import what a stage needs before it declares itself alive, so the first frame is not
    delayed by imports (scipy, rerun: seconds on a busy machine)."""
    for m in modules:
        importlib.import_module(m)


def settle_heap() -> None:
    """Move every object alive now (the modules, numba's and scipy's tables, the warmed-up
    tracker: some 200 000 objects in the tracker stage) to the garbage collector's permanent
    generation (``gc.freeze``), so that the collections during the frames traverse only what
    the frames create.  A stage calls it once, before it declares itself ready.

    Without it, the first full collections of a stage fell among the first frames: 88 ms in
    the tracker and 116 ms in the sink (timed with ``gc.callbacks`` in a paced run), tens of
    milliseconds of added latency for the frames then in flight (docs/pipeline.md,
    Performance).  Nothing frozen is ever freed; it is what the stage keeps for its whole
    life anyway."""
    gc.freeze()


class StageBase:
    """What every stage does besides its loop: health, control messages, waiting for the others."""

    role = ""

    def __init__(self, ctx: StageContext) -> None:
        self.ctx = ctx
        self.cfg = ctx.cfg
        self.bus = ctx.bus
        self.name = ctx.name or self.role
        self.run_id = ctx.cfg.run
        self.clock = ctx.clock
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
        now = self.clock.monotonic()
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
            "t_ns": self.clock.time_ns(),
            "counters": self.counters.as_dict(),
            "dropped": int(self.bus.dropped),
            "zenoh_misses": int(self.bus.misses),
            "backlog": int(self.bus.backlog),
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
            self.eos_time[stage] = self.clock.monotonic()
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
        t0 = self.clock.monotonic()
        while not self.ctx.stop.is_set() and not want <= set(self.eos_seen):
            if self.clock.monotonic() - t0 >= at_least and not (self.bus.alive() - {self.name}):
                return
            ev = self.bus.recv(0.05)
            if ev is not None:
                self.on_control(ev)
            self.health()

    def linger_until_alone(self, timeout: float, at_least: float = 0.0) -> None:
        """Keep the session open until no other stage of the run is alive (so that our
        last messages are delivered), at most ``timeout`` seconds; ``at_least`` seconds in
        any case (a session just opened has not seen the others' tokens yet)."""
        t0 = self.clock.monotonic()
        deadline = t0 + timeout
        while self.clock.monotonic() < deadline and not self.ctx.stop.is_set():
            if not (self.bus.alive() - {self.name}) and self.clock.monotonic() - t0 >= at_least:
                return
            ev = self.bus.recv(0.05)
            if ev is not None:
                self.on_control(ev)
