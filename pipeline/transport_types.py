"""Zenoh-free types shared by :mod:`pipeline.transport` and its in-memory twin
:mod:`pipeline.membus`."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Event"]


@dataclass(frozen=True)
class Event:
    """One received sample: ``topic`` relative to the run (e.g. ``"measurements"``,
    ``"eos/source"``), payload bytes, decoded attachment (``None`` if absent or invalid, then
    ``meta_error`` says why), receive time (``time.time_ns()``)."""

    topic: str
    payload: bytes
    meta: dict | None
    t_recv_ns: int
    meta_error: str | None = None
