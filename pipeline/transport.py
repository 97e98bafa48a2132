"""The network of bnptrack: with :mod:`pipeline.transport_session` (a
:class:`~pipeline.config.ZenohConfig` as Zenoh sessions, the :class:`Router`) and
:mod:`pipeline.transport_liveliness` (the liveliness tokens), the only modules that import zenoh.

It gives the stages a small, zenoh-free interface, :class:`Bus` (the in-memory twin used by the tests is
:class:`pipeline.membus.MemoryBus`):

* ``publish(topic, payload, meta)``: ``payload`` are the codec's JSON bytes, ``meta`` a small
  dict sent as the sample's attachment (JSON): ``{"seq": n, "t": publish_ns, ...}``;
* ``subscribe(patterns)`` then ``recv(timeout) -> Event``: every subscription is drained by a
  callback on Zenoh's thread into one in-process queue (never blocking Zenoh; a sample that
  would exceed ``delivery.queue_limit`` is dropped and counted in :attr:`Bus.dropped`);
* ``declare_alive(kind)`` / ``alive(kind)`` / ``wait_alive(names, timeout, kind)``: liveliness
  tokens ``bnptrack/<run>/alive/<stage>`` (the stage runs) and ``bnptrack/<run>/ready/<stage>``
  (it can process its first frame: the source waits for these).

Key expressions are scoped by run (:func:`key`): ``bnptrack/<run>/<topic>``.  Topics:

=================  ===========================================================================
``measurements``   frames from the source (advanced publisher: cache, miss detection)
``truth``          ground truth from the source (same)
``tracks``         estimates from the tracker (same)
``info/<stage>``   a stage's stream description (cached, for late joiners)
``eos/<stage>``    a stage's end of stream (cached)
``health/<stage>`` periodic health counters (best effort)
``deadletter``     copies of rejected payloads
``alive/<stage>``  liveliness token (not a topic: see :meth:`Bus.declare_alive`)
``ready/<stage>``  liveliness token: ready for the first frame
=================  ===========================================================================

Data and control topics use ``zenoh.ext``'s advanced publisher (reliable, congestion control
BLOCK, a cache of ``delivery.cache_frames`` samples, sample-miss detection with periodic
heartbeats, publisher detection) and advanced subscriber (history with late-publisher
detection, recovery by heartbeat): a consumer that starts late or restarts receives the
publisher's cache, a sample lost on the way is recovered from the cache.  zenoh.ext is
marked unstable: bnptrack pins eclipse-zenoh to 1.10.x and keeps every use of it here.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from typing import Any

import msgspec
import zenoh
import zenoh.ext as zext

from bnptrack.pipeline.acl import KEY_ROOT
from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
from bnptrack.pipeline.events import FETCH_MAX, Event
from bnptrack.pipeline.transport_liveliness import Liveliness
from bnptrack.pipeline.transport_session import (SHM_OFF, NoRouterError, Router, TransportError, open_session,
                                                 session_config)

__all__ = [
    "KEY_ROOT",
    "DATA_TOPICS",
    "Event",
    "Bus",
    "Router",
    "key",
    "session_config",
    "SHM_OFF",
    "TransportError",
    "NoRouterError",
]

log = logging.getLogger("bnptrack.transport")

#: Topics published with a cache of ``delivery.cache_frames`` samples.
DATA_TOPICS = frozenset({"measurements", "truth", "tracks"})
#: Cache size of control topics (``info/<stage>``, ``eos/<stage>``).
CONTROL_CACHE = 16

_META_ENC = msgspec.json.Encoder()
_FETCH_DEC = msgspec.json.Decoder(tuple[int, int])
_META_DEC = msgspec.json.Decoder(dict)


def _event(topic: str, sample: Any) -> Event:
    """The :class:`Event` of a received sample (live or fetched from a cache): payload bytes,
    the attachment decoded as a JSON object (``meta_error`` says why it is not one)."""
    meta, err = None, None
    att = sample.attachment
    if att is not None:
        try:
            meta = _META_DEC.decode(att.to_bytes())
        except Exception as exc:
            err = f"attachment is not a JSON object: {exc}"
    return Event(topic, sample.payload.to_bytes(), meta, time.time_ns(), err)


def key(run: str, topic: str) -> str:
    """``bnptrack/<run>/<topic>``."""
    return f"{KEY_ROOT}/{run}/{topic}"


class Bus(Liveliness):
    """A stage's connection to the run's topics (see the module docstring).

    ``connect`` overrides ``zcfg.connect``.  Use as a context manager or call :meth:`close`:
    a session left open keeps the process from exiting.
    """

    def __init__(
        self,
        run: str,
        stage: str,
        zcfg: ZenohConfig,
        delivery: DeliveryConfig,
        connect: Sequence[str] | None = None,
        listen: Sequence[str] | None = None,
    ) -> None:
        self.run = run
        self.stage = stage
        self.delivery = delivery
        self.prefix = f"{KEY_ROOT}/{run}/"
        self._inbox: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._pubs: dict[str, Any] = {}
        self._subs: list[Any] = []
        self._tokens: dict[str, Any] = {}
        self._present: dict[str, set[str]] = {}
        self._alive_lock = threading.Lock()
        self._alive_changed = threading.Condition(self._alive_lock)
        self._closed = False
        # what this stage published on each data topic, newest delivery.cache_frames, by
        # seq: served to consumers that fetch what they miss (:meth:`fetch`)
        self._ring: dict[str, OrderedDict[int, tuple[bytes, bytes]]] = {}
        self._ring_lock = threading.Lock()
        self._queryables: list[Any] = []
        self.fetched = 0
        self.dropped = 0
        self.misses = 0
        self.received = 0
        self.session = open_session(
            session_config(zcfg, connect=connect, listen=listen), f"stage {stage!r} (run {run!r})",
            list(zcfg.connect if connect is None else connect),
        )
        try:
            self._liveliness_subs = [
                self.session.liveliness().declare_subscriber(self.prefix + f"{kind}/*", self._on_token, history=True)
                for kind in ("alive", "ready")
            ]
        except BaseException:
            self.session.close()
            raise

    # -- context -------------------------------------------------------------------------
    def __enter__(self) -> "Bus":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for obj in [*self._tokens.values(), *self._liveliness_subs, *self._subs, *self._queryables,
                    *self._pubs.values()]:
            if obj is None:
                continue
            try:
                obj.undeclare()
            except Exception:  # already gone
                pass
        self._subs.clear()
        self._pubs.clear()
        self.session.close()

    # -- publishing ----------------------------------------------------------------------
    def _publisher(self, topic: str):
        pub = self._pubs.get(topic)
        if pub is not None:
            return pub
        k = self.prefix + topic
        if topic in DATA_TOPICS or topic.startswith(("info/", "eos/")):
            cache = self.delivery.cache_frames if topic in DATA_TOPICS else CONTROL_CACHE
            pub = zext.declare_advanced_publisher(
                self.session,
                k,
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
                cache=zext.CacheConfig(
                    cache,
                    replies_config=zext.RepliesConfig(congestion_control=zenoh.CongestionControl.BLOCK),
                ),
                sample_miss_detection=zext.MissDetectionConfig(
                    heartbeat=self.delivery.heartbeat_s, sporadic_heartbeat=None
                ),
                publisher_detection=True,
            )
            if topic in DATA_TOPICS:
                self._ring[topic] = OrderedDict()
                self._queryables.append(self.session.declare_queryable(
                    f"{self.prefix}fetch/{topic}/**",
                    zenoh.handlers.Callback(lambda q, t=topic: self._on_fetch(t, q), indirect=True),
                ))
        elif topic.startswith("health/"):
            pub = self.session.declare_publisher(
                k,
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.DROP,
            )
        else:  # deadletter and anything else: reliable, blocking
            pub = self.session.declare_publisher(
                k,
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
            )
        self._pubs[topic] = pub
        return pub

    def declare(self, topics: Iterable[str]) -> None:
        """Declare publishers ahead of the first put (so subscribers can detect them)."""
        for t in topics:
            self._publisher(t)

    def publish(self, topic: str, payload: bytes, meta: dict | None = None) -> None:
        """Put ``payload`` on ``bnptrack/<run>/<topic>`` with ``meta`` as the attachment."""
        pub = self._publisher(topic)
        if meta is None:
            pub.put(payload)
            return
        att = _META_ENC.encode(meta)
        pub.put(payload, attachment=att)
        ring = self._ring.get(topic)
        seq = meta.get("seq")
        if ring is not None and isinstance(seq, int):
            with self._ring_lock:
                ring[seq] = (payload, att)
                ring.move_to_end(seq)
                while len(ring) > self.delivery.cache_frames:
                    ring.popitem(last=False)

    # -- explicit history ------------------------------------------------------------------
    def _on_fetch(self, topic: str, query: Any) -> None:
        """Answer a :meth:`fetch`: one reply per cached sample whose seq is in the asked
        ``[lo, hi]`` (at most ``FETCH_MAX``), key ``fetch/<topic>/<seq>``."""
        try:
            lo, hi = _FETCH_DEC.decode(query.payload.to_bytes() if query.payload is not None else b"")
            with self._ring_lock:
                ring = self._ring.get(topic) or {}
                if lo < 0:  # a head request: the newest seq published (-1: none yet)
                    head = next(reversed(ring), -1) if ring else -1
                    query.reply(f"{self.prefix}fetch/{topic}/head", b"", attachment=_META_ENC.encode({"head": head}))
                    return
                items = [(s, v) for s, v in ring.items() if lo <= s <= hi][:FETCH_MAX]
            for s, (payload, att) in items:
                query.reply(f"{self.prefix}fetch/{topic}/{s}", payload, attachment=att,
                            congestion_control=zenoh.CongestionControl.BLOCK)
        except Exception as exc:  # a malformed query: no answer
            log.debug("%s: fetch on %s refused: %s", self.stage, topic, exc)

    def head(self, topic: str, timeout: float = 2.0) -> int | None:
        """The live head of ``topic``: the newest seq its publisher has published (its
        announcement through the fetch queryable), ``None`` when no publisher answers.  A
        consumer that (re)joins holds its catch-up window until it has passed the head, so
        live frames never push the history out as gaps."""
        heads = []
        try:
            for reply in self.session.get(f"{self.prefix}fetch/{topic}/**", payload=_META_ENC.encode([-1, -1]),
                                          timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE,
                                          target=zenoh.QueryTarget.ALL):
                sample = reply.ok
                if sample is not None and sample.attachment is not None:
                    h = _META_DEC.decode(sample.attachment.to_bytes()).get("head")
                    if isinstance(h, int) and not isinstance(h, bool):
                        heads.append(h)
        except Exception as exc:
            log.warning("%s: asking the head of %s failed: %s", self.stage, topic, exc)
        return max(heads) if heads else None

    def fetch(self, topic: str, lo: int, hi: int, timeout: float = 5.0) -> list[Event]:
        """Ask the publisher of ``topic`` for its cached samples with seq in ``[lo, hi]``
        (what the advanced subscriber's history did not bring); returns them as events (the
        stage validates them like any sample).  Empty when nobody answers in ``timeout``."""
        out: list[Event] = []
        try:
            replies = self.session.get(
                f"{self.prefix}fetch/{topic}/**", payload=_META_ENC.encode([int(lo), int(hi)]),
                timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE,
                target=zenoh.QueryTarget.ALL,
            )
            for reply in replies:
                sample = reply.ok
                if sample is None:
                    continue
                out.append(_event(topic, sample))
        except Exception as exc:
            log.warning("%s: fetching %s %d-%d failed: %s", self.stage, topic, lo, hi, exc)
        self.fetched += len(out)
        return out

    # -- subscribing ---------------------------------------------------------------------
    def subscribe(self, patterns: Iterable[str], advanced: bool = True) -> None:
        """Subscribe to topics (``*`` allowed in a chunk, e.g. ``eos/*``).

        ``advanced`` (data and control topics): history of late and restarted publishers,
        recovery of missed samples.  Plain subscribers (health, deadletter) get live samples
        only.
        """
        for pattern in patterns:
            k = self.prefix + pattern
            if advanced:
                sub = zext.declare_advanced_subscriber(
                    self.session,
                    k,
                    self._handler(),
                    history=zext.HistoryConfig(
                        detect_late_publishers=True, max_samples=self.delivery.cache_frames
                    ),
                    recovery=zext.RecoveryConfig(periodic_queries=None, heartbeat=True),
                    subscriber_detection=True,
                )
                self._subs.append(sub)
                self._subs.append(sub.sample_miss_listener(self._on_miss))
            else:
                self._subs.append(self.session.declare_subscriber(k, self._handler(indirect=True)))

    def _handler(self, indirect: bool = False) -> Any:
        """The subscription callback.  Data and control (``indirect=False``): run on Zenoh's
        network thread itself instead of a Python thread per subscription, one thread
        hand-off less per sample; :meth:`_on_sample` only appends to a queue.  Plain
        subscriptions (``indirect=True``: the launcher's ``health/*`` and ``deadletter``) run
        it on a Python thread of their own: the launcher's process also holds the embedded
        router, whose forwarding shares Zenoh's network threads with these callbacks, and a
        callback there first waits for the GIL (up to the 5 ms switch interval, more when the
        holder is descheduled) while the launcher's own Python code runs."""
        return zenoh.handlers.Callback(self._on_sample, indirect=indirect)

    def _on_sample(self, sample: Any) -> None:
        # Runs on a Zenoh thread: never block it.
        try:
            self.received += 1
            if self._inbox.qsize() >= self.delivery.queue_limit:
                self.dropped += 1
                if self.dropped == 1 or self.dropped % 1000 == 0:
                    log.error(
                        "%s: in-process queue full (%d): dropped %d sample(s) so far",
                        self.stage, self.delivery.queue_limit, self.dropped,
                    )
                return
            k = str(sample.key_expr)
            topic = k[len(self.prefix):] if k.startswith(self.prefix) else k
            self._inbox.put(_event(topic, sample))
        except Exception:  # never let an exception escape into Zenoh's thread
            log.exception("%s: failed to queue a sample", self.stage)

    def _on_miss(self, miss: Any) -> None:
        self.misses += int(miss.nb)
        log.warning("%s: zenoh reports %d missed sample(s) from %s", self.stage, miss.nb, miss.source)

    def recv(self, timeout: float | None = None) -> Event | None:
        """Next received sample, or ``None`` after ``timeout`` seconds."""
        try:
            return self._inbox.get(timeout=timeout)
        except queue.Empty:
            return None

    @property
    def backlog(self) -> int:
        return self._inbox.qsize()

    def links(self) -> dict[str, int]:
        """How many routers and peers this session is connected to (a peer-mode stage
        shows its direct links to the other stages under ``peers``)."""
        info = self.session.info
        return {"routers": len(list(info.routers_zid())), "peers": len(list(info.peers_zid()))}
