"""Tracker state snapshots and the per-frame random stream.

Snapshots are exact: every array is stored with its dtype and shape as raw little-endian
bytes inside a msgpack document, so ``restore(snapshot(s))`` equals ``s`` bit for bit.
The random stream of frame ``k`` is derived from ``(seed, k)`` alone
(``SeedSequence(seed, spawn_key=(TRACKER_STREAM, k))``), so a restored tracker fed frames
``k+1..`` reproduces an uninterrupted run, whatever happened between frames.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from typing import Any, TypeVar

import msgspec
import numpy as np

from bnptrack.tracker.types import Estimate, Frame

S = TypeVar("S")

#: spawn-key prefix of the tracker's random stream (sources use other keys).
TRACKER_STREAM = 0x7A
SNAPSHOT_VERSION = 1


def tracker_frame_rng(seed: int, frame: int) -> np.random.Generator:
    """The tracker's generator for frame ``frame`` of a run seeded with ``seed`` (spawn key
    ``(TRACKER_STREAM, frame)``; the simulator's measurements use another stream,
    ``sources.synthetic.measurement_frame_rng``)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(TRACKER_STREAM, int(frame))))


def _pack(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        arr = np.ascontiguousarray(value)
        return {"__nd__": True, "dtype": arr.dtype.str, "shape": list(arr.shape), "data": arr.tobytes()}
    if isinstance(value, tuple):
        return {"__tuple__": [_pack(v) for v in value]}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _unpack(value: Any) -> Any:
    if isinstance(value, dict) and value.get("__nd__"):
        arr = np.frombuffer(value["data"], dtype=np.dtype(value["dtype"])).reshape(value["shape"])
        return arr.copy()
    if isinstance(value, dict) and "__tuple__" in value:
        return tuple(_unpack(v) for v in value["__tuple__"])
    return value


def snapshot(state: Any) -> bytes:
    """Serialise a tracker state dataclass exactly (type name, fields, arrays)."""
    fields = {f.name: _pack(getattr(state, f.name)) for f in dataclasses.fields(state)}
    doc = {"v": SNAPSHOT_VERSION, "type": type(state).__name__, "fields": fields}
    return msgspec.msgpack.encode(doc)


def restore(data: bytes, cls: type[S]) -> S:
    """Inverse of :func:`snapshot`; checks version and state type."""
    doc = msgspec.msgpack.decode(data)
    if doc.get("v") != SNAPSHOT_VERSION:
        raise ValueError(f"snapshot version {doc.get('v')!r} is not supported (expected {SNAPSHOT_VERSION})")
    if doc.get("type") != cls.__name__:
        raise ValueError(f"snapshot holds a {doc.get('type')!r}, not a {cls.__name__}")
    return cls(**{k: _unpack(v) for k, v in doc["fields"].items()})


def run(tracker, frames: Iterable[Frame], seed: int, state=None) -> Iterator[tuple[Frame, Estimate, Any]]:
    """Feed frames through ``tracker.step`` with the per-frame streams; yields (frame, estimate, state)."""
    state = tracker.initial_state() if state is None else state
    for frame in frames:
        state, est = tracker.step(state, frame, tracker_frame_rng(seed, frame.frame))
        yield frame, est, state
