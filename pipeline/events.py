"""What a bus delivers: one received sample (:class:`Event`).  Both buses (Zenoh in
:mod:`pipeline.transport`, in-memory in :mod:`pipeline.membus`) produce it and the stages
consume it; it sits below both so that neither bus imports the stages."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Event", "FETCH_MAX"]

#: Most samples one answer of the explicit-history queryable holds (``fetch/<topic>``).
FETCH_MAX = 2000


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
