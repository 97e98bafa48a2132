"""The streaming pipeline's commands: ``launch`` (every stage in its own process),
``replay`` (a log through the pipeline), ``stage`` (one stage, for several hosts) and
``router`` (a Zenoh router).  See docs/pipeline.md; ``monitor`` is in
:mod:`pipeline.cli.monitor`.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import click

from bnptrack.pipeline.cli.common import (
    check_option_endpoints,
    checked_endpoints,
    FiniteRange,
    Choice,
    CONNECT_VIEW_HELP,
    END_HELP,
    SET_HELP_PIPE,
    SET_HELP_ZENOH,
    START_HELP,
    TOPIC_HELP,
    VIEW_HELP,
    CliError,
    IncompleteError,
    clean_errors,
    echo_rows,
    literal_choices,
    one_viewer,
    open_live,
    window_of,
    typed_window,
    check_window_holds,
    require_measurements,
    topic_map,
)
from bnptrack.pipeline.cli.option_types import NAME, URL, RUN, PathName
from bnptrack.pipeline.cli.run_figures import RunFigures, figure_rows
from bnptrack.pipeline.compile_notice import FirstCompile
from bnptrack.pipeline.config import PipelineConfig, ZenohConfig
from bnptrack.pipeline.resolve import TRACKERS

__all__ = ["launch", "replay", "stage", "router"]


def _report_launch(res: Any, quiet: bool, paced: bool = True, lag: int = 0) -> None:
    """Print a launch/replay result (the figures every run's summary prints:
    :func:`pipeline.cli.run_figures.figure_rows`; ``lag``: the tracker's ``--lag``); raise
    CliError on failure."""
    summary = res.summary
    if not quiet:
        restarts = ", ".join(f"{k} {v}" for k, v in res.restarts.items() if v) or "none"
        rows = [("run", res.run), ("out", f"{res.out}/")]
        if summary is not None:
            from bnptrack.pipeline.outcome import seq_ranges

            gap_text = ", ".join(f"{k} seq {seq_ranges(v)}" for k, v in summary.gaps.items() if v) or "none"
            rows.append(("frames", f"{summary.frames_written} "
                                   f"({summary.tracks_written} /tracks; gaps: {gap_text})"))
            from bnptrack.pipeline.outcome import describe_missing
            from bnptrack.pipeline.progress import describe_latency, describe_rejected

            rows.append(("rejected", describe_rejected(summary)))
            rows.append(("missing", describe_missing(summary) or "nothing (the output is complete)"))
            if lat_text := describe_latency(summary, paced):
                rows.append(("latency", lat_text))
            if summary.scores is not None or summary.latency.get("tracker_ms"):
                rows += figure_rows(RunFigures.of_summary(summary, lag))
        rows += [("restarts", restarts), ("elapsed", f"{res.elapsed_s:.1f} s")]
        for f in res.files:
            try:
                rows.append(("wrote", f"{f} ({Path(f).stat().st_size} bytes)"))
            except OSError:
                pass
        if summary is not None and summary.view:
            rows.append(("open with", summary.view))
        echo_rows(rows)
    if res.interrupted:
        click.echo(f"Interrupted: partial files are in {res.out}/", err=True)
        raise SystemExit(130)
    if res.incomplete:
        raise IncompleteError(f"output incomplete: {res.incomplete} -- files are in {res.out}/")
    if not res.ok:
        raise CliError(f"{res.error} -- files (if any) are in {res.out}/")


def _run_pipeline(cfg: Any, timeout: float | None, quiet: bool, overwrite: bool = False,
                  view: bool = False, view_connect: str | None = None, origin: Path | None = None) -> None:
    """Launch ``cfg`` and report it; a configuration error names ``origin``, the pipeline file
    the configuration came from (its values with the command's ``--set`` items)."""
    import msgspec as _ms

    from bnptrack.pipeline.launch import launch as _launch
    from bnptrack.pipeline.progress import Progress
    from bnptrack.tracker.config import ConfigError

    one_viewer(view, view_connect)
    if view_connect:  # checked with the rest of the configuration (pipeline.preflight)
        from bnptrack.pipeline.live import viewer_url

        cfg = _ms.structs.replace(cfg, sink=_ms.structs.replace(cfg.sink, view_url=viewer_url(view_connect)))
    first = FirstCompile(cfg.tracker.tracker, quiet) if "tracker" in cfg.stages else None
    progress = None if quiet else Progress(sys.stderr)

    def on_status(status: Any) -> None:
        if first is not None and status.phase != "checking":  # past the checks: compiling
            first.begin()
        if progress is not None:
            progress.update(status)

    ok = False
    try:
        res = _launch(cfg, echo=None if progress is None else progress.echo, timeout=timeout,
                      overwrite=overwrite, progress=on_status, view=view)
        ok = True
    except ConfigError as exc:  # raised by the checks, before anything started
        if origin is None or str(exc).startswith(str(origin)):
            raise
        raise ConfigError(f"{origin}: {exc}") from None
    finally:
        if first is not None:
            first.end(ok)
        if progress is not None:
            progress.close()
    _report_launch(res, quiet, paced=cfg.source.rate > 0,
                   lag=cfg.tracker.lag if "tracker" in cfg.stages else 0)


_OVERWRITE_OPT = click.option(
    "--overwrite", is_flag=True,
    help="Replace the files of an earlier run in the output directory (without it, such a "
    "directory is refused with exit code 2; a directory with a live run is always refused).",
)

_LAG_OPT = click.option(
    "--lag", type=click.IntRange(min=0), default=None, metavar="N",
    help="The tracker publishes each frame's /tracks N scans late (when frame k + N arrives), "
    "re-decided with the N scans that followed and smoothed, as `bnptrack track --lag N` "
    "(docs/trackers.md, \"Fixed-lag output\"). Default: tracker.lag of the pipeline (0: online).",
)

_TIMEOUT_OPT = click.option(
    "--timeout", type=FiniteRange(min=0, min_open=True), default=None, metavar="SECONDS",
    help="Stop everything and fail if the pipeline has not finished after this long.",
)


@click.command()
@click.argument("pipeline_file", metavar="[PIPELINE.toml]", required=False,
                type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=SET_HELP_PIPE)
@click.option("--run", "run_id", type=RUN, default=None, metavar="RUN",
              help="Run id (key-expression chunk). Default: <scenario>-<time>-<hex>.")
@click.option("--out", type=PathName(file_okay=False, path_type=Path), default=None,
              help="Output directory. Default: recordings/<run>/.")
@click.option("--connect", "connect", multiple=True, metavar="ENDPOINT|URL",
              help="Use this Zenoh router (e.g. tcp/10.0.0.5:7447) instead of an embedded one; "
              "a Rerun URL (rerun+http://HOST:PORT/proxy) instead streams the recording live to "
              "that running viewer.")
@click.option("--view", is_flag=True, help=VIEW_HELP)
@_LAG_OPT
@_TIMEOUT_OPT
@_OVERWRITE_OPT
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors (no progress lines).")
@clean_errors
def launch(pipeline_file: Path | None, overrides: tuple[str, ...], run_id: str | None,
           out: Path | None, connect: tuple[str, ...], view: bool, lag: int | None, timeout: float | None,
           overwrite: bool, quiet: bool) -> None:
    """Run the streaming pipeline: every stage in its own process, linked by Zenoh.

    With no PIPELINE.toml: a synthetic vo2017 source (seed 1) -> the DDP-EMM tracker
    (seed 0) -> the recorder, over a Zenoh router the launcher opens on a free loopback
    port. The sink writes <out>/tracks.mcap (input channels + /tracks, as `bnptrack
    track`), <out>/run.rrd when the Rerun sink is installed, and <out>/sink.json. A
    crashed stage is restarted (the tracker resumes from its snapshot). Ctrl-C stops every
    stage and flushes the files. See docs/pipeline.md.

    \b
    Examples:
      bnptrack launch
      bnptrack launch --set source.frames=20 --set tracker.tracker=dpyp --out /tmp/r1
      bnptrack launch examples/pipeline.toml --run test-1   # a pipeline file (docs/pipeline.md)
    """
    import msgspec as _ms

    from bnptrack.pipeline.config import load_pipeline

    cfg = load_pipeline(pipeline_file, overrides)
    if lag is not None:
        cfg = _ms.structs.replace(cfg, tracker=_ms.structs.replace(cfg.tracker, lag=lag))
    if run_id:
        cfg = _ms.structs.replace(cfg, run=run_id)
    if out:
        cfg = _ms.structs.replace(cfg, out=str(out))
    from bnptrack.pipeline.live import is_viewer_url

    viewers = [c for c in connect if is_viewer_url(c)]
    routers = [c for c in connect if not is_viewer_url(c)]
    if len(viewers) > 1:
        raise click.UsageError("--connect: give at most one Rerun viewer URL")
    check_option_endpoints(routers, "'--connect'")
    if routers:
        cfg = _ms.structs.replace(cfg, zenoh=_ms.structs.replace(
            cfg.zenoh, embedded_router=False, connect=routers))
    _run_pipeline(cfg, timeout, quiet, overwrite, view, viewers[0] if viewers else None, pipeline_file)


@click.command()
@click.argument("log", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--rate", type=FiniteRange(min=0, min_open=True), default=1.0, show_default=True,
              metavar="R", help="Replay speed against the log's time stamps (1 = real time).")
@click.option("--as-fast-as-possible", "afap", is_flag=True, help="Publish frames without pacing.")
@click.option("--tracker", "tracker_name", type=Choice(TRACKERS), default="ddp", show_default=True,
              help="Tracker (as `bnptrack track --tracker`).")
@click.option("--config", "config_arg", metavar="NAME|FILE.toml", type=NAME, default=None,
              help="Tracker settings preset or TOML file (as `bnptrack track --config`).")
@click.option("--params", "params_arg", metavar="NAME|FILE.toml", type=NAME, default=None,
              help="Model parameters. Default: the log's bnptrack.scenario record (as `track`).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Tracker seed.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=SET_HELP_PIPE)
@click.option("--run", "run_id", type=RUN, default=None, metavar="RUN", help="Run id. Default: <log stem>-<time>-<hex>.")
@click.option("--out", type=PathName(file_okay=False, path_type=Path), default=None,
              help="Output directory. Default: recordings/<run>/.")
@click.option("--start", "start", metavar="T|Nf", default=None, help=START_HELP)
@click.option("--end", "end", metavar="T|Nf", default=None, help=END_HELP)
@click.option("--loop", "loops", type=click.IntRange(min=0), default=None, metavar="N",
              help="Replay N times (0: until Ctrl-C), each a fresh run (run id RUN-1, RUN-2, ...; "
              "output directories OUT/RUN-i) with a fresh tracker.")
@click.option("--keep-prior", is_flag=True,
              help="With --loop: each replay's tracker starts from the prior the previous replay "
              "ended with (DDP-EMM / DPY-STP: alpha, d and their likelihood), with no track.")
@click.option("--topic", "topics", multiple=True, metavar="SRC[=/measurements]",
              help=TOPIC_HELP + " (source.topics of the pipeline file)")
@click.option("--view", is_flag=True, help=VIEW_HELP)
@click.option("--connect", "view_connect", type=URL, metavar="URL", default=None, help=CONNECT_VIEW_HELP)
@_LAG_OPT
@_TIMEOUT_OPT
@_OVERWRITE_OPT
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors (no progress lines).")
@clean_errors
def replay(log: Path, rate: float, afap: bool, tracker_name: str, config_arg: str | None,
           params_arg: str | None, seed: int, overrides: tuple[str, ...], run_id: str | None,
           out: Path | None, start: str | None, end: str | None, loops: int | None, keep_prior: bool,
           topics: tuple[str, ...], view: bool, view_connect: str | None, lag: int | None, timeout: float | None,
           overwrite: bool, quiet: bool) -> None:
    """Replay an MCAP measurement log through the streaming pipeline.

    Same processes as `launch`, with an MCAP replay source. The tracks do not depend on the
    rate (only on the frames and their order) and equal `bnptrack track LOG --seed N` with
    the same tracker. A truncated or corrupt LOG is replayed up to its last readable frame;
    then the error says where it stopped and the exit code is 2.

    \b
    Examples:
      bnptrack replay recordings/vo2017-s1.mcap --as-fast-as-possible
      bnptrack replay recordings/dpy5-s1.mcap --rate 10 --tracker dpyp --seed 3 --out /tmp/dpy5
      bnptrack replay recordings/vo2017-s1.mcap --rate 5 --start 20s --end 40f --loop 0 --view
      bnptrack replay ros.mcap --topic /radar/detections=/measurements   # your log: a JSON channel as /measurements
    """
    import msgspec as _ms

    from bnptrack.pipeline.config import load_pipeline

    mapping = topic_map(topics)
    require_measurements(log, mapping)  # at once, as `track` (the source checks it again)
    cfg = load_pipeline(None)
    window = window_of(start, end)
    cfg = _ms.structs.replace(
        cfg,
        source=_ms.structs.replace(cfg.source, kind="mcap", log=str(log), rate=0.0 if afap else rate,
                                   start_s=window.start_s, start_frame=window.start_frame, end_s=window.end_s,
                                   end_frame=window.end_frame, topics=mapping),
        tracker=_ms.structs.replace(cfg.tracker, tracker=tracker_name, seed=seed, lag=lag or 0,
                                    config=config_arg or "", params=params_arg or ""),
    )
    from bnptrack.pipeline.config import apply_pipeline_overrides

    cfg = apply_pipeline_overrides(cfg, overrides)
    if start is not None or end is not None:  # named as typed, before the pipeline's own checks
        from bnptrack.sources.frame_window import FrameWindow

        replayed = FrameWindow.of(cfg.source)
        check_window_holds(Path(cfg.source.log), dict(cfg.source.topics), replayed, typed_window(replayed, start, end))
    if run_id:
        cfg = _ms.structs.replace(cfg, run=run_id)
    if out:
        cfg = _ms.structs.replace(cfg, out=str(out))
    if loops is None:
        if keep_prior:
            raise click.UsageError("--keep-prior needs --loop")
        _run_pipeline(cfg, timeout, quiet, overwrite, view, view_connect)
        return
    _replay_loop(cfg, loops, timeout, quiet, overwrite, view, view_connect, keep_prior)


def _replay_loop(cfg: Any, loops: int, timeout: float | None, quiet: bool, overwrite: bool,
                 view: bool, view_connect: str | None, keep_prior: bool = False) -> None:
    """``replay --loop N``: the same replay N times (0: until interrupted), each a fresh run:
    run id ``RUN-i`` (RUN: --run, else generated once) and output ``OUT/RUN-i`` (OUT: --out,
    else recordings/); the tracker starts afresh each time, or with ``keep_prior`` from the
    prior of the previous run's final snapshot.  The first failure ends the loop."""
    import itertools

    import msgspec as _ms

    from bnptrack.pipeline.config import make_run_id

    base = cfg.run or make_run_id(cfg)
    root = Path(cfg.out) if cfg.out else Path("recordings")
    one_viewer(view, view_connect)
    if view:  # one viewer for every run of the loop
        view_connect = open_live("spawn")
    for i in itertools.count(1):
        if loops and i > loops:
            break
        run = f"{base}-{i}"
        if not quiet:
            click.echo(f"loop {i}{f'/{loops}' if loops else ''}: run {run}", err=True)
        one = _ms.structs.replace(cfg, run=run, out=str(root / run))
        if keep_prior and i > 1:
            from bnptrack.pipeline.stages.recovery import SNAPSHOT_NAME
            prev = root / f"{base}-{i - 1}" / SNAPSHOT_NAME
            one = _ms.structs.replace(one, tracker=_ms.structs.replace(one.tracker, prior_from=str(prev)))
        _run_pipeline(one, timeout, quiet, overwrite, False, view_connect)


@click.command()
@click.argument("role", type=Choice(literal_choices(PipelineConfig, "stages", element=True)))
@click.option("--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None, help="Pipeline file (.toml, or the .json the launcher writes).")
@click.option("--run", "run_id", type=RUN, default=None, metavar="RUN", help="Run id (the same for every stage).")
@click.option("--connect", multiple=True, metavar="ENDPOINT", help="Router endpoint, e.g. tcp/10.0.0.5:7447.",
              callback=checked_endpoints)
@click.option("--listen", multiple=True, metavar="ENDPOINT", help="Endpoint to listen on (peer mode).",
              callback=checked_endpoints)
@click.option("--mode", type=Choice(literal_choices(ZenohConfig, "mode")), default=None, help="Zenoh mode (default: client; peer also needs --connect or --listen).")
@click.option("--out", type=PathName(file_okay=False, path_type=Path), default=None,
              help="Output directory (tracker snapshot, sink files). Default: recordings/<run>/.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=SET_HELP_PIPE)
@click.option("--name", type=NAME, default=None, help="Stage name (default: the role).")
@click.option("--parent-pid", type=int, default=None, hidden=True)
@click.option("--link-fd", type=int, default=None, hidden=True)
@click.option("--log-level", default="INFO", show_default=True, help="Logging level.")
@clean_errors
def stage(role: str, pipeline_file: Path | None, run_id: str | None, connect: tuple[str, ...],
          listen: tuple[str, ...], mode: str | None, out: Path | None, overrides: tuple[str, ...],
          name: str | None, parent_pid: int | None, link_fd: int | None, log_level: str) -> None:
    """Run one pipeline stage in this process (to place stages on different hosts).

    Every stage of a run uses the same --run and reaches the others through a Zenoh router
    (`bnptrack router`, or a launcher's embedded one). Exit codes: 0 done, 2 configuration
    error (or restarted alone with nothing to finalize), 3 finished with the output incomplete
    (the source's input ended on an error; a restarted stage whose upstream had left),
    130 stopped by a signal, 1 crash.

    \b
    Example (three hosts, router on 10.0.0.5):
      bnptrack router --listen tcp/0.0.0.0:7447
      bnptrack stage sink    --run r1 --connect tcp/10.0.0.5:7447 --out /data/r1
      bnptrack stage tracker --run r1 --connect tcp/10.0.0.5:7447 --out /data/r1
      bnptrack stage source  --run r1 --connect tcp/10.0.0.5:7447 --set source.frames=50
    """
    from bnptrack.pipeline.stage_process import configure_logging, run_stage, stage_config
    from bnptrack.pipeline.config import load_pipeline
    from bnptrack.pipeline.stage_link import linked_stage
    from bnptrack.pipeline.supervisor import record_exit
    from bnptrack.tracker.config import ConfigError

    configure_logging(name or role, log_level)
    cfg = stage_config(load_pipeline(pipeline_file, overrides), run=run_id, out=str(out) if out else None,
                       connect=connect, listen=listen, mode=mode)
    cfg, link = linked_stage(cfg, link_fd)
    code = 1
    try:
        code = run_stage(role, cfg, name=name, parent_pid=parent_pid, report=link.report if link else None)
    except ConfigError:
        code = 2
        raise
    finally:
        if parent_pid:  # the launcher may be gone: stages.json must not say this one still runs
            record_exit(Path(cfg.out), role, code)
    end_process(code)


def end_process(code: int) -> None:
    """End a stage process once its stage is done (files closed and synced, bus closed): flush
    the logs and the standard streams, then exit at once, so that no library's exit handler
    (the Rerun SDK flushing to a frozen live viewer) can hold the process and the run."""
    import logging

    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


@click.command()
@click.option("--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None, help="Pipeline file: its [zenoh] table (TLS, router_extra) is used.")
@click.option("--listen", multiple=True, metavar="ENDPOINT", callback=checked_endpoints,
              help="Endpoint(s) to listen on. Default: tcp/127.0.0.1:7447 (this host only; "
                   "give e.g. tcp/0.0.0.0:7447 for other hosts, with TLS and --set zenoh.acl=true).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=SET_HELP_ZENOH)
@clean_errors
def router(pipeline_file: Path | None, listen: tuple[str, ...], overrides: tuple[str, ...]) -> None:
    """Run a Zenoh router for pipeline stages on several hosts (until Ctrl-C).

    \b
    Example:
      bnptrack router --listen tcp/0.0.0.0:7447
    """
    import signal as _signal
    import threading as _threading

    from bnptrack.pipeline.config import load_pipeline
    from bnptrack.pipeline.transport import Router

    cfg = load_pipeline(pipeline_file, overrides)
    stop = _threading.Event()
    for sig in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(sig, lambda *_: stop.set())
    with Router(cfg.zenoh, list(listen) or ["tcp/127.0.0.1:7447"]) as r:
        click.echo(f"router listening on {', '.join(r.endpoints)} (Ctrl-C to stop)", err=True)
        while not stop.wait(0.5):
            pass
