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
    resolve_simulation_params,
    simulate_to_log,
    split_overrides,
    track_log,
)
from sources.mcap_log import McapLogError, read_metadata
from sources.scenarios import get_scenario, scenario_names
from tracker.config import ConfigError

__all__ = ["main", "CliError"]

#: Exit code of every reported (non-crash) failure.
EXIT_ERROR = 2


class CliError(click.ClickException):
    """A failure reported as one line on stderr, exit code 2."""

    exit_code = EXIT_ERROR

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


_EXPECTED = (ConfigError, CodecError, McapLogError, OSError, ValueError)


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


_SET_HELP_SIM = (
    "Override one model parameter, KEY=VALUE (VALUE is a TOML literal), e.g. "
    "--set p_detect=0.9 --set clutter_rate=30. Repeatable."
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
    """
    params = resolve_simulation_params(scenario, params_arg, overrides, snr_db)
    if out is None:
        out = Path("recordings") / f"{scenario}-s{seed}.mcap"
    metadata = {"scenario": scenario, "params": params_arg, "seed": str(seed)}
    if params.snr_db is not None:
        metadata["snr_db"] = repr(float(params.snr_db))
    if overrides:
        metadata["overrides"] = format_overrides(overrides)
    res = simulate_to_log(scenario, params, seed, out, metadata)
    if quiet:
        return
    extra = []
    if overrides:
        extra.append("overrides " + " ".join(overrides))
    if params.snr_db is not None:
        extra.append(f"snr_db {params.snr_db:g}")
    _echo_rows(
        [
            ("scenario", f"{scenario} ({get_scenario(scenario).kind} sensor)"),
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
    help="ddp = DDP-EMM, dpyp = DPY-STP.",
)
@click.option(
    "--config",
    "config_arg",
    metavar="NAME|FILE.toml",
    default=None,
    help="Tracker settings: a preset name (ddp, dpyp, ddp-proximity, ddp-snr, ...: "
    "tracker.bnp_tracker.TRACKER_PRESETS) or a TOML file of BnpConfig fields. "
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
    quiet: bool,
) -> None:
    """Run a tracker over an MCAP log offline and write its tracks.

    Reads the frames of LOG (/measurements with /truth when present), runs the tracker
    frame by frame and writes --out with the input frames, one /tracks message per frame
    and LOG's metadata record (plus tracker, tracker_seed, tracker_params,
    tracker_config). Prints mean OSPA (c=100 m, p=1, on position) and mean cardinality
    error when the log has truth, the final number of tracks and the time per frame.

    A truncated or corrupt LOG is processed up to its last readable frame; that prefix is
    written, then the error is reported and the exit code is 2.

    \b
    Examples:
      bnptrack track recordings/vo2017-s1.mcap --tracker ddp --out recordings/vo2017-s1-ddp.mcap
      bnptrack track recordings/dpy5-s1.mcap --tracker dpyp --set tracker.sweeps=50
      bnptrack track recordings/snr-s1.mcap --config ddp-snr --params vo2017 --set snr_db=-5
    """
    metadata = read_metadata(log)
    choice = resolve_params(params_arg, metadata)
    config, config_desc = resolve_config(tracker_name, config_arg)
    params, config = apply_split_overrides(choice.params, config, overrides)
    tracker = build_tracker(tracker_name, params, config)
    if out is None:
        out = default_tracks_path(log, tracker_name)
    check_output_path(log, out)

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
        p_over, t_over = split_overrides(overrides)
        _echo_rows(
            [
                ("log", str(log)),
                ("params", choice.describe(params, p_over)),
                ("config", config_desc + (f"; --set {' '.join(t_over)}" if t_over else "")),
            ]
        )
    res = track_log(log, out, tracker, seed, out_meta)
    if not quiet:
        rows = [("tracker", f"{tracker_name} (seed {seed})"), ("frames", str(res.n_frames))]
        if res.has_truth:
            rows.append(
                ("mean OSPA", f"{_fmt(res.mean_ospa)} m (c={OSPA_C:g}, p={OSPA_P:g}, position)")
            )
            rows.append(("mean card. error", _fmt(res.mean_cardinality_error)))
        else:
            rows.append(("mean OSPA", "n/a (the log has no /truth)"))
        rows += [
            ("final tracks", str(res.final_tracks)),
            ("ms per frame", f"median {_fmt(res.ms_median)}, p95 {_fmt(res.ms_p95)}"),
            ("wrote", f"{out} ({out.stat().st_size} bytes)"),
        ]
        _echo_rows(rows)
    if res.error is not None:
        raise CliError(
            f"{res.error} -- processed and wrote the {res.n_frames} readable frame(s) to {out}"
        )


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


if __name__ == "__main__":  # pragma: no cover
    main()
