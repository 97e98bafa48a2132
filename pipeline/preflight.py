"""Validate a whole pipeline before any process starts (``bnptrack launch`` / ``replay``).

:func:`check_pipeline` runs, in the launcher's process, every check a stage would run at
start-up: the source (kind, scenario, parameter set and overrides, or the MCAP log and its
metadata record), the tracker (name, settings preset or file, model parameters and
``tracker.overrides``, built exactly as :func:`pipeline.stages.build_stage_tracker` builds
it), the Zenoh endpoints and files, and the output paths.  A mistake raises
:class:`tracker.config.ConfigError` with the message ``bnptrack track`` gives for it; the
CLI prints it on one line, exits 2 and nothing has been started or written.

The stages still check their own configuration (a stage started by hand, ``bnptrack
stage``, has no launcher in front of it).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Sequence
from pathlib import Path

from bnptrack.pipeline.config import PipelineConfig
from bnptrack.sources.frame_window import FrameWindow
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.input_checks import check_frames

__all__ = ["check_pipeline", "listening"]


def check_pipeline(cfg: PipelineConfig, overwrite: bool = False) -> None:
    """Raise :class:`ConfigError` if any stage of ``cfg`` would refuse its configuration, or
    if ``out`` holds a live run, or another run and not ``overwrite``.

    ``cfg`` must be resolved (:func:`pipeline.config.resolve_run`): ``out`` set.
    """
    _check_sink(cfg)
    _check_out(Path(cfg.out))
    _check_taken(cfg, overwrite)
    _check_zenoh(cfg)
    metadata = _check_source(cfg) if "source" in cfg.stages else None
    head = _log_start(cfg)
    if "tracker" in cfg.stages:  # last: it imports the tracker (about a second)
        from bnptrack.pipeline.stages import build_stage_tracker

        setup = build_stage_tracker(cfg.tracker, metadata)
        check_frames(setup.params, head, setup.choice.source, setup.set_sensors)
    else:
        check_frames(None, head)


def _log_start(cfg: PipelineConfig) -> list:
    """The first frames of the source's log (none for a synthetic source), decoded now: a
    first ``/measurements`` message that does not decode is refused before any process starts."""
    if "source" not in cfg.stages or cfg.source.kind != "mcap":
        return []
    from bnptrack.pipeline.offline import read_log_start

    return read_log_start(cfg.source.log, dict(cfg.source.topics))


def _check_source(cfg: PipelineConfig) -> dict[str, str] | None:
    """The source's metadata record (what the tracker stage will receive), or an error."""
    from bnptrack.pipeline.stages import source_frames

    metadata, frames = source_frames(cfg)
    window = FrameWindow.of(cfg.source)
    if window != FrameWindow() and next(frames, None) is None:  # read up to the window's first frame
        if cfg.source.kind == "mcap":
            raise ConfigError(window.no_frame(cfg.source.log, hint="; `bnptrack info LOG` lists a log's frames "
                                              "and times"))
        raise ConfigError(window.no_frame(f"source.scenario {cfg.source.scenario!r} (seed {cfg.source.seed})"))
    close = getattr(frames, "close", None)
    if close is not None:  # a generator: nothing was read yet
        close()
    return metadata


def _check_sink(cfg: PipelineConfig) -> None:
    for key in ("mcap_name", "rrd_name"):
        name = getattr(cfg.sink, key)
        if not name or Path(name).name != name or name in (".", ".."):
            raise ConfigError(f"sink.{key}: {name!r} must be a file name (no directory part)")
    if cfg.sink.view_url:
        if not cfg.sink.rerun:
            raise ConfigError("sink.view_url: the live view streams run.rrd's rows: it needs sink.rerun = true")
        from bnptrack.pipeline.live import check_viewer

        check_viewer(cfg.sink.view_url)


def _check_zenoh(cfg: PipelineConfig) -> None:
    z = cfg.zenoh
    try:
        z.check_endpoints()  # also those an option set after the file was read
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if not z.embedded_router and not z.connect and z.mode == "client":
        raise ConfigError("zenoh.connect: a client needs router endpoints (or set "
                          "zenoh.embedded_router = true)")
    if not z.embedded_router and z.mode == "client":
        _check_routers(z.connect)
    files = {f"zenoh.tls.{k}": v for k, v in z.tls.files().items()}
    if z.users_file:
        files["zenoh.users_file"] = z.users_file
    for key, path in files.items():
        if not Path(path).is_file():
            raise ConfigError(f"{key}: {path}: no such file")


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


def _check_routers(endpoints: list[str]) -> None:
    """Some router accepts connections at ``endpoints`` (``tcp/`` and ``tls/`` are probed);
    otherwise every stage would wait ``connect_timeout_s`` and fail."""
    if listening(endpoints) is False:
        raise ConfigError(f"no router at {', '.join(endpoints)}: start one with "
                          f"`bnptrack router --listen {endpoints[0]}`")


#: The lock a launcher holds on its output directory while it runs (``fcntl.flock``).
LOCK_NAME = ".bnptrack.lock"


def run_files(cfg: PipelineConfig) -> list[str]:
    """The files of a run in ``cfg.out`` (any of them means the directory holds a run)."""
    from bnptrack.pipeline.stages import JOURNAL_NAME, SNAPSHOT_NAME, SUMMARY_NAME

    names = ["pipeline.json", "stages.json", SUMMARY_NAME, SNAPSHOT_NAME, JOURNAL_NAME,
             cfg.sink.mcap_name, cfg.sink.rrd_name, "health.jsonl", "logs"]
    out = Path(cfg.out)
    return [n for n in names if (out / n).exists()]


def lock_out(out: Path) -> int:
    """Create and lock ``out/.bnptrack.lock`` for this process (the caller keeps the
    descriptor open for the run); :class:`ConfigError` if another launcher holds it."""
    import fcntl

    fd = os.open(out / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.read(fd, 64).decode(errors="replace").strip() or "?"
        os.close(fd)
        raise ConfigError(f"--out {out}: a run is live there (launcher pid {holder}); "
                          "use another --out") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def _check_taken(cfg: PipelineConfig, overwrite: bool) -> None:
    """Refuse an output directory that holds a live run (always), or another run's files
    (unless ``overwrite``)."""
    out = Path(cfg.out)
    if not out.is_dir():
        return
    if (out / LOCK_NAME).exists():
        os.close(lock_out(out))  # raises if a launcher holds it
    refuse_other_run(cfg, overwrite)


def refuse_other_run(cfg: PipelineConfig, overwrite: bool) -> None:
    """:class:`ConfigError` if ``cfg.out`` holds another run's files and not ``overwrite``
    (the launcher checks again once it holds the lock: a run may have ended in between)."""
    out = Path(cfg.out)
    found = run_files(cfg)
    if found and not overwrite:
        run = ""
        try:
            import json

            run = json.loads((out / "pipeline.json").read_text()).get("run", "")
        except (OSError, ValueError, AttributeError):
            pass
        raise ConfigError(f"--out {out}: holds {'run ' + repr(run) if run else 'another run'} "
                          f"({', '.join(found)}); use another --out, or --overwrite to replace it")


def _check_out(out: Path) -> None:
    """``out`` is a folder, or can be created: its nearest existing parent is a folder in which
    a file can be created (:func:`pipeline.output_paths.check_writable`)."""
    from bnptrack.pipeline.output_paths import check_writable

    check_writable(out, "--out", folder=True)

