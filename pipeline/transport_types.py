"""Zenoh-free types shared by :mod:`pipeline.transport` and its in-memory twin
:mod:`pipeline.membus`."""

from __future__ import annotations

import socket
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["Event", "listening"]


def listening(endpoints: Sequence[str], timeout: float = 1.0) -> bool | None:
    """Whether something accepts TCP connections at one of the ``tcp/`` or ``tls/``
    ``endpoints`` (``HOST:PORT``); ``None`` when an endpoint of another protocol (or an
    unparsable one) is listed, which is not probed."""
    probed = False
    for ep in endpoints:
        proto, _, addr = ep.partition("/")
        host, colon, port = addr.split("#")[0].rpartition(":")
        if proto not in ("tcp", "tls") or not colon or not port.isdigit():
            return None
        probed = True
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
            return True
        except OSError:
            continue
    return False if probed else None


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
