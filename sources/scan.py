"""What a reader of :data:`sources.readers.READERS` returns (:class:`Scan`) and the helpers
the readers share; a reader module imports only this one, so the table can name the reader
modules without an import cycle."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Scan", "stamp_ns_of", "finite_rows"]


class Scan(NamedTuple):
    """One message's measurements (a named tuple: one per message, made cheaply).

    ``stamp_ns``: the message's own time (``header.stamp``, Foxglove's ``timestamp``), ``None``
    when it has none (the log reader then takes the MCAP log time).  ``frame_id``: the frame
    the rows are expressed in (the sensor's name).  ``z``: ``(M, d)`` float64 rows of the
    reader's kind: ``bearing_range`` rows are bnptrack's ``[bearing, range]`` relative to the
    sensor; ``xy`` rows are ``[x, y]`` in the ``frame_id`` frame (the log reader moves them to
    the world frame with the frame's transform, when the log has one).  Rows with a
    non-finite value are dropped by the reader (an organised point cloud's NaN points)."""

    stamp_ns: int | None
    frame_id: str
    z: np.ndarray


def stamp_ns_of(sec: int, nanosec: int) -> int | None:
    """A ``builtin_interfaces/Time`` (or ``google.protobuf.Timestamp``) in ns; ``None`` when
    it is zero (unset: the log reader takes the MCAP log time) or negative."""
    ns = int(sec) * 1_000_000_000 + int(nanosec)
    return ns if ns > 0 else None


def finite_rows(z: np.ndarray) -> np.ndarray:
    """``z`` as float64 without its rows that hold a non-finite value."""
    z = np.asarray(z, dtype=np.float64)
    ok = np.isfinite(z).all(axis=1)
    return z if ok.all() else z[ok]
