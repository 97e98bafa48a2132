"""Zenoh endpoints (locators) as a user gives them: :func:`check_endpoint` refuses a malformed
one with a line naming the option or key, before any session or process starts (Zenoh's own
error is a traceback from its configuration parser)."""

from __future__ import annotations

__all__ = ["check_endpoint", "HOST_PORT_PROTOCOLS", "OTHER_PROTOCOLS"]

#: Zenoh's link protocols whose address is ``host:port``, and those with another address
#: (a socket path, a device name, ...).
HOST_PORT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")


def check_endpoint(endpoint: str, where: str) -> None:
    """Raise :class:`ValueError` (one line naming ``where``, e.g. ``--connect``) unless
    ``endpoint`` is a Zenoh locator ``PROTO/ADDRESS`` (``tcp/10.0.0.5:7447``,
    ``tls/[::1]:7447``, ``unixsock-stream/PATH``; ``?`` / ``#`` options after the address)."""
    proto, sep, rest = endpoint.partition("/")
    address = rest.split("#", 1)[0].split("?", 1)[0]
    known = HOST_PORT_PROTOCOLS + OTHER_PROTOCOLS
    if not sep or proto not in known or not address:
        raise ValueError(f"{where} {endpoint!r}: expected a Zenoh endpoint PROTO/ADDRESS such as "
                         f"tcp/10.0.0.5:7447 (PROTO one of {', '.join(known)})")
    if proto in HOST_PORT_PROTOCOLS:
        host, colon, port = address.rpartition(":")
        if not colon or not host or not port.isdigit() or int(port) > 65535:
            raise ValueError(f"{where} {endpoint!r}: expected {proto}/HOST:PORT with a port 0-65535, "
                             f"e.g. {proto}/10.0.0.5:7447")
