"""The offline tools of ``bnptrack``: ``info`` (describe a log), ``export`` (tracks as a
table), ``view`` (open or render a recording), ``experiment`` (the paper's Monte Carlo
studies) and ``schema`` (the JSON Schema of a channel).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import click

from bnptrack.pipeline.cli.common import FiniteRange, Choice, CliError, clean_errors, echo_rows, topic_map
from bnptrack.pipeline.cli.option_types import PathName
from bnptrack.tracker.config import did_you_mean
from bnptrack.tracker.message_units import described_schema
from bnptrack.tracker.messages import MSG_TYPES
from bnptrack.pipeline.experiments import DEFAULT_EXPERIMENT_PARAMS, EXPERIMENTS
from bnptrack.sources.mcap_log import McapLogError, read_metadata
from bnptrack.tracker.models.params import BUILTIN_PARAMS

__all__ = ["info", "export", "view", "experiment", "schema"]


# --------------------------------------------------------------------------- info


@click.command()
@click.argument("log", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--topic", "topics", multiple=True, metavar="SRC[=/measurements]",
              help="Read channel SRC (as `bnptrack track --topic`).")
@clean_errors
def info(log: Path, topics: tuple[str, ...]) -> None:
    """Describe an MCAP log: channels, frames, sensors, time, and its record.

    Prints every channel (topic, schema and encodings, message count; for a channel bnptrack
    can track, its kind and the exact --topic to give track / replay); for /measurements the
    frames, sensors and kinds (with their poses when the frames carry them), the time span and
    frame rate from the stamps; and the bnptrack.scenario record (scenario, params, seed).

    \b
    Examples:
      bnptrack info recordings/vo2017-s1.mcap
      bnptrack info robot.mcap --topic /radar/scan   # your ROS 2 log: the frames and sensors of one channel
    """
    from bnptrack.pipeline.resolve import DEFAULT_PARAMS
    from bnptrack.sources.mcap_log import log_channels
    from bnptrack.sources.robot_log import robot_topics

    channels = log_channels(log)
    rows = [("log", f"{log} ({log.stat().st_size} bytes)")]
    for c in channels:
        rows.append(("channel", f"{c.topic}: schema {c.schema or '-'} ({c.schema_encoding or '-'}), "
                                f"encoding {c.message_encoding}, {c.messages} messages{_trackable_note(c)}"))
    if not channels:
        rows.append(("channel", "none"))
    mapping = topic_map(topics)
    try:
        robot_topics(log, mapping, channels)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if mapping and channels:
        from bnptrack.pipeline.offline import read_log_start

        read_log_start(log, mapping)  # a mapped channel that is not measurements: one line naming it
    frame_rows, error = _frame_rows(log, mapping) if channels else ([("frames", "0 (the log has no channels)")], None)
    rows += frame_rows
    meta = read_metadata(log)
    if meta:
        rows += [(f"record.{k}", v) for k, v in meta.items()]
    else:
        rows.append(("record", f"none (no bnptrack.scenario metadata: track uses the {DEFAULT_PARAMS} model "
                               "unless --params says otherwise)"))
    echo_rows(rows)
    if error is not None:
        raise CliError(f"{error} -- the lines above describe the frames before it")


def _trackable_note(channel) -> str:
    """What ``info`` says of a channel bnptrack can track: its kind and the ``--topic`` to use."""
    from bnptrack.sources.channels import trackable
    from bnptrack.sources.robot_log import TF_SCHEMA, TF_STATIC
    from bnptrack.tracker.messages import TOPIC_MEASUREMENTS

    entry = trackable(channel)
    if entry is not None:
        return f"; trackable ({entry.kind}): --topic {channel.topic}"
    if channel.topic == TOPIC_MEASUREMENTS:
        return "; trackable (bnptrack measurements, read by default)"
    if channel.topic == TF_STATIC and channel.schema == TF_SCHEMA:
        return "; sensor poses (static transforms)"
    return ""


def _unposed_note(name: str, kind: str) -> str:
    """The sensor row's note for a sensor whose frames carry no pose (not the default sensor)."""
    from bnptrack.tracker.models.measurement import KINDS

    entry = KINDS.get(kind)
    default = ("its field of view and clutter region are the default sensor's, at (0, 0) facing +y"
               if entry is not None and entry.world_frame else "it is tracked as if at (0, 0) facing +y")
    return f", no pose in its frames: give --params a [sensors.{name}] table with x, y, heading_deg (else {default})"


def _frame_rows(log: Path, topic_map: dict[str, str]) -> tuple[list[tuple[str, str]], McapLogError | None]:
    """Frames, sensors / kinds and time rows of ``bnptrack info`` (empty without /measurements),
    and the error that ended reading early (None: the whole log was read); a sensor whose
    stamps look like another unit gets ``track``'s warning."""
    import numpy as np

    from bnptrack.sources.mcap_log import iter_frames
    from bnptrack.tracker.input_checks import DEFAULT_SENSOR_NAMES, check_spacing, warn

    sensors: dict[tuple[str, str], list] = {}
    stamps, n_meas, truth, error = [], 0, 0, None
    try:
        for f in iter_frames(log, topic_map):
            entry = sensors.setdefault((f.sensor, f.kind), [0, set(), []])
            entry[0] += 1
            entry[2].append(f.stamp_ns)
            if f.pose is not None:
                entry[1].add(f.pose)
            stamps.append(f.stamp_ns)
            n_meas += f.n_measurements
            truth += f.truth is not None
    except McapLogError as exc:
        error = exc
    if not stamps:
        return [("frames", "0" + ("" if error else " (no /measurements: give --topic with a trackable channel)"))], error
    for note in filter(None, (check_spacing(name, times) for name, times in _sensor_stamps(sensors).items())):
        warn(note)
    rows = [("frames", f"{len(stamps)} ({n_meas} measurements, {n_meas / len(stamps):.1f} per frame; "
                       f"{truth} with truth)")]
    for (name, kind), (n, poses, _) in sensors.items():
        pose = _unposed_note(name, kind) if name not in DEFAULT_SENSOR_NAMES else ""
        if poses:
            p = sorted(poses)[0]
            pose = f", pose ({p[0]:g}, {p[1]:g}, {np.rad2deg(p[2]):g} deg)" + (f" and {len(poses) - 1} more" if len(poses) > 1 else "")
        rows.append(("sensor", f"{name}: kind {kind}, {n} frames{pose}"))
    span = (stamps[-1] - stamps[0]) / 1e9
    dt = np.diff(np.asarray(stamps, dtype=np.int64)) / 1e9
    rate = f"{(len(stamps) - 1) / span:.3g} frames/s" if span > 0 else "n/a (all stamps equal)"
    origin = " after t = 0" if stamps[-1] < _DATE_FROM_NS else ""
    rows.append(("time", f"{stamp_text(stamps[0])} to {stamp_text(stamps[-1])}{origin} (span {duration_text(span)}), {rate}"
                 + (f", dt median {duration_text(float(np.median(dt)))}, min {duration_text(float(dt.min()))}, "
                    f"max {duration_text(float(dt.max()))}" if dt.size else "")))
    return rows, error


def _sensor_stamps(sensors: dict[tuple[str, str], list]) -> dict[str, list[int]]:
    """Each sensor's stamps in file order (from the ``(name, kind)`` entries of :func:`_frame_rows`)."""
    out: dict[str, list[int]] = {}
    for (name, _kind), (_n, _poses, stamps) in sensors.items():
        out.setdefault(name, []).extend(stamps)
    return out


#: Stamps from this one on (2001-09-09) read as dates; smaller ones as seconds from the origin.
_DATE_FROM_NS = 10**18


def stamp_text(stamp_ns: int) -> str:
    """A time stamp as a UTC date and time (``2024-03-01 12:00:05.250 UTC``) when it is one,
    else (a log that counts from 0) as seconds from the origin (``5.250 s``)."""
    if stamp_ns < _DATE_FROM_NS:
        return f"{stamp_ns / 1e9:.3f} s"
    from datetime import datetime, timezone

    d = datetime.fromtimestamp(stamp_ns // 10**9, tz=timezone.utc)
    return f"{d:%Y-%m-%d %H:%M:%S}.{stamp_ns % 10**9 // 10**6:03d} UTC"


def duration_text(seconds: float) -> str:
    """A duration: ``250 ms``, ``59 s``, ``1.5 s``, ``2 min 05 s``, ``3 h 02 min 05 s``."""
    if seconds < 1.0:
        return f"{seconds * 1e3:.3g} ms"
    if seconds < 60.0:
        return f"{seconds:.3g} s"
    total = int(round(seconds))
    h, rest = divmod(total, 3600)
    m, sec = divmod(rest, 60)
    return f"{h} h {m:02d} min {sec:02d} s" if h else f"{m} min {sec:02d} s"


# --------------------------------------------------------------------------- export


@click.command()
@click.argument("run", type=click.Path(exists=True, dir_okay=False, path_type=Path), metavar="RUN.mcap")
@click.option("--csv", "csv_out", type=PathName(dir_okay=False, path_type=Path), default=None,
              help="Write the track table as CSV (metrics beside it: OUT.metrics.csv).")
@click.option("--overwrite", is_flag=True, help="Replace output files that exist (without it, an existing "
              "output is refused with exit code 2 before anything is written).")
@click.option("--parquet", "parquet_out", type=PathName(dir_okay=False, path_type=Path), default=None,
              help="Write the track table as Parquet (metrics: OUT.metrics.parquet).")
@clean_errors
def export(run: Path, csv_out: Path | None, parquet_out: Path | None, overwrite: bool) -> None:
    """Export a run's tracks (the output of `track`) as a table.

    One row per track per frame: frame, stamp_ns, label, name (the display name the viewer
    and the summary show), the state [px, vx, py, vy, omega],
    its covariance diagonal (var_*) and the existence. When the run has truth, a second file
    holds one row per frame: OSPA (c=100 m, p=1, position) and its parts, cardinality error.

    \b
    Example:
      bnptrack export recordings/vo2017-ddp.mcap --csv tracks.csv
      bnptrack export recordings/vo2017-ddp.mcap --csv tracks.csv --overwrite   # replace an earlier export
    """
    from bnptrack.pipeline.export import check_export_outputs, metrics_path
    from bnptrack.pipeline.export import export as do_export
    from bnptrack.pipeline.output_paths import check_writable, refuse_existing

    if csv_out is None and parquet_out is None:
        raise CliError("give --csv OUT.csv and/or --parquet OUT.parquet")
    tables = {o: p for o, p in (("--csv", csv_out), ("--parquet", parquet_out)) if p is not None}
    check_export_outputs(run, tables)
    for option, path in tables.items():
        check_writable(path, option)
    outs = [p for p in (csv_out, parquet_out) if p is not None]
    refuse_existing({str(p): p for out in outs for p in (out, metrics_path(out))}, overwrite,
                    "--csv / --parquet file")
    try:
        for fmt, out in (("csv", csv_out), ("parquet", parquet_out)):
            if out is not None:
                res = do_export(run, out, fmt)
                echo_rows([("wrote", f"{res.tracks_path} ({res.track_rows} track rows)")]
                           + ([("wrote", f"{res.metrics_path} ({res.metric_rows} frame rows)")]
                              if res.metrics_path else []))
    except ValueError as exc:
        raise CliError(str(exc)) from None


# --------------------------------------------------------------------------- view


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected WIDTHxHEIGHT, e.g. 1600x900", param_hint="--size") from None
    if w < 64 or h < 64:
        raise click.BadParameter(f"{text!r}: at least 64x64", param_hint="--size")
    if w > MAX_SIDE or h > MAX_SIDE:
        raise click.BadParameter(f"{text!r}: at most {MAX_SIDE} pixels a side (the renderer's largest picture)",
                                 param_hint="--size")
    return w, h


#: The largest side of a screenshot: the largest texture every wgpu adapter supports.
MAX_SIDE = 8192


@click.command()
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
    "--timeout", type=FiniteRange(min=1.0), default=60.0, show_default=True,
    help="With --screenshot: give up after this many seconds."
)
@click.option("--web", is_flag=True, help="Serve the web viewer on 127.0.0.1 (open the printed URL) instead of a native window.")
@click.option(
    "--repair",
    "repair_out",
    type=PathName(dir_okay=False, path_type=Path),
    default=None,
    metavar="OUT.rrd",
    help="Rewrite a damaged recording (e.g. its writer was killed before the footer) into OUT.rrd, "
    "keeping every readable chunk, and exit.",
)
@clean_errors
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
      bnptrack view recordings/vo2017-ddp.rrd
      bnptrack view recordings/vo2017-ddp.rrd --screenshot shot.png --frame 60
      bnptrack view broken.rrd --repair fixed.rrd   # a recording cut short by a crash
    """
    from bnptrack.pipeline.view import ViewerUnavailable, open_viewer, screenshot
    from bnptrack.sinks.rerun_tools import RerunToolError, repair

    if screenshot_path is None and frame is not None:
        raise click.UsageError("--frame needs --screenshot")
    _check_recording(rrd, footer=repair_out is None)
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


def _check_recording(path: Path, footer: bool = True) -> None:
    """A file that is not a Rerun recording is an error naming what it is: an MCAP log (the
    command that records one), or another file.  With ``footer``, a recording without its
    footer (its writer stopped before the end, or is still writing) gets a warning naming
    ``--repair`` (the viewer shows what it reads of it)."""
    from bnptrack.sources.channels import MCAP_MAGIC

    try:
        with open(path, "rb") as f:
            head = f.read(8)
            f.seek(max(0, f.seek(0, os.SEEK_END) - RRD_FOOTER_TAIL))
            tail = f.read()
    except OSError:
        return  # the viewer's own error names it
    if head.startswith(MCAP_MAGIC):
        raise CliError(f"{path} is an MCAP log; view expects a Rerun .rrd recording: for the tracks of a log, "
                       f"`bnptrack track LOG --rrd FILE.rrd` records one (a run of launch / replay writes run.rrd)")
    if not head:
        raise CliError(f"{path} is empty (0 bytes): not a Rerun recording; view expects a Rerun .rrd recording, "
                       f"e.g. from `bnptrack track LOG --rrd FILE.rrd`")
    if not head.startswith(RRD_MAGIC):
        raise CliError(f"{path} is not a Rerun recording (it starts with {head!r}, not {RRD_MAGIC!r}); "
                       f"view expects a Rerun .rrd recording, e.g. from `bnptrack track LOG --rrd FILE.rrd`")
    if footer and not RRD_FOOTER.fullmatch(tail[:8]):
        from bnptrack.pipeline.output_paths import view_command

        click.echo(f"warning: {path} is incomplete: it has no footer (its writer stopped before the end, e.g. a "
                   f"crash, or is still writing); `{view_command(path)} --repair FIXED.rrd` keeps its complete "
                   "frames", err=True)


#: The bytes every Rerun recording (.rrd) starts with (then the format version).
RRD_MAGIC = b"RRF"
#: A complete recording's last bytes: "RRF", the format version, "FOOT", then 4 more bytes.
RRD_FOOTER = re.compile(rb"RRF.FOOT", re.DOTALL)
RRD_FOOTER_TAIL = 12


# --------------------------------------------------------------------------- experiment


_EXPERIMENT_HELP = """Run one of the paper's simulation experiments as a Monte Carlo study.

\b
""" + "\n".join(f"{e.name:<13} {e.description}" for e in EXPERIMENTS.values()) + """

Writes summary.md / summary.csv (mean and spread over runs of OSPA and its parts,
OSPA(2), GOSPA, cardinality error, ms per frame; for random also the fraction of
crossing pairs that keep both labels), PNG plots mirroring the paper's
figures and one .rrd per tracker of run 0. Each mean has its 95% confidence
interval. Runs are seeded from (NAME, --seed, run index): a run redone alone,
locally or on a Dask cluster, gives the same numbers.

Resumable: every finished run is appended to OUT/runs.jsonl. The same command
started again (after a stop, a crash, or with a larger --runs) runs only the
runs that file lacks; --fresh starts over. A file written by other tracker code
is refused, so runs of two versions are never pooled, unless --revalidate K
redoes K of its runs with this code and every one gives the same scores.

\b
Examples:
  bnptrack experiment ddp-vs-glmb --runs 100
  bnptrack experiment snr --runs 20 --params vo2017 --out out/snr
  bnptrack experiment dpy-vs-ddp --runs 1000 --cluster tcp://scheduler:8786
  bnptrack experiment ddp-vs-glmb --runs 10000 --no-rrd   # stop and rerun at will
"""


@click.command(help=_EXPERIMENT_HELP)
@click.argument("name", type=Choice(list(EXPERIMENTS)))
@click.option("--runs", type=click.IntRange(min=1), default=100, show_default=True, help="Monte Carlo runs.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True,
              help="Experiment seed; run i uses SeedSequence(seed, spawn_key=(crc32(NAME), i)).")
@click.option("--params", "params_name", type=Choice(BUILTIN_PARAMS), default=DEFAULT_EXPERIMENT_PARAMS,
              show_default=True, help="Model parameter set.")
@click.option("--out", type=PathName(file_okay=False, path_type=Path), default=None,
              help="Output directory. Default: recordings/experiments/NAME-PARAMS-sSEED.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local worker processes (default: one per core).")
@click.option("--cluster", metavar="ADDRESS", default=None,
              help="Run on a Dask distributed scheduler (e.g. tcp://10.0.0.5:8786) instead of local processes; needs the optional extra: pip install 'bnptrack[dask]'.")
@click.option("--no-rrd", is_flag=True, help="Skip the .rrd recordings of the representative run.")
@click.option("--fresh", is_flag=True, help="Discard OUT/runs.jsonl and start from run 0.")
@click.option("--revalidate", type=click.IntRange(min=1), default=None, metavar="K",
              help="Carry over a journal written by other tracker code once K of its runs, redone, give the same scores.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no summary.")
@clean_errors
def experiment(name: str, runs: int, seed: int, params_name: str, out: Path | None, workers: int | None,
               cluster: str | None, no_rrd: bool, fresh: bool, revalidate: int | None, quiet: bool) -> None:
    """Run one of the paper's simulation experiments (help: ``_EXPERIMENT_HELP``, drawn from
    :data:`pipeline.experiments.EXPERIMENTS`)."""
    from bnptrack.pipeline.experiments import run_experiment

    res = run_experiment(name, runs=runs, seed=seed, params=params_name, out=out, workers=workers,
                         cluster=cluster, quiet=quiet, rrd=not no_rrd, fresh=fresh, revalidate=revalidate or 0)
    if not quiet:
        click.echo(res.summary_md.read_text())
        rows = [("took", f"{res.seconds:.1f} s for {len(res.rows) and res.rows[0]['runs']} run(s) per condition"),
                ("summary", f"{res.summary_md}, {res.summary_csv}")]
        rows += [("plot", str(p)) for p in res.plots]
        rows += [("recording", str(p)) for p in res.recordings]
        echo_rows(rows)


# --------------------------------------------------------------------------- schema


@click.command()
@click.argument("topic", metavar="TOPIC")
@clean_errors
def schema(topic: str) -> None:
    """Print the JSON Schema of a channel's messages.

    TOPIC is /measurements, /truth or /tracks. Each property's "description" gives its unit
    (m, m/s, rad, ns, ...). The same schema, without those descriptions, is stored in every MCAP
    log for its channel (schema encoding jsonschema). The leading slash is optional.

    \b
    Example:
      bnptrack schema /tracks > tracks.schema.json
    """
    name = topic if topic.startswith("/") else "/" + topic
    if name not in MSG_TYPES:
        raise click.UsageError(
            f"unknown topic {topic!r}{did_you_mean(name, MSG_TYPES)}; valid topics: {', '.join(MSG_TYPES)}"
        )
    click.echo(json.dumps(described_schema(name), indent=2))
