"""One stage process (``bnptrack stage``): its logging, its signals, the watch on the
launcher, the bus it opens and always closes, and the exit code it returns
(docs/pipeline.md).  :mod:`pipeline.launch` starts and supervises these processes.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import msgspec

from bnptrack.pipeline.config import PipelineConfig, check_run_id, resolve_run
from bnptrack.pipeline.supervisor import stop_on_signals
from bnptrack.pipeline.stages import (
    EXIT_CONFIG, EXIT_CRASH, EXIT_IO,
    STAGES,
    StageContext,
    StageIOError,
    UpstreamGone,
)
from bnptrack.pipeline.stages.base import StopFlag, set_stop
from bnptrack.tracker.config import ConfigError

__all__ = ["run_stage", "stage_config", "configure_logging"]

log = logging.getLogger("bnptrack.launch")

#: errno values of a file that cannot be written (a stage exits EXIT_IO: no restart helps).
_FILE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG, errno.EROFS})


def configure_logging(stage: str, level: str = "INFO") -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format=f"%(asctime)s.%(msecs)03d [{stage}] %(levelname)s %(message)s",
        datefmt="%H:%M:%S",
        stream=sys.stderr,
        force=True,
    )


def run_stage(role: str, cfg: PipelineConfig, name: str | None = None, parent_pid: int | None = None,
              stop: threading.Event | None = None, report: Callable[[dict], None] | None = None) -> int:
    """Run one stage in this process until it finishes or is stopped; return its exit code.

    Installs SIGINT/SIGTERM handlers (a second signal exits at once), watches
    ``parent_pid`` (the launcher: if it disappears the stage stops), opens the Zenoh session
    and always closes it.  ``report`` sends the stage's reports to its launcher
    (:class:`pipeline.stage_link.StageLink`).
    """
    if role not in STAGES:
        raise ConfigError(f"unknown stage {role!r}; stages: {', '.join(STAGES)}")
    name = name or role
    stop = stop or StopFlag()
    # Zenoh's threads run our (short) sample callbacks under the GIL: let them in sooner
    # than the default 5 ms while the main thread computes
    sys.setswitchinterval(0.001)
    signals = stop_on_signals(name, stop) if threading.current_thread() is threading.main_thread() else None
    try:
        return _run_with_bus(role, cfg, name, parent_pid, stop, report)
    finally:
        if signals is not None:
            signals.restore()


def _run_with_bus(role: str, cfg: PipelineConfig, name: str, parent_pid: int | None,
                  stop: threading.Event, report: Callable[[dict], None] | None = None) -> int:
    """:func:`run_stage` once the signals are taken care of: open the bus, run the stage."""
    from bnptrack.pipeline.transport import Bus, NoRouterError, TransportError

    if parent_pid:
        _watch_parent(name, parent_pid, stop)
    try:
        bus = Bus(cfg.run, name, cfg.zenoh, cfg.delivery)
    except NoRouterError:
        raise  # a configuration error: `bnptrack stage` prints it on one line, exit 2
    except TransportError as exc:
        log.error("%s", exc)
        return EXIT_CRASH
    try:
        ctx = StageContext(cfg, bus, stop, name)
        if report is not None:
            ctx.report = report
        return _run_profiled(STAGES[role](ctx), name)
    except ConfigError as exc:
        log.error("%s: configuration error: %s", name, exc)
        return EXIT_CONFIG
    except UpstreamGone as exc:  # restarted alone, with nothing to finalize: one line
        log.error("%s", exc)
        return EXIT_CONFIG
    except OSError as exc:
        if isinstance(exc, ConnectionError) or exc.errno not in _FILE_ERRNOS:
            raise
        return _report_io_error(exc, name, bus)
    finally:
        bus.close()
        _log_cpu(name)


def _watch_parent(name: str, parent_pid: int, stop: threading.Event) -> None:
    """Set ``stop`` when the launcher (``parent_pid``) is gone."""
    def watch() -> None:
        while not stop.wait(0.5):
            if os.getppid() != parent_pid:
                log.error("%s: the launcher (pid %d) is gone: stopping", name, parent_pid)
                set_stop(stop, f"its launcher, pid {parent_pid}, is gone")

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _run_profiled(stage: Any, name: str) -> int:
    """``stage.run()``; with ``$BNPTRACK_PROFILE`` (a debugging aid) under cProfile, into
    ``$BNPTRACK_PROFILE/<name>.prof``."""
    prof_dir = os.environ.get("BNPTRACK_PROFILE")
    if not prof_dir:
        return stage.run()
    import cProfile

    prof = cProfile.Profile(time.thread_time) if os.environ.get("BNPTRACK_PROFILE_CPU") else cProfile.Profile()
    try:
        return prof.runcall(stage.run)
    finally:
        Path(prof_dir).mkdir(parents=True, exist_ok=True)
        prof.dump_stats(str(Path(prof_dir) / f"{name}.prof"))


def _report_io_error(exc: OSError, name: str, bus: Any) -> int:
    """Log a file that could not be written, tell the launcher over the bus: EXIT_IO."""
    text = str(exc) if isinstance(exc, StageIOError) else \
        f"stage {name}: cannot write {exc.filename or 'a file'}: {exc.strerror}"
    log.error("%s: I/O error: %s", name, text)
    try:  # the log may be on the full disk too: tell the launcher over the bus
        bus.publish(f"health/{name}", json.dumps({"stage": name, "io_error": text}).encode())
    except Exception:
        pass
    return EXIT_IO


def _log_cpu(name: str) -> None:
    """Log the CPU time this process used (for the reader of the stage's log; the
    benchmark samples /proc itself)."""
    t = os.times()
    log.info("%s: cpu user %.3f s, system %.3f s", name, t.user, t.system)


def stage_config(base: PipelineConfig, *, run: str | None, out: str | None,
                 connect: Sequence[str], listen: Sequence[str], mode: str | None) -> PipelineConfig:
    """The configuration of a stage started by hand (``bnptrack stage``)."""
    cfg = base
    if run:
        cfg = msgspec.structs.replace(cfg, run=check_run_id(run))
    if not cfg.run:
        raise ConfigError("--run RUN is required (every stage of a run must use the same run id)")
    if out:
        cfg = msgspec.structs.replace(cfg, out=str(out))
    cfg = resolve_run(cfg)
    z = cfg.zenoh
    changes: dict[str, Any] = {"embedded_router": False}
    if connect:
        changes["connect"] = list(connect)
    if listen:
        changes["listen"] = list(listen)
    if mode:
        changes["mode"] = mode
    try:
        z = msgspec.structs.replace(z, **changes)
    except ValueError as exc:  # ZenohConfig's cross-field checks
        raise ConfigError(str(exc)) from None
    if z.mode == "client" and not z.connect:
        raise ConfigError("--connect tcp/HOST:PORT is required in client mode (the router's endpoint)")
    return msgspec.structs.replace(cfg, zenoh=z)
