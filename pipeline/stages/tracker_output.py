"""What the tracker stage publishes per frame: the tracker's own estimate (``tracker.lag = 0``)
or the fixed-lag output of :mod:`tracker.lag` (``tracker.lag = N``, ``--lag N``).

With a lag the stage publishes frame ``k - N``'s ``/tracks`` when frame ``k`` arrives, under
the sequence number (and source time stamp) of frame ``k - N``'s ``/measurements`` sample, so
the sink pairs them by sequence number as without a lag.  The frames waiting in the window keep
their ``(seq, meta)`` entries in :class:`StageOutput`'s state (:class:`WindowState`); the
stage's snapshot stores them beside the layer's state, and its journal holds exactly the
samples published before the snapshot, those of sequence numbers below the window's first
(:func:`published_through`).  At the end of the stream the window is published at once
(:meth:`StageOutput.flush`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import msgspec
import numpy as np

from bnptrack.tracker.lag import FixedLag, LagState, restore_lag, snapshot_lag
from bnptrack.tracker.state import restore, snapshot
from bnptrack.tracker.types import Estimate, Frame

__all__ = ["StageOutput", "WindowState", "inner_snapshot", "published_through"]

#: One frame waiting in the window: its ``/measurements`` sequence number and the meta entries
#: the published ``/tracks`` sample carries over from it (``t``, ``t_in``, ``t_deq``).
Entry = tuple[int, dict]


@dataclass(frozen=True)
class WindowState:
    """The fixed-lag layer's state and the ``(seq, meta)`` entries of its window's frames."""

    layer: LagState
    entries: tuple[Entry, ...] = ()


class StageOutput:
    """The stage's tracker with ``lag`` scans of hindsight (``0``: the tracker's own output)."""

    def __init__(self, tracker: Any, params: Any, lag: int) -> None:
        self.tracker, self.lag = tracker, int(lag)
        self.layer = FixedLag(tracker, params, self.lag) if self.lag else None

    def initial_state(self, inner: Any) -> Any:
        """The stage's state over the tracker state ``inner`` (a fresh or a prior one)."""
        return inner if self.layer is None else WindowState(LagState(inner))

    def step(self, state: Any, frame: Frame, rng: np.random.Generator, entry: Entry
             ) -> tuple[Any, list[tuple[Entry, Estimate]]]:
        """Track ``frame`` (whose sample is ``entry``); returns the new state and what to
        publish now: ``[(entry, estimate)]`` (none while the window fills)."""
        if self.layer is None:
            state, est = self.tracker.step(state, frame, rng)
            return state, [(entry, est)]
        layer, out = self.layer.step(state.layer, frame, rng)
        entries = state.entries + (entry,)
        if out.lagged is None:
            return WindowState(layer, entries), []
        return WindowState(layer, entries[1:]), [(entries[0], out.lagged)]

    def flush(self, state: Any) -> tuple[Any, list[tuple[Entry, Estimate]]]:
        """At the end of the stream: the window's frames, published at once (oldest first), and
        the state with an empty window."""
        if self.layer is None or not state.entries:
            return state, []
        out = [(entry, est) for entry, (_f, est) in zip(state.entries, self.layer.flush(state.layer))]
        empty = replace(state.layer, frames=(), online=())
        return WindowState(empty, ()), out

    def snapshot(self, state: Any) -> bytes:
        """The state's bytes (:func:`tracker.state.snapshot`; with a lag, the layer's
        :func:`~tracker.lag.snapshot_lag` and the window's entries)."""
        if self.layer is None:
            return snapshot(state)
        return msgspec.msgpack.encode({"layer": snapshot_lag(state.layer),
                                       "entries": [[s, meta] for s, meta in state.entries]})

    def restore(self, data: bytes, inner_cls: type) -> Any:
        """Inverse of :meth:`snapshot` for a tracker whose state class is ``inner_cls``."""
        if self.layer is None:
            return restore(data, inner_cls)
        doc = msgspec.msgpack.decode(data)
        entries = tuple((int(s), dict(meta)) for s, meta in doc["entries"])
        return WindowState(restore_lag(doc["layer"], inner_cls), entries)


def published_through(last_seq: int, entries: Sequence[Entry]) -> int:
    """The last sequence number whose ``/tracks`` a stage with this window had published
    after processing ``last_seq``: every one before the window's first frame."""
    return entries[0][0] - 1 if entries else last_seq


def inner_snapshot(data: bytes, lag: int) -> bytes:
    """The tracker's own state's bytes (:func:`tracker.state.snapshot`) inside the bytes of
    :meth:`StageOutput.snapshot` of a stage with ``lag``."""
    if not lag:
        return data
    return msgspec.msgpack.decode(msgspec.msgpack.decode(data)["layer"])["inner"]
