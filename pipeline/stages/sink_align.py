"""The sink stage's pure core: which frames to record, in sequence order, from what each
stream (``measurements``, ``truth``, ``tracks``) has released.

:class:`FrameAligner` takes the items a stream's :class:`~pipeline.stages.delivery.Sequencer`
released (a message, :data:`~pipeline.stages.delivery.GAP` or
:data:`~pipeline.stages.delivery.NO_TRUTH`) and returns what to do as data: :class:`Write`
a frame, :class:`Reject` one whose frame number or stamp breaks the frame bounds,
:class:`Mismatch` a message that names another frame than its ``/measurements``,
:class:`Verify` a ``/measurements`` that does not follow the last frame (the stage asks its
publisher for its own copy of the seq, :meth:`FrameAligner.verified`, and drains again: in
open mode another process may have put a copy under that seq).  It holds no
bus, no clock and no file; :class:`~pipeline.stages.sink.SinkStage` carries the actions out.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from bnptrack.pipeline.stages.delivery import GAP, NO_TRUTH
from bnptrack.tracker.types import FrameBounds, FrameGate

__all__ = ["FrameAligner", "Mismatch", "Reject", "Verify", "Write"]


@dataclass(frozen=True)
class Write:
    """Record frame ``seq``: its items (``truth`` / ``tracks`` may be a gap; ``tracks`` is
    ``None`` when the sink does not record ``/tracks``)."""

    seq: int
    meas: Any
    truth: Any
    tracks: Any


@dataclass(frozen=True)
class Reject:
    """Frame ``seq`` breaks the frame bounds (``why``): none of its messages are recorded."""

    seq: int
    payload: bytes
    why: str


@dataclass(frozen=True)
class Mismatch:
    """The ``stream`` item of ``seq`` is for frame ``frame``, its ``/measurements`` for
    ``meas_frame``: the item is dropped (recorded as a gap)."""

    seq: int
    stream: str
    frame: int
    meas_frame: int


@dataclass(frozen=True)
class Verify:
    """The ``/measurements`` of ``seq`` (``meas``) does not follow the last frame: drain
    stops there until the stage hands the publisher's own copy to :meth:`FrameAligner.verified`."""

    seq: int
    meas: Any


class FrameAligner:
    """Frames in sequence order from the released items of ``streams``.

    :meth:`release` files a stream's released ``(seq, item)`` pairs and returns the seqs
    released as gaps; :meth:`drain` returns the actions for every frame whose streams have
    all released their item, from :attr:`next_write` on.  :attr:`rejected_seqs` and
    :attr:`mismatched` keep what was left out (for ``sink.json``'s ``missing``).
    """

    def __init__(self, streams: Iterable[str], bounds: FrameBounds, next_write: int = 0) -> None:
        self.ready: dict[str, dict[int, Any]] = {k: {} for k in streams}
        self.bounds = bounds
        #: the frame bounds as ``track`` applies them (:class:`~tracker.types.FrameGate`)
        self.gate = FrameGate(bounds)
        self.next_write = next_write
        self.rejected_seqs: list[int] = []
        self.mismatched: dict[str, list[int]] = {}
        self.checked = -1  # the seq whose /measurements is the publisher's own copy

    def verified(self, s: int, meas: Any) -> None:
        """``meas`` is the publisher's own copy of seq ``s`` (after :class:`Verify`)."""
        self.ready["measurements"][s] = meas
        self.checked = s

    def release(self, stream: str, released: Iterable[tuple[int, Any]]) -> list[int]:
        """File ``stream``'s released items; the seqs among them that are gaps."""
        r = self.ready[stream]
        gaps = []
        for s, item in released:
            if item is GAP:
                gaps.append(s)
            r[s] = item
        return gaps

    def restart_at(self, next_write: int, last_frame: int, last_stamp_ns: int | None) -> None:
        """Continue after frames recorded elsewhere (recovered from a ``.part`` file)."""
        self.next_write = next_write
        self.gate.restore(last_frame, last_stamp_ns)

    @property
    def last_frame(self) -> int:
        """The frame number of the last frame recorded."""
        return self.gate.last_frame

    @property
    def last_stamp_ns(self) -> int | None:
        """The time stamp of the last frame recorded."""
        return self.gate.last_stamp_ns

    def drain(self) -> list[Write | Reject | Mismatch | Verify]:
        """The actions of every frame ready from :attr:`next_write` on, in order."""
        ready = self.ready
        has_tracks = "tracks" in ready
        out: list[Write | Reject | Mismatch | Verify] = []
        while True:
            s = self.next_write
            if s not in ready["measurements"] or s not in ready["truth"]:
                return out
            if has_tracks and s not in ready["tracks"]:
                return out
            if self._unchecked(s, ready["measurements"][s]):
                out.append(Verify(s, ready["measurements"][s]))
                return out
            meas = ready["measurements"].pop(s)
            truth = self._same_frame(s, "truth", ready["truth"].pop(s), meas, out)
            tracks = self._same_frame(s, "tracks", ready["tracks"].pop(s), meas, out) if has_tracks else None
            why = self._out_of_bounds(meas)
            if why is None:
                out.append(Write(s, meas, truth, tracks))
            else:
                self.rejected_seqs.append(s)
                out.append(Reject(s, meas.payload, why))
            self.next_write += 1

    def _unchecked(self, s: int, meas: Any) -> bool:
        """Whether ``meas`` (seq ``s``) breaks the bounds and is not yet the publisher's copy."""
        if meas is GAP or s == self.checked:
            return False
        m, g = meas.msg, self.gate
        return self.bounds.violation(g.last_frame, g.last_stamp_ns, m.frame, m.stamp_ns) is not None

    def _out_of_bounds(self, meas: Any) -> str | None:
        """Why the frame of ``meas`` may not be recorded (its frame number and stamp must
        advance within the frame bounds, as the tracker checks them); ``None``: it may."""
        if meas is GAP:
            return None
        return self.gate.admit(meas.msg.frame, meas.msg.stamp_ns)

    def _same_frame(self, s: int, stream: str, item: Any, meas: Any, out: list) -> Any:
        """``item`` (of ``stream``, seq ``s``) if it is for the frame of ``meas``, or if
        either is missing; otherwise :data:`GAP`, and a :class:`Mismatch` in ``out``."""
        if item is GAP or item is NO_TRUTH or meas is GAP or item.msg.frame == meas.msg.frame:
            return item
        self.mismatched.setdefault(stream, []).append(s)
        out.append(Mismatch(s, stream, item.msg.frame, meas.msg.frame))
        return GAP
