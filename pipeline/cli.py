"""The ``bnptrack`` command line (``bnptrack = "pipeline.cli:main"``; also ``python -m pipeline``).

Subcommands are thin: they parse options, call :mod:`pipeline.offline` and print a summary.
Expected failures (bad configuration, missing or damaged files, invalid messages) become a
one-line ``Error: ...`` on stderr and exit code 2; set ``BNPTRACK_DEBUG=1`` to get the
traceback instead.
"""

from __future__ import annotations

import functools
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable

import click

from pipeline.codec import MSG_TYPES, CodecError, json_schema
from pipeline.offline import (
    DEFAULT_PARAMS,
    OSPA_C,
    OSPA_P,
    TRACKERS,
    apply_split_overrides,
    build_tracker,
    check_output_path,
    default_tracks_path,
    format_overrides,
    resolve_config,
    resolve_params,
    resolve_scenario,
    resolve_simulation_params,
    simulation_metadata,
    simulate_to_log,
    split_overrides,
    track_log,
)
from pipeline.view import ViewerUnavailable
from sinks.rerun_writer import RecordingError, RecordingProcess
from sources.mcap_log import McapLogError, read_metadata
from sources.scenarios import scenario_names
from tracker.config import ConfigError

__all__ = ["main", "CliError"]

#: Exit code of every reported (non-crash) failure.
EXIT_ERROR = 2
#: Exit code of a pipeline run that ended with an incomplete output (gaps, rejected frames,
#: a stage that gave up); see docs/pipeline.md.
EXIT_INCOMPLETE = 3


class CliError(click.ClickException):
    """A failure reported as one line on stderr, exit code 2."""

    exit_code = EXIT_ERROR

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


class IncompleteError(CliError):
    """``launch`` / ``replay``: the run ended but its output is incomplete (exit code 3)."""

    exit_code = EXIT_INCOMPLETE


_EXPECTED = (ConfigError, CodecError, McapLogError, OSError, ValueError, RecordingError, ViewerUnavailable)


def _clean_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the expected exceptions of a command into :class:`CliError`."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except click.ClickException:
            raise
        except BrokenPipeError:  # e.g. `bnptrack schema /tracks | head`: stop quietly
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            raise SystemExit(141) from None
        except _EXPECTED as exc:
            if os.environ.get("BNPTRACK_DEBUG"):
                raise
            raise CliError(_describe(exc)) from exc

    return wrapper


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    return str(exc)


_KEY_WIDTH = 16


def _echo_rows(rows: list[tuple[str, str]]) -> None:
    for key, value in rows:
        width = max(_KEY_WIDTH, len(key))
        click.echo(f"{key:<{width}}  {value}")


def _fmt(value: float | None, spec: str = ".2f") -> str:
    return "n/a" if value is None else format(value, spec)


_VIEW_HELP = (
    "Watch the run live: start a Rerun viewer and stream the recording to it while it is "
    "written (the viewer stays open after the run; needs a display)."
)
_CONNECT_VIEW_HELP = (
    "Stream the recording live to a Rerun viewer that is already running, e.g. on another host "
    "(`rerun` there, then --connect rerun+http://HOST:9876/proxy; a port N means "
    "rerun+http://127.0.0.1:N/proxy)."
)

_SET_HELP_SIM = (
    "Override one model parameter, KEY=VALUE (VALUE is a TOML literal), e.g. "
    "--set p_detect=0.9 --set clutter_rate=30; scene.KEY=VALUE sets a parameter of a "
    "generated scenario (random, random-cv), e.g. --set scene.n_objects=25 "
    "--set scene.crossing_pairs=3 (docs/models.md). Repeatable."
)
_SET_HELP_TRACK = (
    "Override a setting, KEY=VALUE (VALUE is a TOML literal). params.KEY goes to the model "
    "parameters, tracker.KEY to the tracker settings; a bare KEY goes to whichever has it "
    "(model parameters first). Repeatable."
)


# --------------------------------------------------------------------------- group


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="bnptrack", prog_name="bnptrack")
def main() -> None:
    """bnptrack: streaming multi-object tracking with Bayesian nonparametric priors.

    Simulate the paper's scenarios into MCAP logs and run the DDP-EMM (ddp) or DPY-STP
    (dpyp) tracker over a log offline. Logs hold /measurements, /truth and /tracks as
    JSON messages (see docs/formats.md and `bnptrack schema`).

    \b
    Example:
      bnptrack simulate --scenario vo2017 --params vo2017 --seed 1 --out recordings/vo2017-s1.mcap
      bnptrack track recordings/vo2017-s1.mcap --tracker ddp --out recordings/vo2017-s1-ddp.mcap
      bnptrack schema /tracks

    Errors are reported on one line with exit code 2 (BNPTRACK_DEBUG=1 shows the traceback).
    """


# --------------------------------------------------------------------------- simulate


@main.command()
@click.option(
    "--scenario",
    type=click.Choice(scenario_names()),
    default="vo2017",
    show_default=True,
    help="Ground-truth scenario (100 scans; see docs/models.md).",
)
@click.option(
    "--params",
    "params_arg",
    metavar="NAME|FILE.toml",
    default=DEFAULT_PARAMS,
    show_default=True,
    help="Model parameter set: built-in vo2017 or paper, or a TOML file of ModelParams fields.",
)
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=_SET_HELP_SIM)
@click.option(
    "--snr",
    "snr_db",
    type=float,
    default=None,
    metavar="DB",
    help="Signal-to-noise ratio in dB (sets snr_db; measurement noise variance is scaled by "
    "10^(-DB/10)). The snr scenario defaults to -3 dB.",
)
@click.option(
    "--seed", type=click.IntRange(min=0), default=1, show_default=True, help="Random seed (>= 0)."
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Output MCAP file. Default: recordings/<scenario>-s<seed>.mcap (directory created).",
)
@click.option("--quiet", "-q", is_flag=True, help="Do not print the summary.")
@_clean_errors
def simulate(
    scenario: str,
    params_arg: str,
    overrides: tuple[str, ...],
    snr_db: float | None,
    seed: int,
    out: Path | None,
    quiet: bool,
) -> None:
    """Simulate a scenario and write its measurements and truth to an MCAP log.

    Writes one frame per scan (100 scans) on /measurements and /truth, and a
    bnptrack.scenario metadata record (scenario, params, seed, plus snr_db and overrides
    when used) so that `bnptrack track` can pick the same model parameters. The same
    seed gives the same messages on every machine.

    \b
    Examples:
      bnptrack simulate --scenario vo2017 --params vo2017 --seed 1 --out recordings/vo2017-s1.mcap
      bnptrack simulate --scenario snr --snr -10 --seed 3
      bnptrack simulate --scenario proximity --params paper --set clutter_rate=30 --seed 2
      bnptrack simulate --scenario random --seed 3 --set scene.n_objects=25
      bnptrack simulate --params two_sensors.toml --seed 1   # one frame per [sensors.NAME] per scan

    The generated scenarios (random, random-cv) draw their scene from --seed too (the
    record then also holds scene_seed, the scene.* settings and the crossing pairs).
    """
    params = resolve_simulation_params(scenario, params_arg, overrides, snr_db)
    scene = resolve_scenario(scenario, seed, overrides)
    if out is None:
        out = Path("recordings") / f"{scenario}-s{seed}.mcap"
    metadata = simulation_metadata(scene, params_arg, seed, params, overrides)
    res = simulate_to_log(scenario, params, seed, out, metadata, overrides)
    if quiet:
        return
    extra = []
    if overrides:
        extra.append("overrides " + " ".join(overrides))
    if params.snr_db is not None:
        extra.append(f"snr_db {params.snr_db:g}")
    rows = [("scenario", f"{scenario} ({scene.kind} sensor)")]
    if scene.seed is not None:
        pairs = ", ".join(f"{a}/{b}@{k}" for a, b, k in scene.crossings) or "none"
        rows.append(("scene", f"seed {scene.seed}: {len(scene.targets)} objects, "
                              f"crossing pairs {pairs}; no birth regions"))
    _echo_rows(
        rows + [
            ("params", params_arg + (f" ({', '.join(extra)})" if extra else "")),
            ("seed", str(seed)),
            ("frames", str(res.frames)),
            ("measurements", f"{res.measurements} ({res.mean_measurements:.1f} per frame)"),
            ("target-scans", str(res.target_scans)),
            ("wrote", f"{res.path} ({res.size_bytes} bytes)"),
        ]
    )


# --------------------------------------------------------------------------- track


@main.command()
@click.argument("log", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option(
    "--tracker",
    "tracker_name",
    type=click.Choice(TRACKERS),
    default="ddp",
    show_default=True,
    help="ddp = DDP-EMM, dpyp = DPY-STP, glmb = the GLMB baseline.",
)
@click.option(
    "--config",
    "config_arg",
    metavar="NAME|FILE.toml",
    default=None,
    help="Tracker settings: a preset name (ddp, dpyp, ddp-proximity, ddp-snr for the BNP "
    "trackers; glmb) or a TOML file of the tracker's settings fields (BnpConfig, GlmbConfig). "
    "Default: the preset named like --tracker.",
)
@click.option(
    "--params",
    "params_arg",
    metavar="NAME|FILE.toml",
    default=None,
    help="Model parameters (vo2017, paper or a TOML file). Default: the set named in the "
    f"log's bnptrack.scenario record (with its snr_db and overrides), else {DEFAULT_PARAMS}.",
)
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=_SET_HELP_TRACK)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Tracker random seed (frame k uses its own stream derived from seed and k).",
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Output MCAP file (input frames + /tracks). Default: <LOG stem>-<tracker>.tracks.mcap "
    "next to LOG.",
)
@click.option(
    "--rrd",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    metavar="FILE.rrd",
    help="Also record the run for the Rerun viewer (scene, assignments, tracks, truth, OSPA, "
    "diagnostics); open it with `bnptrack view FILE.rrd`. See docs/rerun.md.",
)
@click.option(
    "--max-frame-gap", type=click.IntRange(min=1), default=1000, show_default=True, metavar="N",
    help="A frame more than N frame numbers after the previous one ends the run with an error "
    "(a corrupt frame number; the tracker predicts once over the time between stamps).",
)
@click.option(
    "--max-gap-s", type=click.FloatRange(min=0, min_open=True), default=3600.0, show_default=True,
    metavar="SECONDS", help="Likewise for a time stamp more than SECONDS after the previous "
    "frame's (a time stamp that goes back is always an error).",
)
@click.option("--topic", "topics", multiple=True, metavar="SRC=/measurements",
              help="Read channel SRC as /measurements (or /truth), e.g. --topic /radar/detections=/measurements; "
              "its payload must still follow the contract of docs/formats.md.")
@click.option("--view", is_flag=True, help=_VIEW_HELP + " Writes --rrd (default: the --out "
              "file with the suffix .rrd).")
@click.option("--connect", "view_connect", metavar="URL", default=None, help=_CONNECT_VIEW_HELP)
@click.option("--quiet", "-q", is_flag=True, help="Do not print the summary.")
@_clean_errors
def track(
    log: Path,
    tracker_name: str,
    config_arg: str | None,
    params_arg: str | None,
    overrides: tuple[str, ...],
    seed: int,
    out: Path | None,
    rrd: Path | None,
    max_frame_gap: int,
    max_gap_s: float,
    topics: tuple[str, ...],
    view: bool,
    view_connect: str | None,
    quiet: bool,
) -> None:
    """Run a tracker over an MCAP log offline and write its tracks.

    Reads the frames of LOG (/measurements with /truth when present), runs the tracker
    frame by frame and writes --out with the input frames, one /tracks message per frame
    and LOG's metadata record (plus tracker, tracker_seed, tracker_params,
    tracker_config). Prints mean OSPA (c=100 m, p=1, on position) and mean cardinality
    error when the log has truth, the final number of tracks and the time per frame.

    A truncated or corrupt LOG is processed up to its last readable frame; that prefix is
    written, then the error is reported and the exit code is 2. So is a frame that jumps
    beyond --max-frame-gap / --max-gap-s, or that does not come after the previous one.

    \b
    Examples:
      bnptrack track recordings/vo2017-s1.mcap --tracker ddp --out recordings/vo2017-s1-ddp.mcap
      bnptrack track recordings/dpy5-s1.mcap --tracker dpyp --set tracker.sweeps=50
      bnptrack track recordings/snr-s1.mcap --config ddp-snr --params vo2017 --set snr_db=-5
    """
    # --rrd: start the recording process before anything else, so that its imports (rerun)
    # run on the other core beside the tracker's (sinks.rerun_writer); the command's context
    # closes it at the end whatever happens (track_log_with_rrd closes it first, normally)
    topic_map = _topic_map(topics)
    if topic_map and rrd is not None:
        raise CliError("--topic cannot be combined with --rrd yet: track first, then `bnptrack view` the output")
    _require_measurements(log, topic_map)
    live = _live_view(view, view_connect)
    if live is not None and rrd is None:
        rrd = (out or default_tracks_path(log, tracker_name)).with_suffix(".rrd")
    recorder = None
    if rrd is not None:
        recorder = click.get_current_context().with_resource(RecordingProcess())
    metadata = read_metadata(log)
    choice = resolve_params(params_arg, metadata)
    config, config_desc = resolve_config(tracker_name, config_arg)
    params, config = apply_split_overrides(choice.params, config, overrides)
    tracker = build_tracker(tracker_name, params, config)
    if out is None:
        out = default_tracks_path(log, tracker_name)
    check_output_path(log, out)
    from tracker.types import FrameBounds

    bounds = FrameBounds(max_frame_gap, max_gap_s)

    out_meta = dict(metadata or {})
    out_meta.update(
        tracker=tracker_name,
        tracker_seed=str(seed),
        tracker_params=choice.source,
        tracker_config=config_arg or tracker_name,
    )
    if overrides:
        out_meta["tracker_overrides"] = format_overrides(overrides)

    if not quiet:
        p_over, t_over = split_overrides(overrides, type(config))
        _echo_rows(
            [
                ("log", str(log)),
                ("params", choice.describe(params, p_over)),
                ("config", config_desc + (f"; --set {' '.join(t_over)}" if t_over else "")),
            ]
        )
    if rrd is not None:
        from pipeline.view import track_log_with_rrd

        live_url = None
        if live is not None:
            live_url = _open_live(live)
        res = track_log_with_rrd(log, out, rrd, tracker, seed, out_meta, params=params,
                                 recorder=recorder, bounds=bounds, live=live_url)
    else:
        res = track_log(log, out, tracker, seed, out_meta, bounds=bounds, topic_map=topic_map)
    for w in res.warnings:
        click.echo(f"warning: {w}", err=True)
    if not quiet:
        rows = [("tracker", f"{tracker_name} (seed {seed})"), ("frames", str(res.n_frames))]
        if res.has_truth:
            rows.append(
                ("mean OSPA", f"{_fmt(res.mean_ospa)} m (c={OSPA_C:g}, p={OSPA_P:g}, position)")
            )
            rows.append(("mean card. error", _fmt(res.mean_cardinality_error)))
            if res.crossings is not None:
                kept = sum(p.kept for p in res.crossings.pairs)
                rows.append(("crossings kept", f"{kept}/{len(res.crossings.pairs)} pairs keep both "
                             "labels (scan c-5 vs c+5, gate 100 m)"))
        else:
            rows.append(("mean OSPA", "n/a (the log has no /truth)"))
        rows += [
            ("final tracks", str(res.final_tracks)),
            ("ms per frame", f"median {_fmt(res.ms_median)}, p95 {_fmt(res.ms_p95)}"),
            ("wrote", f"{out} ({out.stat().st_size} bytes)"),
        ]
        if rrd is not None:
            rows.append(("recording", f"{rrd} ({rrd.stat().st_size} bytes; bnptrack view {rrd})"))
        _echo_rows(rows)
    if res.error is not None:
        raise CliError(
            f"{res.error} -- processed and wrote the {res.n_frames} readable frame(s) to {out}"
        )


def _topic_map(items: tuple[str, ...]) -> dict[str, str]:
    from pipeline.codec import TOPIC_MEASUREMENTS, TOPIC_TRUTH

    out = {}
    for item in items:
        src, sep, dst = item.partition("=")
        if not sep or not src or dst not in (TOPIC_MEASUREMENTS, TOPIC_TRUTH):
            raise click.BadParameter(f"{item!r}: expected SRC={TOPIC_MEASUREMENTS} (or SRC={TOPIC_TRUTH})",
                                     param_hint="--topic")
        out[src] = dst
    return out


def _require_measurements(log: Path, topic_map: dict[str, str]) -> None:
    """Exit 2 listing the log's channels when none is (or is mapped to) /measurements."""
    from pipeline.codec import TOPIC_MEASUREMENTS
    from sources.mcap_log import log_channels, missing_measurements_message

    channels = log_channels(log)
    if not any(topic_map.get(c.topic, c.topic) == TOPIC_MEASUREMENTS for c in channels):
        raise CliError(missing_measurements_message(log, channels))


# --------------------------------------------------------------------------- info


@main.command()
@click.argument("log", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--topic", "topics", multiple=True, metavar="SRC=/measurements",
              help="Read channel SRC as /measurements (as `bnptrack track --topic`).")
@_clean_errors
def info(log: Path, topics: tuple[str, ...]) -> None:
    """Describe an MCAP log: channels, frames, sensors, time, and its record.

    Prints every channel (topic, schema and encodings, message count); for /measurements the
    frames, sensors and kinds (with their poses when the frames carry them), the time span and
    frame rate from the stamps; and the bnptrack.scenario record (scenario, params, seed).

    \b
    Example:
      bnptrack info recordings/vo2017-s1.mcap
    """
    from sources.mcap_log import log_channels

    channels = log_channels(log)
    rows = [("log", f"{log} ({log.stat().st_size} bytes)")]
    for c in channels:
        rows.append(("channel", f"{c.topic}: schema {c.schema or '-'} ({c.schema_encoding or '-'}), "
                                f"encoding {c.message_encoding}, {c.messages} messages"))
    if not channels:
        rows.append(("channel", "none"))
    rows += _frame_rows(log, _topic_map(topics))
    meta = read_metadata(log)
    if meta:
        rows += [(f"record.{k}", v) for k, v in meta.items()]
    else:
        rows.append(("record", "none (no bnptrack.scenario metadata: give --params to track)"))
    _echo_rows(rows)


def _frame_rows(log: Path, topic_map: dict[str, str]) -> list[tuple[str, str]]:
    """Frames, sensors / kinds and time rows of ``bnptrack info`` (empty without /measurements)."""
    import numpy as np

    from sources.mcap_log import iter_frames

    sensors: dict[tuple[str, str], list] = {}
    stamps, n_meas, truth, error = [], 0, 0, None
    try:
        for f in iter_frames(log, topic_map):
            entry = sensors.setdefault((f.sensor, f.kind), [0, set()])
            entry[0] += 1
            if f.pose is not None:
                entry[1].add(f.pose)
            stamps.append(f.stamp_ns)
            n_meas += f.n_measurements
            truth += f.truth is not None
    except McapLogError as exc:
        error = exc
    if not stamps:
        return [("frames", "0" + (f" ({error})" if error else " (no /measurements: see --topic)"))]
    rows = [("frames", f"{len(stamps)} ({n_meas} measurements, {n_meas / len(stamps):.1f} per frame; "
                       f"{truth} with truth)")]
    for (name, kind), (n, poses) in sensors.items():
        pose = ""
        if poses:
            p = sorted(poses)[0]
            pose = f", pose ({p[0]:g}, {p[1]:g}, {np.rad2deg(p[2]):g} deg)" + (f" and {len(poses) - 1} more" if len(poses) > 1 else "")
        rows.append(("sensor", f"{name}: kind {kind}, {n} frames{pose}"))
    span = (stamps[-1] - stamps[0]) / 1e9
    dt = np.diff(np.asarray(stamps, dtype=np.int64)) / 1e9
    rate = f"{(len(stamps) - 1) / span:.3g} frames/s" if span > 0 else "n/a (all stamps equal)"
    rows.append(("time", f"{stamps[0] / 1e9:.3f} - {stamps[-1] / 1e9:.3f} s (span {span:.3f} s), {rate}"
                 + (f", dt median {np.median(dt):.3g} s, min {dt.min():.3g}, max {dt.max():.3g}" if dt.size else "")))
    if error is not None:
        rows.append(("error", str(error)))
    return rows


# --------------------------------------------------------------------------- export


@main.command()
@click.argument("run", type=click.Path(exists=True, dir_okay=False, path_type=Path), metavar="RUN.mcap")
@click.option("--csv", "csv_out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the track table as CSV (metrics beside it: OUT.metrics.csv).")
@click.option("--parquet", "parquet_out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the track table as Parquet (metrics: OUT.metrics.parquet).")
@_clean_errors
def export(run: Path, csv_out: Path | None, parquet_out: Path | None) -> None:
    """Export a run's tracks (the output of `track`) as a table.

    One row per track per frame: frame, stamp_ns, label, the state [px, vx, py, vy, omega],
    its covariance diagonal (var_*) and the existence. When the run has truth, a second file
    holds one row per frame: OSPA (c=100 m, p=1, position) and its parts, cardinality error.

    \b
    Example:
      bnptrack export recordings/vo2017-s1-ddp.tracks.mcap --csv tracks.csv
    """
    from pipeline.export import export as do_export

    if csv_out is None and parquet_out is None:
        raise CliError("give --csv OUT.csv and/or --parquet OUT.parquet")
    try:
        for fmt, out in (("csv", csv_out), ("parquet", parquet_out)):
            if out is not None:
                res = do_export(run, out, fmt)
                _echo_rows([("wrote", f"{res.tracks_path} ({res.track_rows} track rows)")]
                           + ([("wrote", f"{res.metrics_path} ({res.metric_rows} frame rows)")]
                              if res.metrics_path else []))
    except ValueError as exc:
        raise CliError(str(exc)) from None
def _live_view(view: bool, connect: str | None) -> str | None:
    """``"spawn"`` (``--view``), a viewer URL (``--connect``; checked now: a viewer must be
    listening there) or None."""
    if view and connect:
        raise click.UsageError("--view starts a viewer, --connect URL uses a running one: give one of them")
    if connect:
        from pipeline.live import check_viewer

        return check_viewer(connect)
    return "spawn" if view else None


def _open_live(live: str) -> str:
    """The URL to stream to: ``live``, or that of a viewer started now (``"spawn"``)."""
    if live != "spawn":
        return live
    from pipeline.live import spawn_viewer

    viewer = spawn_viewer()
    click.echo(f"viewer: {viewer.url} (pid {viewer.pid}; it stays open after the run)", err=True)
    return viewer.url


# --------------------------------------------------------------------------- view


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected WIDTHxHEIGHT, e.g. 1600x900", param_hint="--size") from None
    if w < 64 or h < 64:
        raise click.BadParameter(f"{text!r}: at least 64x64", param_hint="--size")
    return w, h


@main.command()
@click.argument("rrd", type=click.Path(exists=True, dir_okay=False, path_type=Path), metavar="FILE.rrd")
@click.option(
    "--screenshot",
    "screenshot_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    metavar="OUT.png",
    help="Render the recording without a screen (headless viewer) to OUT.png instead of opening a window.",
)
@click.option(
    "--frame",
    type=int,
    default=None,
    metavar="K",
    help="With --screenshot: the frame to show (time cursor on the frame timeline). Default: the last frame.",
)
@click.option("--size", default="1600x900", show_default=True, metavar="WxH", help="With --screenshot: picture size.")
@click.option(
    "--timeout", type=click.FloatRange(min=1.0), default=60.0, show_default=True,
    help="With --screenshot: give up after this many seconds."
)
@click.option("--web", is_flag=True, help="Serve the web viewer on 127.0.0.1 (open the printed URL) instead of a native window.")
@click.option(
    "--repair",
    "repair_out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    metavar="OUT.rrd",
    help="Rewrite a damaged recording (e.g. its writer was killed before the footer) into OUT.rrd, "
    "keeping every readable chunk, and exit.",
)
@_clean_errors
def view(
    rrd: Path,
    screenshot_path: Path | None,
    frame: int | None,
    size: str,
    timeout: float,
    web: bool,
    repair_out: Path | None,
) -> None:
    """Open a Rerun recording (.rrd) in the Rerun viewer, or render it to a PNG.

    FILE.rrd comes from `bnptrack track LOG --rrd FILE.rrd`, `bnptrack launch`/`replay`
    (run.rrd) or `bnptrack experiment`: the 2-D scene (measurements coloured by the track
    they were assigned to, grey clutter, tracks with label, trail and 2-sigma ellipse, ground
    truth as grey crosses) beside the time series (cardinality, OSPA, OSPA(2), tracker
    diagnostics). See docs/rerun.md.

    Without options this runs the viewer that ships with rerun-sdk (`rerun FILE.rrd`) and
    needs a display. --screenshot renders headless instead; on a machine without a GPU that
    needs Mesa's software renderer (Debian: apt-get install -y mesa-vulkan-drivers).

    \b
    Examples:
      bnptrack view recordings/vo2017-s1-ddp.rrd
      bnptrack view recordings/vo2017-s1-ddp.rrd --screenshot shot.png --frame 60
      bnptrack view broken.rrd --repair fixed.rrd
    """
    from pipeline.view import ViewerUnavailable, open_viewer, screenshot
    from sinks.rerun_sink import RerunToolError, repair

    if screenshot_path is None and frame is not None:
        raise click.UsageError("--frame needs --screenshot")
    try:
        if repair_out is not None:
            out = repair(rrd, repair_out)
            click.echo(f"wrote {out} ({out.stat().st_size} bytes)")
            return
        if screenshot_path is not None:
            w, h = _parse_size(size)
            out = screenshot(rrd, screenshot_path, frame=frame, size=(w, h), timeout=timeout)
            click.echo(f"wrote {out} ({w}x{h}, frame {'last' if frame is None else frame})")
            return
        code = open_viewer(rrd, web=web)
    except (ViewerUnavailable, RerunToolError, TimeoutError) as exc:
        raise CliError(str(exc)) from exc
    if code:
        raise CliError(f"the Rerun viewer exited with code {code}")


# --------------------------------------------------------------------------- experiment


@main.command()
@click.argument("name", type=click.Choice(["ddp-vs-glmb", "proximity", "snr", "dpy-vs-glmb", "dpy-vs-ddp", "random"]))
@click.option("--runs", type=click.IntRange(min=1), default=100, show_default=True, help="Monte Carlo runs.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True,
              help="Experiment seed; run i uses SeedSequence(seed, spawn_key=(crc32(NAME), i)).")
@click.option("--params", "params_name", type=click.Choice(["vo2017", "paper"]), default="vo2017",
              show_default=True, help="Model parameter set.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output directory. Default: recordings/experiments/NAME-PARAMS-sSEED.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local worker processes (default: one per core).")
@click.option("--cluster", metavar="ADDRESS", default=None,
              help="Run on a Dask distributed scheduler (e.g. tcp://10.0.0.5:8786) instead of local processes.")
@click.option("--no-rrd", is_flag=True, help="Skip the .rrd recordings of the representative run.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no summary.")
@_clean_errors
def experiment(name: str, runs: int, seed: int, params_name: str, out: Path | None, workers: int | None,
               cluster: str | None, no_rrd: bool, quiet: bool) -> None:
    """Run one of the paper's simulation experiments as a Monte Carlo study.

    \b
    ddp-vs-glmb   DDP-EMM vs GLMB, 10 targets (vo2017 scenario)
    proximity     DDP-EMM vs GLMB, 5 targets on one path
    snr           DDP-EMM vs GLMB, range-only, SNR -3/-5/-10 dB
    dpy-vs-glmb   DPY-STP vs GLMB, 5 targets (dpy5)
    dpy-vs-ddp    DPY-STP vs DDP-EMM, 10 targets
    random        DDP-EMM, DPY-STP and GLMB on generated random scenes (no birth regions)

    Writes summary.md / summary.csv (mean and spread over runs of OSPA and its parts,
    OSPA(2), GOSPA, cardinality error, ms per frame; for random also the fraction of
    crossing pairs that keep both labels), PNG plots mirroring the paper's
    figures and one .rrd per tracker of run 0. Runs are seeded from (NAME, --seed, run
    index): a run redone alone, locally or on a Dask cluster, gives the same numbers.

    \b
    Examples:
      bnptrack experiment ddp-vs-glmb --runs 100
      bnptrack experiment snr --runs 20 --params paper --out out/snr
      bnptrack experiment dpy-vs-ddp --runs 1000 --cluster tcp://scheduler:8786
    """
    from pipeline.experiments import run_experiment

    res = run_experiment(name, runs=runs, seed=seed, params=params_name, out=out, workers=workers,
                         cluster=cluster, quiet=quiet, rrd=not no_rrd)
    if not quiet:
        click.echo(res.summary_md.read_text())
        rows = [("took", f"{res.seconds:.1f} s for {len(res.rows) and res.rows[0]['runs']} run(s) per condition"),
                ("summary", f"{res.summary_md} , {res.summary_csv}")]
        rows += [("plot", str(p)) for p in res.plots]
        rows += [("recording", str(p)) for p in res.recordings]
        _echo_rows(rows)


# --------------------------------------------------------------------------- schema


@main.command()
@click.argument("topic", metavar="TOPIC")
@_clean_errors
def schema(topic: str) -> None:
    """Print the JSON Schema of a channel's messages.

    TOPIC is /measurements, /truth or /tracks. The same schema is stored in every MCAP log for its channel (schema encoding
    jsonschema). The leading slash is optional.

    \b
    Example:
      bnptrack schema /tracks > tracks.schema.json
    """
    name = topic if topic.startswith("/") else "/" + topic
    if name not in MSG_TYPES:
        raise click.UsageError(
            f"unknown topic {topic!r}; valid topics: {', '.join(MSG_TYPES)}"
        )
    click.echo(json.dumps(json_schema(name), indent=2))


# --------------------------------------------------------------------------- pipeline
# (launch, replay, stage, router: the Zenoh pipeline; see docs/pipeline.md)

_SET_HELP_PIPE = (
    "Override a setting, KEY=VALUE (VALUE is a TOML literal). source.KEY, sink.KEY, delivery.KEY, "
    "zenoh.KEY and tracker.KEY of the tracker stage (tracker, config, params, seed, ...) are keys "
    "of the pipeline file; params.KEY, tracker.KEY of the tracker's settings and a bare KEY mean "
    "what they mean in `bnptrack track` (a bare KEY: model parameters first, then tracker "
    "settings), e.g. --set source.frames=20 --set tracker.seed=3 --set tracker.sweeps=10 "
    "--set p_detect=0.9. Repeatable."
)


def _echo_err(msg: str) -> None:
    click.echo(msg, err=True)


def _report_launch(res: Any, quiet: bool, paced: bool = True) -> None:
    """Print a launch/replay result; raise CliError on failure."""
    summary = res.summary or {}
    if not quiet:
        gaps = summary.get("gaps") or {}
        gap_text = ", ".join(f"{k} {v}" for k, v in gaps.items() if v) or "none"
        restarts = ", ".join(f"{k} {v}" for k, v in res.restarts.items() if v) or "none"
        rows = [("run", res.run), ("out", f"{res.out}/")]
        if summary:
            rows.append(("frames", f"{summary.get('frames_written', 0)} "
                                   f"({summary.get('tracks_written', 0)} /tracks; gaps: {gap_text})"))
            c = summary.get("counters") or {}
            rows.append(("rejected", f"{c.get('rejected', 0)} (duplicates dropped: {c.get('duplicates', 0)})"))
            from pipeline.launch import describe_missing

            rows.append(("missing", describe_missing(summary) or "nothing (the output is complete)"))
            lat = (c.get("latency_ms") or {})
            if lat.get("p50") is not None:
                note = "" if paced else " (frames published as fast as possible: includes queueing)"
                rows.append(("latency", f"source -> sink p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms{note}"))
        rows += _score_rows(summary.get("scores"))
        rows += [("restarts", restarts), ("elapsed", f"{res.elapsed_s:.1f} s")]
        for f in res.files:
            try:
                rows.append(("wrote", f"{f} ({Path(f).stat().st_size} bytes)"))
            except OSError:
                pass
        if summary.get("view"):
            rows.append(("open with", summary["view"]))
        _echo_rows(rows)
    if res.interrupted:
        click.echo(f"Interrupted: partial files are in {res.out}/", err=True)
        raise SystemExit(130)
    if res.incomplete:
        raise IncompleteError(f"output incomplete: {res.incomplete} -- files are in {res.out}/")
    if not res.ok:
        raise CliError(f"{res.error} -- files (if any) are in {res.out}/")


def _score_rows(scores: dict | None) -> list[tuple[str, str]]:
    """Summary rows of the sink's ``scores`` (``sink.json``): the means of OSPA, OSPA(2)
    and the cardinality error over the frames with truth, and the tracks."""
    if not scores:
        return []
    rows = []
    if scores.get("ospa") is not None:
        rows += [
            ("mean OSPA", f"{scores['ospa']:.2f} m (c={scores.get('c', OSPA_C):g}, "
                          f"p={scores.get('p', OSPA_P):g}, position; {scores['frames_scored']} frames)"),
            ("mean OSPA(2)", f"{scores['ospa2']:.2f} m (window {scores.get('ospa2_window')} frames)"),
            ("mean card. error", f"{scores['cardinality_error']:.2f}"),
        ]
    elif scores.get("frames"):
        rows.append(("mean OSPA", "n/a (the frames carry no truth)"))
    rows.append(("tracks", f"{scores.get('tracks', 0)} at the last frame "
                           f"({scores.get('labels', 0)} labels in all)"))
    return rows


def _run_pipeline(cfg: Any, timeout: float | None, quiet: bool, overwrite: bool = False,
                  view: bool = False, view_connect: str | None = None) -> None:
    import msgspec as _ms

    from pipeline.launch import launch as _launch
    from pipeline.progress import Progress

    if view and view_connect:
        raise click.UsageError("--view starts a viewer, --connect URL uses a running one: give one of them")
    if view_connect:  # checked with the rest of the configuration (pipeline.preflight)
        from pipeline.live import viewer_url

        cfg = _ms.structs.replace(cfg, sink=_ms.structs.replace(cfg.sink, view_url=viewer_url(view_connect)))
    progress = None if quiet else Progress(sys.stderr)
    try:
        res = _launch(cfg, echo=None if progress is None else progress.echo, timeout=timeout,
                      overwrite=overwrite, progress=None if progress is None else progress.update,
                      view=view)
    finally:
        if progress is not None:
            progress.close()
    _report_launch(res, quiet, paced=cfg.source.rate > 0)


_OVERWRITE_OPT = click.option(
    "--overwrite", is_flag=True,
    help="Replace the files of an earlier run in the output directory (without it, such a "
    "directory is refused with exit code 2; a directory with a live run is always refused).",
)

_TIMEOUT_OPT = click.option(
    "--timeout", type=click.FloatRange(min=0, min_open=True), default=None, metavar="SECONDS",
    help="Stop everything and fail if the pipeline has not finished after this long.",
)


@main.command()
@click.argument("pipeline_file", metavar="[PIPELINE.toml]", required=False,
                type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=_SET_HELP_PIPE)
@click.option("--run", "run_id", default=None, metavar="RUN",
              help="Run id (key-expression chunk). Default: <scenario>-<time>-<hex>.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output directory. Default: recordings/<run>/.")
@click.option("--connect", "connect", multiple=True, metavar="ENDPOINT|URL",
              help="Use this Zenoh router (e.g. tcp/10.0.0.5:7447) instead of an embedded one; "
              "a Rerun URL (rerun+http://HOST:PORT/proxy) instead streams the recording live to "
              "that running viewer.")
@click.option("--view", is_flag=True, help=_VIEW_HELP)
@_TIMEOUT_OPT
@_OVERWRITE_OPT
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors (no progress lines).")
@_clean_errors
def launch(pipeline_file: Path | None, overrides: tuple[str, ...], run_id: str | None,
           out: Path | None, connect: tuple[str, ...], view: bool, timeout: float | None, overwrite: bool,
           quiet: bool) -> None:
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
      bnptrack launch my_pipeline.toml --run test-1
    """
    import msgspec as _ms

    from pipeline.pipeline_config import load_pipeline

    cfg = load_pipeline(pipeline_file, overrides)
    if run_id:
        cfg = _ms.structs.replace(cfg, run=run_id)
    if out:
        cfg = _ms.structs.replace(cfg, out=str(out))
    from pipeline.live import is_viewer_url

    viewers = [c for c in connect if is_viewer_url(c)]
    routers = [c for c in connect if not is_viewer_url(c)]
    if len(viewers) > 1:
        raise click.UsageError("--connect: give at most one Rerun viewer URL")
    if routers:
        cfg = _ms.structs.replace(cfg, zenoh=_ms.structs.replace(
            cfg.zenoh, embedded_router=False, connect=routers))
    _run_pipeline(cfg, timeout, quiet, overwrite, view, viewers[0] if viewers else None)


@main.command()
@click.argument("log", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--rate", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              metavar="R", help="Replay speed against the log's time stamps (1 = real time).")
@click.option("--as-fast-as-possible", "afap", is_flag=True, help="Publish frames without pacing.")
@click.option("--tracker", "tracker_name", default="ddp", show_default=True,
              help="Tracker: ddp = DDP-EMM, dpyp = DPY-STP (any name `bnptrack track` accepts).")
@click.option("--config", "config_arg", metavar="NAME|FILE.toml", default=None,
              help="Tracker settings preset or TOML file (as `bnptrack track --config`).")
@click.option("--params", "params_arg", metavar="NAME|FILE.toml", default=None,
              help="Model parameters. Default: the log's bnptrack.scenario record (as `track`).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Tracker seed.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=_SET_HELP_PIPE)
@click.option("--run", "run_id", default=None, metavar="RUN", help="Run id. Default: <log stem>-<time>-<hex>.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output directory. Default: recordings/<run>/.")
@click.option("--start", "start", metavar="T|Nf", default=None,
              help="Start at T seconds of log time after the first frame (12.5 or 12.5s), or at frame "
              "number N (40f).")
@click.option("--end", "end", metavar="T|Nf", default=None,
              help="End at T seconds of log time after the first frame, or at frame N (both included).")
@click.option("--loop", "loops", type=click.IntRange(min=0), default=None, metavar="N",
              help="Replay N times (0: until Ctrl-C), each a fresh run (run id RUN-1, RUN-2, ...; "
              "output directories OUT/RUN-i) with a fresh tracker.")
@click.option("--keep-prior", is_flag=True,
              help="With --loop: each replay's tracker starts from the prior the previous replay "
              "ended with (DDP-EMM / DPY-STP: alpha, d and their likelihood), with no track.")
@click.option("--view", is_flag=True, help=_VIEW_HELP)
@click.option("--connect", "view_connect", metavar="URL", default=None, help=_CONNECT_VIEW_HELP)
@_TIMEOUT_OPT
@_OVERWRITE_OPT
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors (no progress lines).")
@_clean_errors
def replay(log: Path, rate: float, afap: bool, tracker_name: str, config_arg: str | None,
           params_arg: str | None, seed: int, overrides: tuple[str, ...], run_id: str | None,
           out: Path | None, start: str | None, end: str | None, loops: int | None, keep_prior: bool,
           view: bool, view_connect: str | None, timeout: float | None, overwrite: bool,
           quiet: bool) -> None:
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
    """
    import msgspec as _ms

    from pipeline.pipeline_config import load_pipeline

    _require_measurements(log, {})  # (replay reads /measurements only; `track --topic` maps channels)
    cfg = load_pipeline(None)
    start_s, start_frame = _parse_offset(start, "--start")
    end_s, end_frame = _parse_offset(end, "--end")
    cfg = _ms.structs.replace(
        cfg,
        source=_ms.structs.replace(cfg.source, kind="mcap", log=str(log), rate=0.0 if afap else rate,
                                   start_s=start_s, start_frame=start_frame, end_s=end_s,
                                   end_frame=end_frame),
        tracker=_ms.structs.replace(cfg.tracker, tracker=tracker_name, seed=seed,
                                    config=config_arg or "", params=params_arg or ""),
    )
    from pipeline.pipeline_config import apply_pipeline_overrides

    cfg = apply_pipeline_overrides(cfg, overrides)
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


def _parse_offset(text: str | None, opt: str) -> tuple[float | None, int | None]:
    """``--start`` / ``--end``: ``12.5`` or ``12.5s`` -> (12.5 s, None); ``40f`` -> (None, 40)."""
    if text is None:
        return None, None
    t = text.strip().lower()
    try:
        if t.endswith("f"):
            n = int(t[:-1])
            if n < 0:
                raise ValueError
            return None, n
        v = float(t[:-1] if t.endswith("s") else t)
        if not v >= 0 or v == float("inf"):
            raise ValueError
        return v, None
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected seconds of log time (12.5 or 12.5s) or a frame "
                                 "number (40f), >= 0", param_hint=opt) from None


def _replay_loop(cfg: Any, loops: int, timeout: float | None, quiet: bool, overwrite: bool,
                 view: bool, view_connect: str | None, keep_prior: bool = False) -> None:
    """``replay --loop N``: the same replay N times (0: until interrupted), each a fresh run:
    run id ``RUN-i`` (RUN: --run, else generated once) and output ``OUT/RUN-i`` (OUT: --out,
    else recordings/); the tracker starts afresh each time, or with ``keep_prior`` from the
    prior of the previous run's final snapshot.  The first failure ends the loop."""
    import itertools

    import msgspec as _ms

    from pipeline.pipeline_config import make_run_id

    base = cfg.run or make_run_id(cfg)
    root = Path(cfg.out) if cfg.out else Path("recordings")
    if view and view_connect:
        raise click.UsageError("--view starts a viewer, --connect URL uses a running one: give one of them")
    if view:  # one viewer for every run of the loop
        view_connect = _open_live("spawn")
    for i in itertools.count(1):
        if loops and i > loops:
            break
        run = f"{base}-{i}"
        if not quiet:
            click.echo(f"loop {i}{f'/{loops}' if loops else ''}: run {run}", err=True)
        one = _ms.structs.replace(cfg, run=run, out=str(root / run))
        if keep_prior and i > 1:
            prev = root / f"{base}-{i - 1}" / "tracker.snap"
            one = _ms.structs.replace(one, tracker=_ms.structs.replace(one.tracker, prior_from=str(prev)))
        _run_pipeline(one, timeout, quiet, overwrite, False, view_connect)


@main.command()
@click.argument("role", type=click.Choice(["source", "tracker", "sink"]))
@click.option("--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None, help="Pipeline file (.toml, or the .json the launcher writes).")
@click.option("--run", "run_id", default=None, metavar="RUN", help="Run id (the same for every stage).")
@click.option("--connect", multiple=True, metavar="ENDPOINT", help="Router endpoint, e.g. tcp/10.0.0.5:7447.")
@click.option("--listen", multiple=True, metavar="ENDPOINT", help="Endpoint to listen on (peer mode).")
@click.option("--mode", type=click.Choice(["client", "peer"]), default=None, help="Zenoh mode (default: client; peer also needs --connect or --listen).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output directory (tracker snapshot, sink files). Default: recordings/<run>/.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=_SET_HELP_PIPE)
@click.option("--name", default=None, help="Stage name (default: the role).")
@click.option("--parent-pid", type=int, default=None, hidden=True)
@click.option("--log-level", default="INFO", show_default=True, help="Logging level.")
@_clean_errors
def stage(role: str, pipeline_file: Path | None, run_id: str | None, connect: tuple[str, ...],
          listen: tuple[str, ...], mode: str | None, out: Path | None, overrides: tuple[str, ...],
          name: str | None, parent_pid: int | None, log_level: str) -> None:
    """Run one pipeline stage in this process (to place stages on different hosts).

    Every stage of a run uses the same --run and reaches the others through a Zenoh router
    (`bnptrack router`, or a launcher's embedded one). Exit codes: 0 done, 2 configuration
    error, 3 the source's input ended on an error, 130 stopped by a signal, 1 crash.

    \b
    Example (three hosts, router on 10.0.0.5):
      bnptrack router --listen tcp/0.0.0.0:7447
      bnptrack stage sink    --run r1 --connect tcp/10.0.0.5:7447 --out /data/r1
      bnptrack stage tracker --run r1 --connect tcp/10.0.0.5:7447 --out /data/r1
      bnptrack stage source  --run r1 --connect tcp/10.0.0.5:7447 --set source.frames=50
    """
    from pipeline.launch import configure_logging, run_stage, stage_config
    from pipeline.pipeline_config import load_pipeline

    configure_logging(name or role, log_level)
    cfg = stage_config(load_pipeline(pipeline_file, overrides), run=run_id, out=str(out) if out else None,
                       connect=connect, listen=listen, mode=mode)
    code = run_stage(role, cfg, name=name, parent_pid=parent_pid)
    raise SystemExit(code)


@main.command()
@click.option("--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None, help="Pipeline file: its [zenoh] table (TLS, router_extra) is used.")
@click.option("--listen", multiple=True, metavar="ENDPOINT",
              help="Endpoint(s) to listen on. Default: tcp/127.0.0.1:7447 (this host only; "
                   "give e.g. tcp/0.0.0.0:7447 for other hosts, with TLS and --set zenoh.acl=true).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=_SET_HELP_PIPE)
@_clean_errors
def router(pipeline_file: Path | None, listen: tuple[str, ...], overrides: tuple[str, ...]) -> None:
    """Run a Zenoh router for pipeline stages on several hosts (until Ctrl-C).

    \b
    Example:
      bnptrack router --listen tcp/0.0.0.0:7447
    """
    import signal as _signal
    import threading as _threading

    from pipeline.pipeline_config import load_pipeline
    from pipeline.transport import Router

    cfg = load_pipeline(pipeline_file, overrides)
    stop = _threading.Event()
    for sig in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(sig, lambda *_: stop.set())
    with Router(cfg.zenoh, list(listen) or ["tcp/127.0.0.1:7447"]) as r:
        click.echo(f"router listening on {', '.join(r.endpoints)} (Ctrl-C to stop)", err=True)
        while not stop.wait(0.5):
            pass


@main.command()
@click.option("--run", "run_id", required=True, metavar="RUN", help="Run id to watch.")
@click.option("--connect", multiple=True, required=True, metavar="ENDPOINT", help="Router endpoint.")
@click.option("--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None, help="Pipeline file (for its [zenoh] TLS settings).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=_SET_HELP_PIPE)
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), default=None, metavar="SECONDS",
              help="Stop after this long (default: until Ctrl-C).")
@click.option("--connect-timeout", type=click.FloatRange(min=0), default=1.0, show_default=True,
              metavar="SECONDS", help="Give up when no router answers within this long.")
@_clean_errors
def monitor(run_id: str, connect: tuple[str, ...], pipeline_file: Path | None, overrides: tuple[str, ...],
            duration: float | None, connect_timeout: float) -> None:
    """Watch a run's stages: liveliness, health counters, dead letters, end of stream.

    With no router at --connect: one line `Error: no router at ...` and exit code 2.

    \b
    Example:
      bnptrack monitor --run r1 --connect tcp/127.0.0.1:7447
    """
    import signal as _signal
    import threading as _threading
    import time as _time

    import msgspec as _ms

    from pipeline.launch import stage_config
    from pipeline.pipeline_config import load_pipeline
    from pipeline.transport import Bus

    cfg = stage_config(load_pipeline(pipeline_file, overrides), run=run_id, out=None, connect=connect,
                       listen=(), mode=None)
    cfg = _ms.structs.replace(cfg, zenoh=_ms.structs.replace(cfg.zenoh, connect_timeout_s=connect_timeout))
    stop = _threading.Event()
    for sig in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(sig, lambda *_: stop.set())
    end = _time.monotonic() + duration if duration else None
    with Bus(cfg.run, "monitor", cfg.zenoh, cfg.delivery) as bus:
        bus.subscribe(["health/*", "deadletter"], advanced=False)
        bus.subscribe(["eos/*"])
        shown: tuple = ()
        while not stop.is_set() and (end is None or _time.monotonic() < end):
            now = (bus.alive(), bus.alive("ready"))
            if now != shown:
                click.echo(f"alive: {', '.join(sorted(now[0])) or '(none)'}; "
                           f"ready: {', '.join(sorted(now[1])) or '(none)'}")
                shown = now
            ev = bus.recv(0.2)
            if ev is None:
                continue
            try:
                doc = json.loads(ev.payload)
            except ValueError:
                click.echo(f"{ev.topic}: {len(ev.payload)} bytes (not JSON)")
                continue
            if ev.topic.startswith("health/"):
                c = doc.get("counters", {})
                lat = c.get("latency_ms") or {}
                lat_text = (f" latency p50 {lat['p50']:.1f} ms p99 {lat['p99']:.1f} ms"
                            if lat.get("p50") is not None else "")
                click.echo(f"{doc.get('stage')}: pid {doc.get('pid')} received {c.get('received')} "
                           f"accepted {c.get('accepted')} rejected {c.get('rejected')} dup "
                           f"{c.get('duplicates')} gaps {c.get('gaps')} dropped {doc.get('dropped')} "
                           f"backlog {doc.get('backlog')}{lat_text}")
            elif ev.topic == "deadletter":
                click.echo(f"dead letter from {doc.get('stage')}: {doc.get('topic')} seq {doc.get('seq')}: "
                           f"{doc.get('reason')}")
            else:
                click.echo(f"{ev.topic}: last seq {doc.get('last_seq')}, {doc.get('frames')} frame(s)"
                           + (f", gaps {doc['gaps']}" if doc.get("gaps") else "")
                           + (f", error: {doc['error']}" if doc.get("error") else ""))


if __name__ == "__main__":  # pragma: no cover
    main()
