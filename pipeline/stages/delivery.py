"""Delivery: what a stage receives, checked and put in order.

A bus (:class:`pipeline.transport.Bus`, :class:`pipeline.membus.MemoryBus`) hands a stage
:class:`Event` samples; :class:`Intake` validates each one (size, attachment, codec, run id)
into an :class:`Accepted` sample or rejects it with a dead letter; a :class:`Sequencer` per
stream dedupes, reorders within a window and declares gaps; :class:`HoleWatch` and
:func:`fetch_holes` fetch what a stream misses from its publisher's cache.
"""

from __future__ import annotations

import base64
import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from bnptrack.tracker.messages import TOPIC_MEASUREMENTS, TOPIC_TRACKS, TOPIC_TRUTH, CodecError, decode
from bnptrack.pipeline.config import DeliveryConfig
from bnptrack.pipeline.events import FETCH_MAX
from bnptrack.pipeline.stages.health import _JSON, Counters

__all__ = ["Accepted", "Intake", "Sequencer", "HoleWatch", "fetch_holes", "settle_holes", "resolve_conflict",
           "HeadAsk", "end_gaps_due", "publisher_copy",
           "GAP", "NO_TRUTH", "FETCH_AFTER_S", "BUS_TOPIC", "CODEC_TOPIC", "MAX_SEQ", "DEADLETTER_COPY",
           "RepeatLog"]

log = logging.getLogger("bnptrack.stage")


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

    ``confirm`` (the pipeline's consumers): a frame missing while later ones arrive is not
    declared a gap by the window alone; it is declared by :meth:`confirm_through`, once the
    live publishers were asked for it (:func:`settle_holes`) and did not return it, or when
    ``catch_up`` later frames have arrived (no cache holds it any more).  ``ask_head``
    (``() -> int | None``: the publishers' live head, ``None`` when nobody answers) bounds the
    look-ahead: a sample ``window`` or more past the next expected one whose seq is beyond
    the live head is answered ``"ahead"`` (not accepted, nothing declared).  A sample whose
    seq is buffered with another payload is answered ``"conflict"`` (the earlier one stays;
    :func:`resolve_conflict` asks the publisher which is its own).
    """

    def __init__(self, window: int, start: int = 0, name: str = "", catch_up: int | None = None,
                 max_ahead: int | None = None, confirm: bool = False,
                 ask_head: Callable[[], int | None] | None = None) -> None:
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
        self.confirm = bool(confirm)
        self.ask_head = ask_head
        self.known_head = -1
        self.ahead = 0
        self.conflicts = 0

    @classmethod
    def for_delivery(cls, delivery: DeliveryConfig, start: int, name: str,
                     ask_head: Callable[[], int | None] | None = None) -> Sequencer:
        """A consumer's sequencer with the pipeline's ``window``, ``catch_up`` and
        ``max_seq_ahead``; gaps are confirmed with the publishers (``confirm``)."""
        return cls(delivery.window, start, name, delivery.catch_up, delivery.max_seq_ahead, confirm=True,
                   ask_head=ask_head)

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
            if _differs(self.buf[seq], item):
                self.conflicts += 1
                return "conflict", []
            self.duplicates += 1
            return "duplicate", []
        if seq >= self.next + self.window and not self._within_head(seq):
            self.ahead += 1
            return "ahead", []
        self.accepted += 1
        self.max_seen = max(self.max_seen, seq)
        out: list[tuple[int, Any]] = []
        window = self.window if self.caught_up and not self.confirm else self.catch_up
        if seq >= self.next + window:
            out += self._advance_to(seq - window + 1)
        self.buf[seq] = item
        out += self._release()
        self.caught_up = self.caught_up or (not self.buf and self.next > self.catch_up_through)
        return "accepted", out

    def _within_head(self, seq: int) -> bool:
        """Whether ``seq`` can have been published: at most the live head (asked again when
        ``seq`` is past the head known so far; ``True`` when nobody answers)."""
        if seq <= self.known_head or self.ask_head is None:
            return True
        head = self.ask_head()
        if head is None:
            return True
        self.known_head = max(self.known_head, int(head))
        return seq <= self.known_head

    def replace(self, seq: int, item: Any) -> None:
        """Put ``item`` (the publisher's own copy) in the buffered slot ``seq``."""
        if seq in self.buf:
            self.buf[seq] = item

    def confirm_through(self, hi: int) -> list[tuple[int, Any]]:
        """The live publishers were asked for the missing frames up to ``hi`` and did not
        return them: declare those the window has passed (``window`` or more behind the
        newest frame received) gaps; returns what is released."""
        target = min(int(hi) + 1, self.max_seen - self.window + 1)
        if target <= self.next:
            return []
        return self._advance_to(target) + self._release()

    def hold_catch_up_through(self, head: int | None) -> None:
        """The publisher's announced live head: the history a (re)joining consumer receives
        ends there, so the catch-up window holds until everything up to ``head`` is released
        (not merely until the buffer is empty once)."""
        if head is None:
            return
        self.catch_up_through = max(self.catch_up_through, int(head))
        self.known_head = max(self.known_head, int(head))
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

    def restore_gaps(self, gaps: Iterable[int]) -> None:
        """The gaps an earlier run of this consumer declared (from its snapshot): a frame
        of them arriving now is *late*, as it would have been for that run."""
        self.gaps = [int(g) for g in gaps]
        self._gapset = set(self.gaps)

    def far_reason(self, seq: int) -> str:
        """Why ``push(seq, ...)`` answered ``"far"`` or ``"ahead"`` (for the rejection)."""
        if self.max_ahead is None or seq - self.next < self.max_ahead:
            return (f"seq {seq} is past the publisher's live head {self.known_head} (no publisher "
                    f"has published it)")
        return (f"seq {seq} is {seq - self.next} past the next expected {self.next} (the limit is "
                f"delivery.max_seq_ahead = {self.max_ahead})")

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

    def __init__(self, after: float, monotonic: Callable[[], float] = time.monotonic) -> None:
        self.after = after
        self.next = -1
        self._monotonic = monotonic
        self.since = monotonic()

    def due(self, seqr: Sequencer) -> bool:
        now = self._monotonic()
        if seqr.next != self.next:
            self.next, self.since = seqr.next, now
            return False
        if seqr.pending and now - self.since >= self.after:
            self.since = now
            return True
        return False


def _differs(a: Any, b: Any) -> bool:
    """Two received copies of one seq with different payloads (markers never differ)."""
    pa, pb = getattr(a, "payload", None), getattr(b, "payload", None)
    return pa is not None and pb is not None and bytes(pa) != bytes(pb)


def fetch_holes(bus: Any, topic: str, seqr: Sequencer, upto: int,
                on_event: Callable[[Any], None]) -> int | None:
    """Fetch explicitly from the publisher's cache (:meth:`pipeline.transport.Bus.fetch`) the
    frames of ``topic`` that ``seqr`` still misses up to ``upto`` (at most ``FETCH_MAX``
    from the first), and hand each to ``on_event`` (validated like any sample).  Returns how
    many came back (0 when nothing is missing or the publisher holds none of them), ``None``
    when no live publisher answered (e.g. while the router is away)."""
    if upto < seqr.next:
        return 0
    hi = next((s for s in range(upto, seqr.next - 1, -1) if s not in seqr.buf), None)
    if hi is None:
        return 0
    lo, hi = seqr.next, min(hi, seqr.next + FETCH_MAX - 1)
    events = bus.fetch(topic, lo, hi)
    for ev in events:
        on_event(ev)
    if events:
        log.info("%s: fetched %d %s sample(s) in %d-%d from the publisher's cache", bus.stage, len(events),
                 topic, lo, hi)
    elif bus.head(topic) is None:
        return None
    return len(events)


def settle_holes(bus: Any, topic: str, seqr: Sequencer, on_event: Callable[[Any], None]) -> list[tuple[int, Any]]:
    """Ask the live publishers for what ``seqr`` misses below the newest frame received, then
    declare what they did not return (and the window has passed) gaps; returns what is
    released.  Nothing is declared when no publisher answered: the frames may still come."""
    lo, top = seqr.next, seqr.max_seen
    got = fetch_holes(bus, topic, seqr, top, on_event)
    if got is None:
        log.info("%s: no publisher of %s answered for seq %d-%d: asking again later", bus.stage, topic, lo, top)
        return []
    return seqr.confirm_through(min(top, lo + FETCH_MAX - 1))


def resolve_conflict(bus: Any, topic: str, seqr: Sequencer, seq: int, check: Callable[[Any], Any]) -> bool:
    """Two copies of ``seq`` with different payloads (one is not the publisher's: in open mode
    anybody can put): ask the publisher for its copy (validated by ``check``) and keep it.
    False when the publisher does not answer (the earlier copy stays)."""
    for ev in bus.fetch(topic, seq, seq):
        acc = check(ev)
        if acc is not None and acc.seq == seq:
            seqr.replace(seq, acc)
            return True
    return False


def publisher_copy(bus: Any, topic: str, acc: Any, check: Callable[[Any], Any]) -> Any:
    """The publisher's own copy of ``acc``'s seq when it differs from ``acc`` (a copy another
    process put under that seq: in open mode anybody can), else ``acc``.  Asked only for a
    frame out of order with its stream."""
    for ev in bus.fetch(topic, acc.seq, acc.seq):
        own = check(ev)
        if own is not None and own.seq == acc.seq and own.payload != acc.payload:
            log.warning("%s: %s seq %d: the publisher's copy replaces a different one", bus.stage, topic, acc.seq)
            return own
    return acc


class HeadAsk:
    """``ask_head`` of a :class:`Sequencer`: the live head of ``topic`` (:meth:`Bus.head`);
    after nobody answered, not asked again for ``quiet`` seconds (answers ``None``)."""

    def __init__(self, bus: Any, topic: str, monotonic: Callable[[], float] = time.monotonic,
                 quiet: float = 1.0) -> None:
        self.bus, self.topic, self.quiet = bus, topic, quiet
        self._monotonic = monotonic
        self.quiet_until = -float("inf")

    def __call__(self) -> int | None:
        now = self._monotonic()
        if now < self.quiet_until:
            return None
        head = self.bus.head(self.topic)
        if head is None:
            self.quiet_until = now + self.quiet
        return head


def end_gaps_due(got: int | None, idle: float, delivery: DeliveryConfig) -> bool:
    """After the end of stream and ``idle`` seconds without progress, with the fetch of the
    missing frames answered by ``got`` (:func:`fetch_holes`): are they gaps?  Yes once the
    grace has passed and the live publishers hold none of them; when no publisher answers,
    only after ``upstream_gone_s`` more (they may be away with the router)."""
    if idle < delivery.eos_grace_s or got:
        return False
    return got == 0 or idle >= delivery.eos_grace_s + delivery.upstream_gone_s


class RepeatLog:
    """A warning repeated per frame, rate-limited: the first ``first`` occurrences, then every
    ``every``-th with the count so far (a burst of thousands writes a few lines)."""

    def __init__(self, first: int = 20, every: int = 1000) -> None:
        self.first, self.every, self.n = first, every, 0

    def warning(self, msg: str, *args: Any) -> None:
        self.n += 1
        if self.n <= self.first or self.n % self.every == 0:
            log.warning(msg + " [%d so far%s]", *args, self.n,
                        "" if self.n < self.first else f"; logging 1 in {self.every}")


#: Seconds a stream's next frame may be missing, with later ones waiting, before it is fetched.
FETCH_AFTER_S = 1.0
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

    def __init__(self, stage: str, run: str, bus: Any, counters: Counters, max_payload_bytes: int,
                 time_ns: Callable[[], int] = time.time_ns) -> None:
        self.stage = stage
        self._time_ns = time_ns
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
            msg = decode(codec_topic, ev.payload)
        except CodecError as exc:
            return self.reject(ev, seq, str(exc))
        if msg.run != self.run:
            return self.reject(ev, seq, f"{codec_topic} frame {msg.frame}: run {msg.run!r} is not this run {self.run!r}")
        frame = meta.get("frame")
        if frame is not None and frame != msg.frame:
            return self.reject(ev, seq, f"{codec_topic}: attachment frame {frame!r} != payload frame {msg.frame}")
        return Accepted(seq, msg, meta, ev.t_recv_ns, ev.payload)

    def reject(self, ev: Any, seq: int | None, reason: str) -> None:
        """Reject the received sample ``ev`` (returns ``None``, for ``return self.reject(...)``)."""
        return self.reject_sample(ev.topic, ev.payload, seq, reason)

    def reject_sample(self, topic: str, payload: bytes, seq: int | None, reason: str) -> None:
        """Reject a sample of ``topic`` (e.g. an accepted one that a later check refuses):
        a log line, the counters, a copy on ``deadletter``."""
        self.counters.rejected += 1
        self.rejected_by_topic[topic] = self.rejected_by_topic.get(topic, 0) + 1
        n = self.counters.rejected
        if n <= 20 or n % 100 == 0:
            log.warning("%s: rejected %s sample (seq %s, %d bytes): %s [rejected so far: %d]",
                        self.stage, topic, seq, len(payload), reason, n)
        letter = {
            "stage": self.stage,
            "run": self.run,
            "topic": topic,
            "seq": seq,
            "reason": reason,
            "size": len(payload),
            "truncated": len(payload) > DEADLETTER_COPY,
            "payload_b64": base64.b64encode(bytes(payload[:DEADLETTER_COPY])).decode(),
            "t_ns": self._time_ns(),
        }
        try:
            self.bus.publish("deadletter", _JSON.encode(letter))
        except Exception as exc:  # the dead letter is best effort
            log.error("%s: could not publish a dead letter: %s", self.stage, exc)
        return None

