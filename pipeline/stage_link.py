"""The private channel between the launcher and each stage process it starts: a Unix socket
pair whose stage end the process inherits (``bnptrack stage --link-fd N``).

Down the channel goes the stage's Zenoh credentials (one JSON line, read once at start-up,
then kept in memory only); up it go the source's reports of what it published
(``{"eos": {"last_seq": s, "frames": n}}`` just before it publishes its end of stream,
``{"stopped": {...}}`` when it stops before its end).  The launcher checks the end of stream
the sink recorded against them (:func:`eos_conflict`).

No other process reads the channel: it is in no environment, command line or file, and a
socket cannot be opened again through ``/proc/<pid>/fd`` (only a process allowed to trace
the stage, i.e. to read its memory, can take the descriptor)."""

from __future__ import annotations

import json
import logging
import select
import os
import socket
from typing import Any

import msgspec

from bnptrack.pipeline.config import PipelineConfig
from bnptrack.tracker.config import ConfigError

__all__ = ["LauncherLink", "StageLink", "linked_stage", "eos_conflict"]

log = logging.getLogger("bnptrack.launch")

#: The most a stage waits for its credentials at start-up (the launcher sends them before it
#: starts the process: they are there at once).
KEY_TIMEOUT_S = 10.0


class LauncherLink:
    """The launcher's end of one stage process's channel: :meth:`child_fd` goes to the
    process (``pass_fds``), :meth:`closed_in_parent` after the start; :meth:`poll` returns
    what the stage reported since the last call."""

    def __init__(self) -> None:
        self.mine, self.theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        self.mine.setblocking(False)
        self._buf = b""

    def child_fd(self) -> int:
        return self.theirs.fileno()

    def send_key(self, user: str, password: str) -> None:
        """Queue the stage's credentials (before the process starts: a few bytes always fit)."""
        self.mine.sendall(json.dumps({"user": user, "password": password}).encode() + b"\n")

    def closed_in_parent(self) -> None:
        self.theirs.close()

    def poll(self) -> list[dict[str, Any]]:
        """The reports that arrived since the last call (never blocks)."""
        while True:
            try:
                chunk = self.mine.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            if not chunk:
                break
            self._buf += chunk
        *lines, self._buf = self._buf.split(b"\n")
        reports = []
        for line in lines:
            try:
                msg = json.loads(line)
            except ValueError:
                continue
            if isinstance(msg, dict):
                reports.append(msg)
        return reports

    def close(self) -> None:
        for s in (self.mine, self.theirs):
            try:
                s.close()
            except OSError:
                pass


class StageLink:
    """A stage process's end of the channel (fd ``fd``, inherited from the launcher)."""

    def __init__(self, fd: int) -> None:
        try:
            self.sock = socket.socket(fileno=fd)
        except OSError as exc:
            raise ValueError(f"not a socket inherited from the launcher ({exc.strerror})") from None

    def read_key(self, timeout: float = KEY_TIMEOUT_S) -> tuple[str, str]:
        """The stage's (user, password), the first line on the channel."""
        buf = b""
        while b"\n" not in buf:
            ready, _, _ = select.select([self.sock], [], [], timeout)
            chunk = self.sock.recv(4096) if ready else b""
            if not chunk:
                raise ValueError("the launcher sent no credentials")
            buf += chunk
        msg = json.loads(buf.partition(b"\n")[0])
        return str(msg["user"]), str(msg["password"])

    def report(self, msg: dict[str, Any]) -> None:
        """Send one report to the launcher (best effort: a launcher that is gone is no error)."""
        try:
            self.sock.sendall(json.dumps(msg).encode() + b"\n")
        except OSError as exc:
            log.debug("report to the launcher failed: %s", exc)

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass


def linked_stage(cfg: PipelineConfig, fd: int | None) -> tuple[PipelineConfig, StageLink | None]:
    """A stage process's pipeline with the credentials its launcher sent on link ``fd`` (kept
    in memory: they win over ``BNPTRACK_ZENOH_USER`` / ``BNPTRACK_ZENOH_PASSWORD``, which are
    removed from this process's environment), and the link (``None`` without ``fd``)."""
    if fd is None:
        return cfg, None
    try:
        link = StageLink(fd)
        user, password = link.read_key()
    except (ValueError, OSError, KeyError) as exc:  # not started by a launcher: one line, exit 2
        raise ConfigError(f"--link-fd {fd}: {exc}") from None
    if not user:
        return cfg, link
    os.environ.pop("BNPTRACK_ZENOH_USER", None)
    os.environ.pop("BNPTRACK_ZENOH_PASSWORD", None)
    return msgspec.structs.replace(cfg, zenoh=msgspec.structs.replace(cfg.zenoh, user=user, password=password)), link


def eos_conflict(source_eos: dict | None, source_stopped: dict | None, recorded: dict | None) -> str:
    """Why the source's end of stream the sink recorded (``recorded``: ``last_seq``, ``frames``)
    is not the source process's own (``""``: it is, or nothing was recorded).  ``source_eos``:
    what the source reported just before it published its end of stream (``None``: it never
    did); ``source_stopped``: what it had published when it was stopped before its end."""
    if not recorded:
        return ""
    rec = f"seq {recorded.get('last_seq')} ({recorded.get('frames')} frame(s))"
    if source_eos is None:
        had = ""
        if source_stopped:
            had = (f"; it had published {source_stopped.get('frames')} frame(s), up to seq "
                   f"{source_stopped.get('last_seq')}, when it was stopped")
        return (f"end of stream conflict: the sink ended the run on an end of stream of the source at {rec} "
                f"that the source process never sent (a forged end of stream){had}")
    if (source_eos.get("last_seq"), source_eos.get("frames")) != (recorded.get("last_seq"), recorded.get("frames")):
        return (f"end of stream conflict: the sink ended the run on an end of stream of the source at {rec}; "
                f"the source process's own end of stream is at seq {source_eos.get('last_seq')} "
                f"({source_eos.get('frames')} frame(s))")
    return ""
