"""Watch a run live in the Rerun viewer (``--view``, ``--connect URL`` of ``bnptrack track``,
``launch`` and ``replay``).

The recording is streamed to a viewer's gRPC server while it is written to its ``.rrd`` file
(:class:`sinks.rerun_sink.RerunSink` ``live=URL``: one recording stream, two sinks, the same
rows).  :func:`spawn_viewer` starts the ``rerun`` viewer that ships with rerun-sdk on a free
loopback port and waits until it listens (the viewer is left running when the run ends, as
``rr.spawn`` leaves it: close its window when done); :func:`check_viewer` makes sure a viewer
given by URL (``--connect``) is there before anything starts, so a wrong URL is a one-line
error (exit code 2), not 5 s of retries at the end of the run.

This module does not import rerun.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from bnptrack.pipeline.ports import free_port
from bnptrack.tracker.config import ConfigError

__all__ = ["Viewer", "viewer_url", "is_viewer_url", "check_viewer", "spawn_viewer"]

_SCHEMES = ("rerun", "rerun+http", "rerun+https")

#: Environment variable: when set (to anything but ``0``), :func:`spawn_viewer` starts the
#: viewer with ``--headless`` (no window: tests and machines without a display).
HEADLESS_ENV = "BNPTRACK_VIEWER_HEADLESS"


@dataclass
class Viewer:
    """A viewer this process started: its gRPC URL and process (left running)."""

    url: str
    proc: subprocess.Popen
    log: Path

    @property
    def pid(self) -> int:
        return self.proc.pid


def is_viewer_url(text: str) -> bool:
    """True for a Rerun URL (``rerun+http://...``, ``rerun://...``) or a bare port (``9876``, a
    viewer on this machine, as :func:`viewer_url` reads it) -- as opposed to a Zenoh endpoint
    (``tcp/HOST:PORT``), which ``launch --connect`` also takes."""
    return text.partition("://")[0] in _SCHEMES or _is_port(text.strip())


def _is_port(text: str) -> bool:
    """``text`` is a port number in ASCII digits (``9876``; not ``²``)."""
    return text.isascii() and text.isdigit()


def viewer_url(text: str) -> str:
    """The gRPC URL of a viewer: a port (``9876``) means ``rerun+http://127.0.0.1:PORT/proxy``,
    as for ``rerun --connect``; a URL must use ``rerun://``, ``rerun+http://`` or
    ``rerun+https://`` and the path ``/proxy``."""
    text = text.strip()
    if _is_port(text):
        if not 0 < int(text) <= 65535:
            raise ConfigError(f"--connect {text}: a port is 1-65535")
        return f"rerun+http://127.0.0.1:{int(text)}/proxy"
    parts = urlsplit(text)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in _SCHEMES or not parts.hostname or port is None or parts.path != "/proxy":
        raise ConfigError(f"--connect {text!r}: expected a Rerun viewer URL like "
                          "rerun+http://127.0.0.1:9876/proxy (or a port)")
    return text


def check_viewer(url: str, timeout: float = 2.0) -> str:
    """Raise :class:`ConfigError` unless something accepts TCP connections at ``url``'s host
    and port; returns the URL."""
    url = viewer_url(url)
    parts = urlsplit(url)
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=timeout):
            pass
    except OSError as exc:
        raise ConfigError(f"no Rerun viewer at {url} ({exc.strerror or exc}): start one with `rerun` "
                          "(or `rerun --serve-grpc`), or use --view to start one") from None
    return url


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


def _headless(headless: bool | None) -> bool:
    """``headless``, or by default whether :data:`HEADLESS_ENV` is set (not ``0``)."""
    if headless is None:
        return os.environ.get(HEADLESS_ENV, "0") not in ("", "0")
    return headless


def viewer_command(*, headless: bool | None = None) -> list[str]:
    """The command :func:`spawn_viewer` runs, less its port: the ``rerun`` CLI, headless when
    ``headless`` (default: :data:`HEADLESS_ENV`).  Raises
    :class:`pipeline.view.ViewerUnavailable` when there is no display (Linux without
    ``DISPLAY`` / ``WAYLAND_DISPLAY``) or no ``rerun`` CLI: the commands call it while checking
    their options, before anything is written (``--view``)."""
    from bnptrack.pipeline.view import ViewerUnavailable
    from bnptrack.sinks.rerun_tools import RerunToolError, rerun_cli

    headless = _headless(headless)
    if not headless and sys.platform.startswith("linux") and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerUnavailable(
            "--view: no display (neither DISPLAY nor WAYLAND_DISPLAY is set); run a viewer where "
            "you can see it (`rerun`, or `rerun --serve-web` for a browser) and pass "
            "--connect rerun+http://HOST:9876/proxy, or open the recording afterwards with "
            "`bnptrack view`")
    if not headless and sys.platform.startswith("linux"):
        unreachable = display_unreachable(os.environ)
        if unreachable:
            raise ViewerUnavailable(
                f"--view: {unreachable}: the viewer cannot open a window; start the display, or run a "
                "viewer where you can see it and pass --connect rerun+http://HOST:9876/proxy, or open "
                "the recording afterwards with `bnptrack view`")
    try:
        cli = rerun_cli()
    except RerunToolError as exc:
        raise ViewerUnavailable(str(exc)) from exc
    return [*cli, "--headless"] if headless else cli


def display_unreachable(env: Mapping[str, str]) -> str:
    """Why no window can open on the display of ``env``, or ``""`` when one can be reached:
    a Wayland socket (``$XDG_RUNTIME_DIR/$WAYLAND_DISPLAY``) that exists, or an X server that
    accepts a connection on ``DISPLAY`` (its local socket ``/tmp/.X11-unix/X<N>``, abstract
    or on disk, or TCP port 6000 + N of a ``HOST:N``).  Checked in well under a second."""
    wayland = env.get("WAYLAND_DISPLAY", "")
    if wayland:
        path = wayland if os.path.isabs(wayland) else os.path.join(env.get("XDG_RUNTIME_DIR", ""), wayland)
        if os.path.exists(path):
            return ""
    display = env.get("DISPLAY", "")
    if not display:
        return f"the Wayland display {wayland} has no socket" if wayland else "no display"
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return f"DISPLAY={display} is not of the form [HOST]:N"
    if host and host not in ("unix", "localhost") and not host.startswith("/"):
        targets = [(socket.AF_INET, (host, 6000 + int(number)))]
    else:
        path = f"/tmp/.X11-unix/X{number}"
        targets = [(socket.AF_UNIX, "\0" + path), (socket.AF_UNIX, path)]
        if host == "localhost":
            targets.append((socket.AF_INET, ("127.0.0.1", 6000 + int(number))))
    for family, address in targets:
        try:
            with socket.socket(family, socket.SOCK_STREAM) as s:
                s.settimeout(1.0)
                s.connect(address)
                return ""
        except OSError:
            continue
    return f"no X server answers on DISPLAY={display}"


def spawn_viewer(*, headless: bool | None = None, timeout: float = 30.0) -> Viewer:
    """Start the Rerun viewer on a free port of 127.0.0.1 and wait until it listens.

    ``headless`` (default: :data:`HEADLESS_ENV`) runs it without a window.  Raises
    :class:`pipeline.view.ViewerUnavailable` when :func:`viewer_command` does (no display, no
    CLI) or the viewer exits or does not listen in ``timeout`` seconds.  Its output goes to a
    log file in the temporary directory (named in errors).
    """
    from bnptrack.pipeline.view import ViewerUnavailable, viewer_failure
    from bnptrack.sinks.rerun_tools import rerun_env

    headless = _headless(headless)
    command = viewer_command(headless=headless)
    port = free_port()
    cmd = [*command, "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"]
    fd, name = tempfile.mkstemp(prefix="bnptrack-viewer-", suffix=".log")
    log = Path(name)
    with os.fdopen(fd, "wb") as log_f:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log_f, stderr=subprocess.STDOUT,
                                env=rerun_env(analytics=not headless, quiet=True), start_new_session=True)
    deadline = time.monotonic() + timeout
    while not _listening(port):
        if proc.poll() is not None:
            raise viewer_failure(log, f"the Rerun viewer exited at start (code {proc.returncode}; log {log})")
        if time.monotonic() > deadline:
            proc.terminate()
            raise ViewerUnavailable(f"the Rerun viewer did not listen on port {port} within {timeout:g} s "
                                    f"(log {log})")
        time.sleep(0.05)
    return Viewer(f"rerun+http://127.0.0.1:{port}/proxy", proc, log)
