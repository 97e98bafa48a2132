"""An in-process stand-in for :class:`pipeline.transport.Bus` (no zenoh).

:class:`MemoryNetwork` keeps every sample published on it (the equivalent of an unbounded
publisher cache) and delivers it to the :class:`MemoryBus` subscribers of the same run; a
subscriber declared late receives the history first, like Zenoh's advanced subscriber.
``tap`` lets a test drop, duplicate, reorder or corrupt samples on their way.  Used by the
stage-logic tests and by the benchmark's in-process baseline.
"""

from __future__ import annotations

import fnmatch
import queue
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import msgspec

from bnptrack.pipeline.events import Event

__all__ = ["MemoryNetwork", "MemoryBus"]

_ENC = msgspec.json.Encoder()
_DEC = msgspec.json.Decoder(dict)


def _match(pattern: str, topic: str) -> bool:
    p, t = pattern.split("/"), topic.split("/")
    return len(p) == len(t) and all(a == "*" or fnmatch.fnmatchcase(b, a) for a, b in zip(p, t))


class MemoryNetwork:
    """Shared medium of several :class:`MemoryBus` (one per stage)."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.history: list[tuple[str, str, bytes, bytes | None]] = []  # run, topic, payload, att
        self.buses: list[MemoryBus] = []
        self.alive: dict[tuple[str, str], set[str]] = {}
        #: ``tap(run, topic, payload, attachment) -> list of (payload, attachment)`` to deliver
        self.tap: Callable[[str, str, bytes, bytes | None], list[tuple[bytes, bytes | None]]] | None = None
        #: whether :meth:`MemoryBus.fetch` answers (from the publishers' own record, before
        #: ``tap``), like the Zenoh bus's explicit history
        self.fetchable = False

    def bus(self, run: str, stage: str, queue_limit: int = 100_000) -> "MemoryBus":
        b = MemoryBus(self, run, stage, queue_limit)
        with self.lock:
            self.buses.append(b)
        return b

    def _publish(self, run: str, topic: str, payload: bytes, att: bytes | None) -> None:
        with self.lock:
            deliveries = [(payload, att)] if self.tap is None else self.tap(run, topic, payload, att)
            # the history (what a late subscriber receives) is what went on the wire
            self.history.extend((run, topic, p, a) for p, a in deliveries)
            for b in list(self.buses):
                if b.run == run and not b.closed and b.wants(topic):
                    for p, a in deliveries:
                        b._deliver(topic, p, a)


class MemoryBus:
    """The :class:`pipeline.transport.Bus` interface over a :class:`MemoryNetwork`."""

    def __init__(self, net: MemoryNetwork, run: str, stage: str, queue_limit: int) -> None:
        self.net = net
        self.run = run
        self.stage = stage
        self.queue_limit = queue_limit
        self.patterns: list[str] = []
        self._q: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self.closed = False
        self.dropped = 0
        self.misses = 0
        self.received = 0
        self.published: list[tuple[str, bytes, dict | None]] = []

    def __enter__(self) -> "MemoryBus":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        with self.net.lock:
            self.closed = True
            for (run, _kind), names in self.net.alive.items():
                if run == self.run:
                    names.discard(self.stage)

    def declare(self, topics: Iterable[str]) -> None:
        pass

    def publish(self, topic: str, payload: bytes, meta: dict | None = None) -> None:
        att = None if meta is None else _ENC.encode(meta)
        self.published.append((topic, payload, meta))
        self.net._publish(self.run, topic, payload, att)

    def head(self, topic: str, timeout: float = 2.0) -> int | None:
        """The newest seq published on ``topic`` (``None``: nothing, or not ``fetchable``)."""
        if not self.net.fetchable:
            return None
        with self.net.lock:
            pubs = [b for b in self.net.buses if b.run == self.run and not b.closed]
        seqs = [m["seq"] for b in pubs for t, _p, m in list(b.published)
                if t == topic and m is not None and isinstance(m.get("seq"), int)]
        return max(seqs) if seqs else None

    def fetch(self, topic: str, lo: int, hi: int, timeout: float = 5.0) -> list[Event]:
        """What the live publishers of ``topic`` published with seq in ``[lo, hi]`` (empty
        unless the network is ``fetchable``)."""
        if not self.net.fetchable:
            return []
        with self.net.lock:
            pubs = [b for b in self.net.buses if b.run == self.run and not b.closed]
        out = []
        for b in pubs:
            for t, payload, meta in list(b.published):
                if t == topic and meta is not None and isinstance(meta.get("seq"), int) and lo <= meta["seq"] <= hi:
                    out.append(Event(topic, bytes(payload), dict(meta), time.time_ns()))
        return out

    def wants(self, topic: str) -> bool:
        return any(_match(p, topic) for p in self.patterns)

    def subscribe(self, patterns: Iterable[str], advanced: bool = True) -> None:
        with self.net.lock:
            new = list(patterns)
            self.patterns.extend(new)
            if advanced:
                for run, topic, payload, att in list(self.net.history):
                    if run == self.run and any(_match(p, topic) for p in new):
                        self._deliver(topic, payload, att)

    def _deliver(self, topic: str, payload: bytes, att: bytes | None) -> None:
        self.received += 1
        if self._q.qsize() >= self.queue_limit:
            self.dropped += 1
            return
        meta, err = None, None
        if att is not None:
            try:
                meta = _DEC.decode(att)
            except Exception as exc:
                err = f"attachment is not a JSON object: {exc}"
        self._q.put(Event(topic, bytes(payload), meta, time.time_ns(), err))

    def recv(self, timeout: float | None = None) -> Event | None:
        try:
            if timeout == 0:
                return self._q.get_nowait()
            return self._q.get(timeout=timeout)
        except queue.Empty:
            return None

    @property
    def backlog(self) -> int:
        return self._q.qsize()

    def declare_alive(self, kind: str = "alive") -> None:
        with self.net.lock:
            self.net.alive.setdefault((self.run, kind), set()).add(self.stage)

    def alive(self, kind: str = "alive") -> set[str]:
        with self.net.lock:
            return set(self.net.alive.get((self.run, kind), set()))

    def wait_alive(self, names: Iterable[str], timeout: float, kind: str = "alive") -> set[str]:
        want = set(names)
        deadline = time.monotonic() + timeout
        while True:
            missing = want - self.alive(kind)
            if not missing or time.monotonic() >= deadline:
                return missing
            time.sleep(0.01)
