"""``bnptrack simulate`` and ``bnptrack track``: a scenario into a log, a tracker over a log.

The commands parse options, open the scenario (:func:`sources.scenarios.open_scenario`) or
set the tracker up (:func:`pipeline.resolve.tracker_setup`), run :mod:`pipeline.offline`
and print a summary.
"""

from __future__ import annotations

from pathlib import Path

import click

from bnptrack.pipeline.cli.common import (
    FiniteRange,
    Choice,
    CONNECT_VIEW_HELP,
    END_HELP,
    SET_HELP_TRACK,
    START_HELP,
    VIEW_HELP,
    CliError,
    IncompleteError,
    LazyHelpOption,
    clean_errors,
    config_help,
    echo_rows,
    live_view,
    open_live,
    window_of,
    typed_window,
    check_window_holds,
    require_measurements,
    TOPIC_HELP,
    topic_map,
    tracker_help,
)
from bnptrack.pipeline.compile_notice import compile_progress
from bnptrack.pipeline.config import sink_outputs
from bnptrack.pipeline.cli.option_types import NAME, URL, PathName
from bnptrack.pipeline.cli.run_figures import RunFigures, figure_rows
from bnptrack.pipeline.offline import TrackResult, default_tracks_path, open_sinks, read_log_start, track_to_sinks
from bnptrack.pipeline.output_paths import (check_outputs, check_writable, refuse_existing, sink_option,
                                            view_command)
from bnptrack.pipeline.resolve import DEFAULT_PARAMS, TRACKERS, TrackerSetup, tracker_setup, window_overrides
from bnptrack.pipeline.stop_request import StopOnSignal
from bnptrack.sinks.sink import SINKS, SinkSet, check_sink_names
from bnptrack.sinks.records import SinkOptions
from bnptrack.sources.frame_window import FrameWindow
from bnptrack.sources.mcap_log import read_metadata
from bnptrack.sources.scenarios import OpenScenario, open_scenario, scenario_names
from bnptrack.tracker.input_checks import check_frames
from bnptrack.tracker.models.params import BUILTIN_PARAMS

__all__ = ["simulate", "track"]

_BUILTIN = " or ".join(BUILTIN_PARAMS)

_SET_HELP_SIM = (
    "Override one model parameter, KEY=VALUE (VALUE is a TOML literal), e.g. "
    "--set p_detect=0.9 --set clutter_rate=30; scene.KEY=VALUE sets a parameter of a "
    "generated scenario (random, random-cv, groups, groups-pl, groups-py), e.g. --set scene.n_objects=25 "
    "--set scene.crossing_pairs=3 (docs/models.md). Repeatable."
)


def _check_sinks(ctx: click.Context, param: click.Parameter, names: tuple[str, ...]) -> tuple[str, ...]:
    try:
        check_sink_names(names, "--sink")
    except ValueError as exc:
        raise click.BadParameter(str(exc).removeprefix("--sink: ")) from None
    return names


# --------------------------------------------------------------------------- simulate


@click.command()
@click.option(
    "--scenario",
    type=Choice(scenario_names()),
    default="vo2017",
    show_default=True,
    help="Ground-truth scenario (100 scans; see docs/models.md).",
)
@click.option(
    "--params",
    "params_arg",
    metavar="NAME|FILE.toml",
    type=NAME,
    default=DEFAULT_PARAMS,
    show_default=True,
    help=f"Model parameter set: built-in {_BUILTIN}, or a TOML file of ModelParams fields.",
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
    type=PathName(dir_okay=False, path_type=Path),
    default=None,
    help="Output MCAP file. Default: recordings/<scenario>-s<seed>.mcap (directory created).",
)
@click.option("--overwrite", is_flag=True, help="Replace --out if it exists (without it, an existing file is "
              "refused with exit code 2 before anything is simulated).")
@click.option("--quiet", "-q", is_flag=True, help="Do not print the summary.")
@clean_errors
def simulate(
    scenario: str,
    params_arg: str,
    overrides: tuple[str, ...],
    snr_db: float | None,
    seed: int,
    out: Path | None,
    overwrite: bool,
    quiet: bool,
) -> None:
    """Simulate a scenario and write its measurements and truth to an MCAP log.

    Writes one frame per scan (100 scans) on /measurements and /truth, and a
    bnptrack.scenario metadata record (scenario, params, seed, plus snr_db and overrides
    when used) so that `bnptrack track` can pick the same model parameters. The same
    seed gives the same frames and measurement counts on every machine; a bearing can
    differ in its last binary digit between CPUs (numpy's vectorised arctan2).

    \b
    Examples:
      bnptrack simulate --scenario vo2017 --params vo2017 --seed 1 --out recordings/vo2017-s1.mcap --overwrite
      bnptrack simulate --scenario snr --snr -10 --seed 3
      bnptrack simulate --scenario proximity --params paper --set clutter_rate=30 --seed 2
      bnptrack simulate --scenario random --seed 3 --set scene.n_objects=25
      bnptrack simulate --params examples/two_sensors.toml --seed 1 --out recordings/two.mcap   # one frame per sensor per scan

    The generated scenarios (random, random-cv, groups, groups-pl, groups-py) draw their scene
    from --seed too (the record then also holds scene_seed, the scene.* settings and the
    crossing pairs).
    """
    from bnptrack.pipeline.offline import simulate_to_log

    if out is None:
        out = Path("recordings") / f"{scenario}-s{seed}.mcap"
    check_writable(out, "--out", renamed=True)  # written beside it, then renamed onto it
    refuse_existing({"mcap": out}, overwrite)
    opened = open_scenario(scenario, params_arg, seed, overrides, snr_db)
    res = simulate_to_log(opened, seed, out)
    if not quiet:
        echo_rows(_simulate_rows(opened, params_arg, overrides, seed)
                  + [("frames", str(res.frames)),
                     ("measurements", f"{res.measurements} ({res.mean_measurements:.1f} per frame)"),
                     ("target-scans", str(res.target_scans)),
                     ("wrote", f"{res.path} ({res.size_bytes} bytes)")])


def _simulate_rows(opened: OpenScenario, params_arg: str, overrides: tuple[str, ...],
                   seed: int) -> list[tuple[str, str]]:
    """The scenario, scene, params and seed rows of ``simulate``'s summary."""
    scene, params = opened.scenario, opened.params
    extra = []
    if overrides:
        extra.append("overrides " + " ".join(overrides))
    if params.snr_db is not None:
        extra.append(f"snr_db {params.snr_db:g}")
    rows = [("scenario", f"{scene.name} ({scene.kind} sensor)")]
    if scene.seed is not None:
        pairs = ", ".join(f"{a}/{b}@{k}" for a, b, k in scene.crossings) or "none"
        rows.append(("scene", f"seed {scene.seed}: {len(scene.targets)} objects, "
                              f"crossing pairs {pairs}; no birth regions"))
    return rows + [("params", params_arg + (f" ({', '.join(extra)})" if extra else "")),
                   ("seed", str(seed))]


# --------------------------------------------------------------------------- track


@click.command()
@click.argument("log", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option(
    "--tracker",
    "tracker_name",
    type=Choice(TRACKERS),
    default="ddp",
    show_default=True,
    cls=LazyHelpOption,
    help_text=tracker_help,
)
@click.option(
    "--config",
    "config_arg",
    metavar="NAME|FILE.toml",
    type=NAME,
    default=None,
    cls=LazyHelpOption,
    help_text=config_help,
)
@click.option(
    "--params",
    "params_arg",
    metavar="NAME|FILE.toml",
    type=NAME,
    default=None,
    help=f"Model parameters ({', '.join(BUILTIN_PARAMS)} or a TOML file). Default: the set named in the "
    f"log's bnptrack.scenario record (with its snr_db and overrides), else {DEFAULT_PARAMS}.",
)
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=SET_HELP_TRACK)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Tracker random seed (frame k uses its own stream derived from seed and k).",
)
@click.option(
    "--out",
    type=PathName(dir_okay=False, path_type=Path),
    default=None,
    help="Output MCAP file (input frames + /tracks). Default: <LOG stem>-<tracker>.tracks.mcap "
    "next to LOG.",
)
@click.option(
    "--rrd",
    type=PathName(dir_okay=False, path_type=Path),
    default=None,
    metavar="FILE.rrd",
    help="Also record the run for the Rerun viewer (scene, assignments, tracks, truth, OSPA, "
    "diagnostics); open it with `bnptrack view FILE.rrd`. See docs/rerun.md.",
)
@click.option(
    "--max-frame-gap", type=click.IntRange(min=1), default=1000, show_default=True, metavar="N",
    help="A frame more than N frame numbers after the previous one is skipped, as is one that does "
    "not come after it (a corrupt frame number; the tracker predicts once over the time between "
    "stamps); the run goes on and exits 3 naming the skipped frames (docs/pipeline.md, \"Bad input\").",
)
@click.option(
    "--max-gap-s", type=FiniteRange(min=0, min_open=True), default=3600.0, show_default=True,
    metavar="SECONDS", help="Likewise for a time stamp more than SECONDS after the previous "
    "frame's, or before it.",
)
@click.option(
    "--resync-frames", type=click.IntRange(min=0), default=10, show_default=True, metavar="N",
    help="After N skipped frames in a row that are within the bounds of each other (a log that "
    "resumes after a long pause), accept the next such frame and go on from it. 0: never.",
)
@click.option("--topic", "topics", multiple=True, metavar="SRC[=/measurements]",
              help=TOPIC_HELP)
@click.option("--start", "start", metavar="T|Nf", default=None, help=START_HELP)
@click.option("--end", "end", metavar="T|Nf", default=None, help=END_HELP)
@click.option("--view", is_flag=True, help=VIEW_HELP + " Writes --rrd (default: the --out "
              "file with the suffix .rrd).")
@click.option("--connect", "view_connect", type=URL, metavar="URL", default=None, help=CONNECT_VIEW_HELP)
@click.option("--sink", "sink_names", multiple=True, metavar="NAME", callback=_check_sinks,
              help="Also record to the sink NAME of the table of sinks (sinks/sink.py), next to --out "
              "with its file suffix (--sink foxglove: a foxglove.SceneUpdate channel beside /tracks in --out); mcap "
              "(--out) and rerun (--rrd) are chosen by their own options. Repeatable.")
@click.option("--overwrite", is_flag=True, help="Replace output files that exist (without it, an existing --out, "
              "--rrd or --sink file is refused with exit code 2 before anything is read).")
@click.option("--lag", type=click.IntRange(min=0), default=0, show_default=True, metavar="N",
              help="Publish each frame N scans late, re-decided with the N scans that followed: births "
              "from the first detection, deaths at the last detection, broken tracks continued, states "
              "smoothed (docs/trackers.md, \"Fixed-lag output\"). 0: the online output.")
@click.option("--quiet", "-q", is_flag=True, help="Do not print the summary.")
@clean_errors
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
    resync_frames: int,
    topics: tuple[str, ...],
    start: str | None,
    end: str | None,
    view: bool,
    view_connect: str | None,
    sink_names: tuple[str, ...],
    overwrite: bool,
    lag: int,
    quiet: bool,
) -> None:
    """Run a tracker over an MCAP log offline and write its tracks.

    Reads the frames of LOG (/measurements with /truth when present), runs the tracker
    frame by frame and writes --out with the input frames, one /tracks message per frame
    and LOG's metadata record (plus tracker, tracker_seed, tracker_params,
    tracker_config). Prints the lines `launch` and `replay` print: mean OSPA (c=100 m, p=1),
    OSPA(2) and cardinality error with truth, the final tracks, the labels reported, the time
    per frame (with --lag: online step + lag layer).

    A truncated or corrupt LOG is processed up to its last readable frame; that prefix is
    written, then the error is reported and the exit code is 2. A frame that jumps beyond
    --max-frame-gap / --max-gap-s, or that does not come after the previous one, is skipped:
    the run goes on, the skipped frames are named and the exit code is 3 (as in `replay`).
    Ctrl-C or SIGTERM ends the run at the next frame as if the log ended (exit code 130).

    \b
    Examples:
      bnptrack track recordings/vo2017-s1.mcap --tracker ddp --out recordings/vo2017-ddp.mcap --rrd recordings/vo2017-ddp.rrd
      bnptrack track recordings/dpy5-s1.mcap --tracker dpyp --set tracker.sweeps=50
      bnptrack track recordings/snr-s1.mcap --config ddp-snr --params vo2017 --set snr_db=-5
      bnptrack track recordings/vo2017-s1.mcap --start 20s --end 40f   # as replay --start/--end
    """
    from bnptrack.tracker.types import FrameBounds

    window, overrides = _window(start, end, overrides)
    io = _TrackIO.open(log, out or default_tracks_path(log, tracker_name), rrd, topics, view, view_connect,
                       sink_names)
    check_window_holds(log, io.topics, window, typed_window(window, start, end))
    setup = tracker_setup(tracker_name, params=params_arg, config=config_arg, overrides=overrides,
                          metadata=read_metadata(log), seed=seed)
    io.refuse_existing(overwrite)  # every option checked first: a mistake is named before an existing file
    io.build()
    _header(log, setup, quiet)
    with compile_progress(tracker_name, quiet), StopOnSignal() as stop:
        res = io.run(setup, seed, FrameBounds(max_frame_gap, max_gap_s, resync_frames), window, lag, stop)
    if not quiet:
        echo_rows(_track_rows(res, tracker_name, seed, io.out, io.rrd, lag))
    _track_outcome(res, io.out, stop.signal_name if stop.cut_short else None)


def _track_outcome(res: TrackResult, out: Path, signal_name: str | None = None) -> None:
    """``track``'s error after the summary: a damaged log (exit 2), a stop by a signal (exit
    130: the frames tracked and written before it), or frames beyond the bounds skipped (exit
    3: how many, the first reasons)."""
    if res.error is not None:
        raise CliError(f"{res.error} -- processed and wrote the {res.n_frames} readable frame(s) to {out}")
    if signal_name is not None:
        last = f" (up to log frame {res.frames[-1].frame})" if res.frames else ""
        skipped = f"; {len(res.skipped)} frame(s) beyond the frame bounds skipped" if res.skipped else ""
        click.echo(f"Interrupted by {signal_name}: tracked and wrote {res.n_frames} frame(s){last}{skipped}; "
                   f"the outputs are complete files", err=True)
        raise SystemExit(130)
    if res.skipped:
        first = "; ".join(why for _, why in res.skipped[:3]) + ("; ..." if len(res.skipped) > 3 else "")
        raise IncompleteError(f"output incomplete: {len(res.skipped)} frame(s) beyond the frame bounds skipped "
                              f"({first}) -- wrote the other {res.n_frames} frame(s) to {out}")


def _header(log: Path, setup: TrackerSetup, quiet: bool) -> None:
    """What ``track`` says before it starts: a warning about the parameters, then (unless
    ``quiet``) the log, params and config lines."""
    if setup.choice.warning:
        click.echo(f"warning: {setup.choice.warning}", err=True)
    if not quiet:
        echo_rows([("log", str(log)), ("params", setup.describe_params()), ("config", setup.describe_config())])


class _TrackIO:
    """What ``track`` reads and writes: the log, its channel mapping, and the sinks the
    options choose (:func:`pipeline.config.sink_outputs`: ``--out`` the MCAP log, ``--rrd``
    the Rerun recording, ``--view`` / ``--connect`` streaming it live, ``--sink NAME`` more
    entries of :data:`sinks.sink.SINKS` next to ``--out``)."""

    def __init__(self, log: Path, outputs: dict[str, Path], topics: dict[str, str], live: str | None) -> None:
        self.log, self.outputs, self.topics, self.live = log, outputs, topics, live
        self.params = None
        self.sinks: SinkSet | None = None
        self.head: list = []  # the log's first frames (:func:`pipeline.offline.read_log_start`)

    @property
    def out(self) -> Path:
        return self.outputs["mcap"]

    @property
    def rrd(self) -> Path | None:
        return self.outputs.get("rerun")

    @classmethod
    def open(cls, log: Path, out: Path, rrd: Path | None, topics: tuple[str, ...], view: bool,
             view_connect: str | None, extra: tuple[str, ...]) -> _TrackIO:
        """Check the log and the options, and choose the sinks (files that exist already are
        refused by :meth:`refuse_existing`, once the tracker's settings are checked too)."""
        mapping = topic_map(topics)
        require_measurements(log, mapping)
        head = read_log_start(log, mapping)
        live = live_view(view, view_connect)
        if live is not None and rrd is None:
            rrd = out.with_suffix(".rrd")
        outputs = sink_outputs(out, rrd, extra, lambda name: out.with_suffix(Path(SINKS[name].filename).suffix))
        check_outputs(log, outputs)
        for name, path in outputs.items():
            check_writable(path, sink_option(name))
        io = cls(log, outputs, mapping, live)
        io.head = head
        return io

    def refuse_existing(self, overwrite: bool) -> None:
        """Refuse output files that exist unless ``overwrite`` (:func:`pipeline.output_paths.refuse_existing`)."""
        refuse_existing(self.outputs, overwrite)

    def build(self) -> None:
        """Build the sinks now, before the tracker runs: a sink that starts work at once does it
        beside the tracker's first step, which loads or compiles its kernels (the Rerun
        recording's child process imports rerun on the other core, :mod:`sinks.rerun_process`).  The command's context closes them at the
        end whatever happens (:meth:`run` closes them first, normally)."""
        options = SinkOptions(self.out, params=lambda: self.params, live=self._live_url, process=True,
                              source=str(self.log))
        self.sinks = click.get_current_context().with_resource(open_sinks(self.outputs, options))

    def _live_url(self) -> str | None:
        return open_live(self.live) if self.live is not None else None

    def run(self, setup: TrackerSetup, seed: int, bounds, window: FrameWindow, lag: int = 0,
            stop: StopOnSignal | None = None) -> TrackResult:
        """Track the log's frames of ``window`` with ``setup``'s tracker and record them to the
        sinks (up to a signal held by ``stop``)."""
        check_frames(setup.params, self.head, setup.choice.source, setup.set_sensors)  # a misspelt sensor: an error before tracking
        self.params = setup.params
        return track_to_sinks(self.log, self.sinks, setup.tracker, seed, setup.metadata, bounds, self.topics,
                              window, lag, stop)


def _window(start: str | None, end: str | None, overrides: tuple[str, ...]) -> tuple[FrameWindow, tuple[str, ...]]:
    """``--start`` / ``--end`` and the ``source.KEY`` items of ``--set`` (the window of ``replay``),
    and the other ``--set`` items."""
    return window_overrides(overrides, window_of(start, end))


def _track_rows(res: TrackResult, tracker_name: str, seed: int, out: Path,
                rrd: Path | None, lag: int = 0) -> list[tuple[str, str]]:
    """The summary rows of ``track``: the run, the figures every run's summary prints
    (:func:`pipeline.cli.run_figures.figure_rows`), crossings kept (a log with crossings),
    files."""
    rows = [("tracker", f"{tracker_name} (seed {seed})"), ("frames", str(res.n_frames))]
    rows += figure_rows(RunFigures.of_track(res, lag))
    if res.crossings is not None:
        kept = sum(p.kept for p in res.crossings.pairs)
        rows.append(("crossings kept", f"{kept}/{len(res.crossings.pairs)} pairs keep both "
                     "labels (scan c-5 vs c+5, gate 100 m)"))
    rows.append(("wrote", f"{out} ({out.stat().st_size} bytes)"))
    if rrd is not None:
        rows.append(("recording", f"{rrd} ({rrd.stat().st_size} bytes; {view_command(rrd)})"))
    return rows
