"""The tracker stage's pure core: which ``/measurements`` frames to track, in sequence order.

:class:`TrackerCore` holds the stream's :class:`~pipeline.stages.delivery.Sequencer` and the
position of the run (last seq, frame and stamp; the frames rejected).  For each frame the
sequencer releases, :meth:`TrackerCore.decide` returns what to do as data: :class:`Step`
(track it), :class:`Skip` (a gap: predict through it), :class:`Reject` (its frame number or
stamp breaks the frame bounds of :class:`~tracker.types.FrameGate`, the one rule of ``track``
and the pipeline, with its resynchronisation after a genuine jump), :class:`Verify` (it does not follow the last frame: ask its
publisher for its own copy of that seq first, then decide again with ``own=True``; in open
mode another process may have put a copy under that seq).  The position advances past a tracked frame only when the
stage says its tracks are out (:meth:`TrackerCore.stepped`), so a snapshot taken at any
point is consistent.  No bus, no clock, no file: :class:`~pipeline.stages.tracker.TrackerStage`
carries the actions out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bnptrack.pipeline.stages.delivery import GAP, Sequencer
from bnptrack.tracker.messages import to_frame
from bnptrack.tracker.types import Frame, FrameBounds, FrameGate

__all__ = ["Reject", "Skip", "Step", "TrackerCore", "Verify"]


@dataclass(frozen=True)
class Step:
    """Track frame ``seq``: ``item`` as received, ``frame`` decoded; ``fresh``: the frame
    resynchronises the stream (the tracker starts again from its initial state)."""

    seq: int
    item: Any
    frame: Frame
    fresh: bool = False


@dataclass(frozen=True)
class Skip:
    """Frame ``seq`` is a gap: the tracker predicts through it."""

    seq: int


@dataclass(frozen=True)
class Reject:
    """Frame ``seq`` breaks the frame bounds (``why``), before the tracker predicts through
    the jump: it is not tracked."""

    seq: int
    payload: bytes
    why: str


@dataclass(frozen=True)
class Verify:
    """Frame ``seq`` (``item``) does not follow the last frame: the stage fetches the
    publisher's own copy of the seq (:func:`~pipeline.stages.delivery.publisher_copy`) and
    decides again on that copy (``decide(seq, copy, own=True)``)."""

    seq: int
    item: Any


class TrackerCore:
    """The order of a run's ``/measurements`` and the position reached in it."""

    def __init__(self, seq: Sequencer, bounds: FrameBounds) -> None:
        self.seq = seq
        self.bounds = bounds
        self.gate = FrameGate(bounds)
        #: the gate's run of skipped frames before the frame decided but not yet stepped
        self.gate_before: tuple[int, int, int | None] | None = None
        self.last_seq = -1
        self.last_frame = -1
        self.last_stamp_ns: int | None = None
        self.rejected_seqs: list[int] = []

    def resume(self, seq: Sequencer, last_seq: int, last_frame: int, last_stamp_ns: int | None,
               rejected: list[int], gate: tuple[int, int, int | None] = (0, -1, None)) -> None:
        """Continue from a snapshot's position (``seq``: its sequencer, gaps restored;
        ``gate``: :meth:`gate_state`)."""
        self.gate.restore(last_frame, last_stamp_ns, gate)
        self.seq = seq
        self.last_seq, self.last_frame, self.last_stamp_ns = last_seq, last_frame, last_stamp_ns
        self.rejected_seqs = list(rejected)

    def push(self, seq: int, item: Any) -> tuple[str, list[tuple[int, Any]]]:
        """:meth:`Sequencer.push`: the status of ``item`` and the frames it releases."""
        return self.seq.push(seq, item)

    def decide(self, s: int, item: Any, own: bool = False) -> Step | Skip | Reject | Verify:
        """What to do with released frame ``s`` (a gap or a rejected frame moves the position
        past it at once; a frame to track, once :meth:`stepped`).  ``own``: ``item`` is the
        publisher's copy (no :class:`Verify` again)."""
        if item is GAP:
            self.last_seq = s
            return Skip(s)
        m, g = item.msg, self.gate
        if not own and self.bounds.violation(g.last_frame, g.last_stamp_ns, m.frame, m.stamp_ns) is not None:
            return Verify(s, item)
        before = g.state()
        why = g.admit(m.frame, m.stamp_ns)
        if why is not None:
            self.rejected_seqs.append(s)
            self.last_seq = s
            return Reject(s, item.payload, why)
        self.gate_before = before
        return Step(s, item, to_frame(m), g.resynced)

    def gate_state(self) -> tuple[int, int, int | None]:
        """The frame gate's run of skipped frames at the position (for a snapshot)."""
        return self.gate.state() if self.gate_before is None else self.gate_before

    def stepped(self, s: int, frame: Frame) -> None:
        """Frame ``s`` is tracked and its tracks are out: the position moves past it."""
        self.gate_before = None
        self.last_seq, self.last_frame, self.last_stamp_ns = s, frame.frame, frame.stamp_ns
