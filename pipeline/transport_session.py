"""Zenoh sessions of bnptrack: a :class:`~pipeline.config.ZenohConfig` as a ``zenoh.Config``
(mode, endpoints, TLS, credentials, the router's access control; :func:`session_config`),
opened with one-line errors (:func:`open_session`), and the :class:`Router` in this process.
With :mod:`pipeline.transport` (the stages' :class:`~pipeline.transport.Bus`) and
:mod:`pipeline.transport_liveliness`, the only modules that import zenoh."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from typing import Any

import zenoh

from bnptrack.pipeline.acl import acl_config
from bnptrack.pipeline.config import ZenohConfig
from bnptrack.pipeline.ports import free_port
from bnptrack.pipeline.preflight import listening

__all__ = ["PEER_LISTEN", "SHM_OFF", "NoRouterError", "Router", "TransportError", "open_session", "session_config"]

#: Where a peer-mode stage listens unless ``zenoh.listen`` says otherwise (a free loopback port).
PEER_LISTEN = ("tcp/127.0.0.1:0",)

#: Zenoh's shared-memory transport, switched off in every session (``zenoh.extra`` may turn it
#: back on).  Zenoh 1.x enables it by default and then sends each sample above 3 KB
#: (``transport/shared_memory/transport_optimization/message_size_threshold``) through a
#: shared-memory pool instead of the socket.  The pool is created lazily, by the first put of
#: such a sample on the publishing thread itself: a file in /dev/shm created, sized, mapped and
#: mlocked, and two watchdog threads started (seen with ``strace``).  That put blocked for 5 to
#: 120 ms (``benchmarks/pipeline_latency.py --first-puts 5800``; 0.1-0.6 ms without shared
#: memory), and it is the tracker's first /tracks of several KB, some ten frames into every
#: run.  The samples of a pipeline are a few KB: a socket copy costs microseconds.
SHM_OFF = ("transport/shared_memory/enabled", "false")

class TransportError(ConnectionError):
    """A Zenoh session could not be opened or configured (an ``OSError``: the CLI reports
    it on one line with exit code 2)."""


class NoRouterError(TransportError):
    """No Zenoh router answered at the endpoints a session was to connect to."""


def _resolve_port0(endpoints: Sequence[str]) -> list[str]:
    """Replace a ``:0`` port with a free one (Zenoh does not report the port it bound)."""
    out = []
    for ep in endpoints:
        proto, sep, rest = ep.partition("/")
        host, colon, port = rest.rpartition(":")
        if sep and colon and port == "0":
            h = host.strip("[]") or "127.0.0.1"
            ep = f"{proto}/{host}:{free_port(h if h != '0.0.0.0' else '127.0.0.1')}"
        out.append(ep)
    return out


def session_config(
    zcfg: ZenohConfig,
    *,
    mode: str | None = None,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    router: bool = False,
) -> zenoh.Config:
    """A ``zenoh.Config`` for a stage (client/peer) or, with ``router``, for the router."""
    conf = zenoh.Config()
    ins = conf.insert_json5
    mode = "router" if router else (mode or zcfg.mode)
    ins("mode", json.dumps(mode))
    connect = list(zcfg.connect if connect is None else connect)
    listen = list(zcfg.listen if listen is None else listen)
    if mode == "peer" and not listen:
        # a peer listens so that the others connect to it directly (they learn its
        # endpoint by gossip through the router); Zenoh's default would be every interface
        listen = list(PEER_LISTEN)
    if connect:
        ins("connect/endpoints", json.dumps(connect))
    if listen or mode != "client":
        ins("listen/endpoints", json.dumps(listen))
    ins("scouting/multicast/enabled", json.dumps(bool(zcfg.multicast_scouting)))
    # no shared memory (see SHM_OFF): before ``extra``, which may turn it back on
    ins(*SHM_OFF)
    if not router and connect and zcfg.connect_timeout_s > 0:
        # keep trying to reach the router for a while at start-up (it may come up a moment
        # later on another host) instead of failing at once
        ins("connect/timeout_ms", json.dumps(int(zcfg.connect_timeout_s * 1000)))
    tls = zcfg.tls
    for name, value in tls.files().items():
        ins(f"transport/link/tls/{name}", json.dumps(value))
    if tls.mtls:
        ins("transport/link/tls/enable_mtls", "true")
    if not tls.verify_name_on_connect:
        ins("transport/link/tls/verify_name_on_connect", "false")
    if router:
        if zcfg.users_file:
            ins("transport/auth/usrpwd/dictionary_file", json.dumps(zcfg.users_file))
        if zcfg.acl:
            ins("access_control", json.dumps(acl_config()))
    else:
        user = os.environ.get("BNPTRACK_ZENOH_USER") or zcfg.user
        password = os.environ.get("BNPTRACK_ZENOH_PASSWORD") or zcfg.password
        if user:
            ins("transport/auth/usrpwd/user", json.dumps(user))
            ins("transport/auth/usrpwd/password", json.dumps(password))
    for path, value in zcfg.extra.items():
        ins(path, value)
    if router:
        for path, value in zcfg.router_extra.items():
            ins(path, value)
    return conf


#: Zenoh appends the Rust source location of an error (`` at /path/file.rs:123.``).
_RUST_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?\s*$")


def open_session(conf: zenoh.Config, what: str, connect: Sequence[str] = ()) -> zenoh.Session:
    """``zenoh.open``; a failure is a one-line :class:`TransportError`, and
    :class:`NoRouterError` with a hint when no router answered at ``connect``."""
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError and friends
        text = _RUST_LOCATION.sub("", " ".join(str(exc).split()))
        if connect and "Unable to connect" in text and listening(connect) is not True:
            eps = ", ".join(connect)
            raise NoRouterError(
                f"no router at {eps}: start one with `bnptrack router --listen {connect[0]}`, "
                "or connect to the endpoint `bnptrack launch` printed"
            ) from exc
        hint = ""
        if connect and "Unable to connect" in text:
            hint = " (a router is listening there: check the TLS certificates, user and password)"
        raise TransportError(f"cannot open the Zenoh session of {what}: {text}{hint}") from exc


class Router:
    """A Zenoh router in this process (``mode: router``), listening on ``endpoints``.

    Stages connect to it as clients.  ``tcp/127.0.0.1:0`` picks a free port; the endpoints
    actually used are in :attr:`endpoints`.  Close it (or use ``with``).
    """

    def __init__(self, zcfg: ZenohConfig, listen: Sequence[str] | None = None, attempts: int = 5):
        wanted = list(listen if listen is not None else zcfg.router_listen)
        last: Exception | None = None
        for _ in range(attempts):
            eps = _resolve_port0(wanted)
            try:
                self.session = open_session(session_config(zcfg, listen=eps, connect=[], router=True), "the router")
            except TransportError as exc:  # port taken in between: try another
                last = exc
                if eps == wanted:
                    break
                continue
            self.endpoints = eps
            return
        raise TransportError(f"router could not listen on {wanted}: {last}")

    @property
    def connect_endpoints(self) -> list[str]:
        """Endpoints a client on this host uses (``0.0.0.0`` -> ``127.0.0.1``)."""
        return [ep.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:") for ep in self.endpoints]

    def close(self) -> None:
        s, self.session = getattr(self, "session", None), None
        if s is not None:
            s.close()

    def __enter__(self) -> "Router":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
