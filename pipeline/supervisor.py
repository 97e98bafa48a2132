"""The launcher's side of the stage processes: a supervised process (:class:`StageProcess`),
the end of a launch (:class:`LaunchResult`) and the health monitor (:class:`HealthMonitor`);
and the stage's side of the launcher's SIGTERM (:func:`stop_on_signals`)."""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import secrets
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from bnptrack.pipeline.config import PipelineConfig, ZenohConfig
from bnptrack.pipeline.stage_link import LauncherLink
from bnptrack.pipeline.stages import EXIT_STOPPED
from bnptrack.pipeline.stages.base import set_stop
from bnptrack.pipeline.stages.summary import RunSummary, read_summary

__all__ = ["StageProcess", "LaunchResult", "HealthMonitor", "open_embedded_router", "recorded_complete",
           "sink_left_output", "write_stages", "record_exit", "stop_stages", "StopSignals", "stop_on_signals"]

log = logging.getLogger("bnptrack.launch")


@dataclass
class StageProcess:
    role: str
    argv: list[str]
    log_path: Path
    proc: subprocess.Popen | None = None
    restarts: int = 0
    state: str = "pending"  # pending | running | done | failed | stopped
    returncode: int | None = None
    restart_at: float | None = None
    history: list[dict] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)
    key: tuple[str, str] | None = None
    """The stage's Zenoh (user, password): sent down its :class:`LauncherLink`, never in its
    environment, command line or a file."""
    link: LauncherLink | None = None
    reports: list[dict] = field(default_factory=list)
    """What the stage's processes reported on their links, in order (over restarts)."""

    def start(self, env: dict[str, str]) -> None:
        env = {**env, **self.env}
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self.poll_reports()
        if self.link is not None:
            self.link.close()
        self.link = link = LauncherLink()
        user, password = self.key or ("", "")
        link.send_key(user, password)
        try:
            with open(self.log_path, "ab") as logf:
                logf.write(f"--- start #{self.restarts} {time.strftime('%H:%M:%S')}\n".encode())
                logf.flush()
                self.proc = subprocess.Popen(
                    [*self.argv, "--link-fd", str(link.child_fd())], stdin=subprocess.DEVNULL, stdout=logf,
                    stderr=subprocess.STDOUT, env=env, process_group=0, pass_fds=(link.child_fd(),),
                )
        finally:
            link.closed_in_parent()
        self.state = "running"
        self.restart_at = None
        self.history.append({"pid": self.proc.pid, "start": time.time()})

    def close_link(self) -> None:
        """Take the last reports and close the link (the process has exited)."""
        self.poll_reports()
        if self.link is not None:
            self.link.close()
            self.link = None

    def poll_reports(self) -> list[dict]:
        """Every report the stage's processes sent so far (reads what has arrived)."""
        if self.link is not None:
            self.reports.extend(self.link.poll())
        return self.reports

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def signal(self, sig: int) -> None:
        if self.alive():
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass

    def error_line(self) -> str:
        """The stage's configuration error, from its log: its ``Error: ...`` line (printed by
        the ``stage`` command) or its ``configuration error: ...`` log record; else the last
        lines of the log."""
        try:
            lines = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return ""
        for line in reversed(lines):
            if line.startswith("Error: "):
                return line[len("Error: "):]
            for marker in ("configuration error: ", "I/O error: "):
                head, sep, msg = line.partition(marker)
                if sep and " ERROR " in head:
                    return msg
        return " / ".join(lines[-3:])

    def tail(self, n: int = 12) -> str:
        try:
            lines = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(lines[-n:])


@dataclass
class LaunchResult:
    """The end of a launch.  ``ok``: every stage finished and the output is complete.
    ``incomplete`` (exit code 3): what the output lacks, when the run ended but its output is
    incomplete (gaps, rejected frames, a stage that gave up: ``gave_up`` names it);
    ``error`` (exit code 2): why the run failed otherwise."""

    run: str
    out: Path
    ok: bool
    error: str = ""
    interrupted: bool = False
    incomplete: str = ""
    gave_up: str = ""
    files: list[str] = field(default_factory=list)
    summary: RunSummary | None = None
    restarts: dict[str, int] = field(default_factory=dict)
    elapsed_s: float = 0.0
    endpoints: list[str] = field(default_factory=list)


class HealthMonitor:
    """The launcher's subscription to ``health/*`` and ``deadletter``: appends every message
    to ``<out>/health.jsonl``, keeps each role's latest health message (:attr:`latest`, for
    the progress line) and the I/O error line a stage reported (:attr:`io_errors`)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.bus = None
        self.file = None
        self.latest: dict[str, dict] = {}  # role -> its latest health message
        self.io_errors: dict[str, str] = {}  # stage -> its I/O error line, from its health message

    def open(self, cfg: PipelineConfig, credentials: dict[str, str]) -> None:
        from bnptrack.pipeline.transport import Bus

        z = msgspec.structs.replace(cfg.zenoh, mode="client", listen=[])  # it only listens to health
        if "launcher" in credentials:
            z = msgspec.structs.replace(z, user="launcher", password=credentials["launcher"])
        try:
            self.bus = Bus(cfg.run, "launcher", z, cfg.delivery)
            self.bus.subscribe(["health/*", "deadletter"], advanced=False)
        except Exception as exc:  # monitoring is optional
            log.warning("launcher: no health monitor: %s", exc)
            self.bus = None
        self.file = open(self.out / "health.jsonl", "ab")

    def drain(self) -> None:
        if self.bus is None:
            return
        lines = []
        while (ev := self.bus.recv(0)) is not None:
            lines.append(json.dumps(self._record(ev)).encode() + b"\n")
        if self.file is None:
            return
        try:
            self.file.writelines(lines)
            self.file.flush()
        except OSError as exc:  # disk full: health records are not worth stopping the run for
            log.error("launcher: cannot write %s: %s; no more health records", self.out / "health.jsonl", exc)
            hf, self.file = self.file, None
            try:
                hf.close()
            except OSError:
                pass

    def _record(self, ev: Any) -> dict:
        rec = {"topic": ev.topic, "t_ns": ev.t_recv_ns}
        try:
            rec["msg"] = json.loads(ev.payload)
            if ev.topic.startswith("health/") and isinstance(rec["msg"], dict):
                self.latest[str(rec["msg"].get("role", ""))] = rec["msg"]
        except ValueError:
            rec["raw"] = ev.payload[:200].decode("latin-1")
        msg = rec.get("msg")
        if ev.topic.startswith("health/") and isinstance(msg, dict) and isinstance(msg.get("io_error"), str):
            self.io_errors[ev.topic.partition("/")[2]] = msg["io_error"]
        return rec

    def await_error(self, role: str, timeout: float = 1.0) -> None:
        """Drain until ``role``'s I/O error line has arrived, or ``timeout``."""
        deadline = time.monotonic() + timeout
        while role not in self.io_errors and time.monotonic() < deadline and self.bus is not None:
            self.drain()
            time.sleep(0.02)

    def close(self) -> None:
        try:
            self.drain()
        except Exception:
            pass
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        hf, self.file = self.file, None
        if hf is not None:
            try:
                hf.close()
            except OSError:  # disk full: what could not be written is lost
                pass


def recorded_complete(summary_path: Path, run: str) -> bool:
    """Whether ``sink.json`` says the sink recorded the whole run ``run`` (then finishes
    renaming its outputs, should it have been killed in between)."""
    from bnptrack.pipeline.stages.recovery import commit_parts

    summary = read_summary(summary_path, run)
    if summary is None or not summary.complete:
        return False
    commit_parts(summary.files)
    return True


def sink_left_output(cfg: PipelineConfig, out: Path) -> bool:
    """Whether a sink process of run ``cfg.run`` left an output in ``out`` that a sink
    restarted with nobody else there finalizes (exit 3): a ``sink.json`` of this run, or a
    ``.tracks.mcap.part`` with a readable frame (:func:`pipeline.stages.salvage_part`)."""
    from bnptrack.pipeline.stages.recovery import SUMMARY_NAME, part_path
    from bnptrack.pipeline.stages.salvage import salvage_part

    if read_summary(out / SUMMARY_NAME, cfg.run) is not None:
        return True
    found = salvage_part(part_path(out / cfg.sink.mcap_name), cfg.run) if cfg.sink.mcap else None
    return found is not None and bool(found.frames)


def open_embedded_router(z: ZenohConfig, out: Path, stages: Sequence[str]) -> tuple[Any, ZenohConfig, dict[str, str]]:
    """Open the launcher's router; returns it, the stages' Zenoh settings (connect to it)
    and the per-run credentials (empty unless the ACL or authentication needs them)."""
    from bnptrack.pipeline.transport import Router

    credentials: dict[str, str] = {}
    generated = (z.acl or (z.auth and z.mode == "client")) and not z.users_file
    if generated:
        credentials, z = _credentials(z, out, stages)
    try:
        router = Router(z)
    finally:
        if generated:  # the router has read it; each stage gets its own on its private link
            Path(z.users_file).unlink(missing_ok=True)
            z = msgspec.structs.replace(z, users_file="")
    z = msgspec.structs.replace(z, embedded_router=False, connect=router.connect_endpoints)
    return router, z, credentials


def _credentials(z: ZenohConfig, out: Path, stages: Sequence[str]) -> tuple[dict[str, str], ZenohConfig]:
    """Per-run credentials: one random password per stage (and one for the launcher's
    monitor), given to each process on its private link only (:mod:`pipeline.stage_link`), and the ACL that lets each
    stage put only on its own keys.  The users file (mode 0600) lives only until the
    router has read it."""
    credentials = {name: secrets.token_urlsafe(18) for name in [*stages, "launcher"]}
    users = out / ".zenoh-users.txt"
    fd = os.open(users, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.writelines(f"{u}:{pw}\n" for u, pw in credentials.items())
    return credentials, msgspec.structs.replace(z, users_file=str(users), acl=True)


def write_stages(out: Path, stages: Sequence[StageProcess]) -> None:
    """``<out>/stages.json``: pid, state, restarts, exit code and log of each stage (atomic,
    under ``<out>/.stages.lock``).  A stage process that recorded its own exit
    (:func:`record_exit`) before this launcher saw it keeps that record."""
    doc = {s.role: {"pid": s.pid, "state": s.state, "restarts": s.restarts,
                    "returncode": s.returncode, "log": str(s.log_path), "history": s.history}
           for s in stages}
    with _stages_lock(out):
        earlier = _read_stages(out)
        for role, rec in doc.items():
            own = earlier.get(role)
            if rec["state"] == "running" and isinstance(own, dict) and own.get("pid") == rec["pid"] \
                    and own.get("exited"):
                rec.update(state=own.get("state"), returncode=own.get("returncode"), exited=True)
        _replace_stages(out, doc)


def record_exit(out: Path, role: str, code: int) -> None:
    """A stage process's own record of its exit (``code``) in ``<out>/stages.json``, when the
    file lists this process: its launcher may be gone (SIGKILL), and the file must not say
    that the stage still runs.  Errors are ignored (the stage's exit code stands)."""
    try:
        with _stages_lock(out):
            doc = _read_stages(out)
            rec = doc.get(role)
            if not isinstance(rec, dict) or rec.get("pid") != os.getpid():
                return
            rec.update(state={0: "done", 3: "done", 130: "stopped"}.get(code, "exited"), returncode=code,
                       exited=True)
            _replace_stages(out, doc)
    except OSError as exc:
        log.debug("%s: cannot record its exit in %s: %s", role, out / "stages.json", exc)


@contextlib.contextmanager
def _stages_lock(out: Path) -> Iterator[None]:
    fd = os.open(out / ".stages.lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _read_stages(out: Path) -> dict:
    try:
        doc = json.loads((out / "stages.json").read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _replace_stages(out: Path, doc: dict) -> None:
    tmp = out / f".stages.json.{os.getpid()}.tmp"
    try:
        tmp.write_text(json.dumps(doc, indent=1))
        os.replace(tmp, out / "stages.json")
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def stop_stages(stages: Sequence[StageProcess], timeout: float, echo: Callable[[str], None]) -> bool:
    """SIGTERM every running stage, SIGKILL those still running after ``timeout`` seconds;
    False when none was running."""
    running = [sp for sp in stages if sp.alive()]
    if not running:
        return False
    for sp in running:
        sp.signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout
    for sp in running:
        try:
            sp.proc.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            echo(f"stage {sp.role} (pid {sp.pid}) did not stop in time: SIGKILL")
            sp.signal(signal.SIGKILL)
            sp.proc.wait(5)
        sp.returncode = sp.proc.returncode
        if sp.state == "running":
            sp.state = "stopped"
    return True


#: The signals that stop a stage.
_STOP_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})


class StopSignals:
    """SIGINT / SIGTERM set ``stop`` (the stage flushes its files); a second one exits at once
    (``os._exit``, exit code 130).

    The signals are blocked in the main thread (and so in every thread it starts afterwards,
    Zenoh's among them) and taken by a thread of their own with ``sigtimedwait``: a signal
    must never interrupt the main thread while it waits in the bus's receive.  CPython 3.11's
    ``queue.SimpleQueue.get(timeout=...)`` (``pipeline.transport.Bus.recv``) can go on waiting
    forever once a signal handler has run during its wait: only the next message wakes it, and
    after a SIGTERM the other stages are stopping too, so the stage never flushed its files and
    was killed after ``supervisor.stop_timeout_s`` (the sink's ``sink.json`` then missing:
    tests/pipeline/test_stage_signals.py reproduces the hang and checks the cure).  The Python
    handlers stay installed for the threads started before (numpy's BLAS threads), to which the
    kernel may still deliver a signal; they do the same.  :meth:`restore` puts the earlier mask
    back."""

    def __init__(self, name: str, stop: threading.Event) -> None:
        self.name, self.stop = name, stop
        self.done = threading.Event()
        self.old_handlers = {sig: signal.signal(sig, self.on_signal) for sig in _STOP_SIGNALS}
        self.old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        self.thread = threading.Thread(target=self._take, name="stop-signals", daemon=True)
        self.thread.start()  # it inherits the blocked mask, as sigtimedwait requires

    def on_signal(self, signum: int, _frame: Any = None) -> None:
        if self.stop.is_set():
            os._exit(EXIT_STOPPED)
        log.info("%s: %s: stopping (flushing files)", self.name, signal.Signals(signum).name)
        set_stop(self.stop, signal.Signals(signum).name)

    def _take(self) -> None:
        # the timeout only bounds how long this thread outlives restore(); a signal is taken at once
        while not self.done.is_set():
            info = signal.sigtimedwait(_STOP_SIGNALS, 0.5)
            # CPython 3.11 returns an unset siginfo (not None) when a signal of another
            # thread's handler interrupted the wait just before its timeout: check the number
            if info is not None and info.si_signo in _STOP_SIGNALS:
                self.on_signal(info.si_signo)

    def restore(self, handlers: bool = False) -> None:
        """Unblock the signals in the main thread again; with ``handlers`` put the earlier
        handlers back too (else they stay: a signal after a stage has returned still exits at
        once).  The thread ends within its 0.5 s timeout; until then it may still take one."""
        self.done.set()
        signal.pthread_sigmask(signal.SIG_SETMASK, self.old_mask)
        if handlers:
            for sig, old in self.old_handlers.items():
                signal.signal(sig, old)


def stop_on_signals(name: str, stop: threading.Event) -> StopSignals:
    """SIGINT / SIGTERM set ``stop``; a second one exits at once (:class:`StopSignals`)."""
    return StopSignals(name, stop)
