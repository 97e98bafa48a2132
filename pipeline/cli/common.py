"""What every ``bnptrack`` command shares: error handling (one line on stderr, exit code 2),
summary rows, option help texts and option choices derived from the registries.

Expected failures (bad configuration, missing or damaged files, invalid messages) become a
one-line ``Error: ...`` on stderr and exit code 2; set ``BNPTRACK_DEBUG=1`` to get the
traceback instead.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import sys
import typing
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from bnptrack.tracker.messages import CodecError
from bnptrack.sources.mcap_log import McapLogError
from bnptrack.tracker.config import ConfigError, did_you_mean

if TYPE_CHECKING:
    from bnptrack.sources.frame_window import FrameWindow

__all__ = [
    "EXIT_ERROR",
    "EXIT_INCOMPLETE",
    "CliError",
    "Choice",
    "IncompleteError",
    "clean_errors",
    "echo_rows",
    "fmt",
    "LazyHelpOption",
    "literal_choices",
    "TOPIC_HELP",
    "topic_map",
    "require_measurements",
    "live_view",
    "one_viewer",
    "open_live",
    "parse_offset",
    "typed_window",
    "check_window_holds",
    "START_HELP",
    "END_HELP",
]

#: Exit code of every reported (non-crash) failure.
EXIT_ERROR = 2
#: Exit code of a pipeline run that ended with an incomplete output (gaps, rejected frames,
#: a stage that gave up); see docs/pipeline.md.
EXIT_INCOMPLETE = 3


class Choice(click.Choice):
    """:class:`click.Choice` whose error for a value not among the choices adds the closest
    one (``'ddpp' is not one of ... (did you mean 'ddp'?)``)."""

    def get_invalid_choice_message(self, value: Any, ctx: click.Context | None) -> str:
        message = super().get_invalid_choice_message(value, ctx)
        hint = did_you_mean(str(value), [str(c) for c in self.choices], cutoff=0.5)
        return f"{message.rstrip('.')}{hint}" if hint else message


class FiniteRange(click.FloatRange):
    """:class:`click.FloatRange` that also refuses ``inf`` and ``nan`` (which compare as in
    range or not at all)."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


def checked_endpoints(ctx: click.Context, param: click.Parameter, values: tuple[str, ...]) -> tuple[str, ...]:
    """Callback of an ENDPOINT option (``--connect``, ``--listen``): each a Zenoh endpoint
    (:func:`pipeline.config.check_endpoint`), else a usage error naming it."""
    check_option_endpoints(values, param=param, ctx=ctx)
    return values


def check_option_endpoints(values: Iterable[str], hint: str | None = None, param: click.Parameter | None = None,
                           ctx: click.Context | None = None) -> None:
    """Each of ``values`` is a Zenoh endpoint (:func:`pipeline.endpoints.check_endpoint`), else
    a usage error naming the option (``param``, or ``hint`` such as ``'--connect'``)."""
    from bnptrack.pipeline.endpoints import check_endpoint

    for value in values:
        try:
            check_endpoint(value, "")
        except ValueError as exc:
            raise click.BadParameter(str(exc).strip(), ctx, param, param_hint=hint) from None


class InternalError(click.ClickException):
    """A failure inside bnptrack, not a user's mistake: one line, exit code 1."""

    exit_code = 1


class CliError(click.ClickException):
    """A failure reported as one line on stderr, exit code 2."""

    exit_code = EXIT_ERROR

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


class IncompleteError(CliError):
    """``launch`` / ``replay``: the run ended but its output is incomplete (exit code 3)."""

    exit_code = EXIT_INCOMPLETE


def _expected() -> tuple[type[Exception], ...]:
    """The failures a command reports on one line.  The viewer's and the recording's errors
    are imported here, at a failure: most commands never load those modules."""
    from bnptrack.pipeline.view import ViewerUnavailable
    from bnptrack.sinks.rerun_process import RecordingError

    return (ConfigError, CodecError, McapLogError, OSError, ValueError, RecordingError, ViewerUnavailable)


def clean_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the expected exceptions of a command into :class:`CliError`."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            with one_line_warnings():
                return fn(*args, **kwargs)
        except click.ClickException:
            raise
        except BrokenPipeError:  # e.g. `bnptrack schema /tracks | head`: stop quietly
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            raise SystemExit(141) from None
        except Exception as exc:
            known = isinstance(exc, (_expected(), MemoryError)) or _numerical(exc)
            if not known or os.environ.get("BNPTRACK_DEBUG"):
                raise
            if isinstance(exc, MemoryError):
                raise InternalError(f"out of memory ({exc or type(exc).__name__}): a setting far beyond what the "
                                    "scene needs (e.g. clutter_rate, sweeps, scene.n_objects) asks for more than "
                                    "this machine has") from exc
            if _numerical(exc):
                raise InternalError(f"numerical failure inside bnptrack ({type(exc).__name__}: {exc}); "
                                    "BNPTRACK_DEBUG=1 shows the traceback: please report it with the command") from exc
            raise CliError(_describe(exc)) from exc

    return wrapper


@contextlib.contextmanager
def one_line_warnings() -> Iterator[None]:
    """Print each :class:`tracker.input_checks.InputWarning` raised meanwhile as one line on
    stderr (``warning: ...``; each distinct message once); other warnings as Python shows them."""
    from bnptrack.tracker.input_checks import InputWarning

    shown: set[str] = set()
    with warnings.catch_warnings():
        warnings.simplefilter("always", InputWarning)
        show = warnings.showwarning

        def one_line(message: Any, category: type, *rest: Any, **kw: Any) -> None:
            if not issubclass(category, InputWarning):
                show(message, category, *rest, **kw)
            elif str(message) not in shown:
                shown.add(str(message))
                click.echo(f"warning: {message}", err=True)

        warnings.showwarning = one_line
        yield


def _numerical(exc: BaseException) -> bool:
    """A failure of bnptrack's own numerics (numpy's ``LinAlgError``, an overflow), not a
    mistake of the user's: reported as an internal error."""
    if isinstance(exc, (FloatingPointError, OverflowError)):
        return True
    np = sys.modules.get("numpy")
    return np is not None and isinstance(exc, np.linalg.LinAlgError)


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    return str(exc)


_KEY_WIDTH = 16


def rows_text(rows: list[tuple[str, str]]) -> str:
    """``key  value`` summary rows, one a line, keys left-aligned in one column (as wide as
    the longest key, at least 16 characters) so the values line up."""
    width = max([_KEY_WIDTH, *(len(key) for key, _ in rows)])
    return "\n".join(f"{key:<{width}}  {value}" for key, value in rows)


def echo_rows(rows: list[tuple[str, str]]) -> None:
    """Print :func:`rows_text`."""
    if rows:
        click.echo(rows_text(rows))


def fmt(value: float | None, spec: str = ".2f") -> str:
    return "n/a" if value is None else format(value, spec)


# --------------------------------------------------------------------------- help texts

VIEW_HELP = (
    "Watch the run live: start a Rerun viewer and stream the recording to it while it is "
    "written (the viewer stays open after the run; needs a display)."
)
CONNECT_VIEW_HELP = (
    "Stream the recording live to a Rerun viewer that is already running, e.g. on another host "
    "(`rerun` there, then --connect rerun+http://HOST:9876/proxy; a port N means "
    "rerun+http://127.0.0.1:N/proxy)."
)
TOPIC_HELP = (
    "Read channel SRC: a ROS 2 or Foxglove channel by its name, the kind from its schema (e.g. "
    "--topic /radar/scan; `bnptrack info LOG` lists the trackable ones; several topics: several "
    "sensors), or a bnptrack JSON channel as /measurements (or /truth), e.g. "
    "--topic /radar/detections=/measurements. Repeatable."
)
SET_HELP_TRACK = (
    "Override a setting, KEY=VALUE (VALUE is a TOML literal). params.KEY goes to the model "
    "parameters, tracker.KEY to the tracker settings; a bare KEY goes to whichever has it "
    "(model parameters first). source.KEY selects frames as in replay: source.frames=N (the first N), "
    "source.start_s / end_s / start_frame / end_frame (= --start / --end). Repeatable."
)
SET_HELP_PIPE = (
    "Override a setting, KEY=VALUE (VALUE is a TOML literal). source.KEY, sink.KEY, delivery.KEY, "
    "zenoh.KEY and tracker.KEY of the tracker stage (tracker, config, params, seed, ...) are keys "
    "of the pipeline file; params.KEY, tracker.KEY of the tracker's settings and a bare KEY mean "
    "what they mean in `bnptrack track` (a bare KEY: model parameters first, then tracker "
    "settings), e.g. --set source.frames=20 --set tracker.seed=3 --set tracker.sweeps=10 "
    "--set p_detect=0.9. Repeatable."
)
SET_HELP_ZENOH = (
    "Override a key of the pipeline file, KEY=VALUE (VALUE is a TOML literal). Only its "
    "zenoh.KEY settings (tls.*, user, password, users_file, acl, ...) act "
    "on this command, e.g. --set zenoh.acl=true --set zenoh.users_file=users.txt. Repeatable."
)


# --------------------------------------------------------------------------- registry-derived


class LazyHelpOption(click.Option):
    """An option whose help text is computed when help is shown: texts drawn from the
    tracker registry import every tracker (numba), which no command should pay for."""

    def __init__(self, param_decls: list[str], *, help_text: Callable[[], str], **attrs: Any) -> None:
        super().__init__(param_decls, **attrs)
        self._help_text = help_text

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        self.help = self._help_text()
        return super().get_help_record(ctx)


def tracker_help() -> str:
    """``--tracker``: every tracker of :mod:`tracker.registry` with its description."""
    from bnptrack.tracker.registry import TRACKERS, kind

    return "; ".join(f"{name} = {kind(name).description}" for name in TRACKERS) + "."


def config_help() -> str:
    """``--config``: the presets of every tracker of :mod:`tracker.registry`."""
    from bnptrack.tracker.registry import TRACKERS, kind

    kinds = [kind(name) for name in TRACKERS]
    presets = ", ".join(dict.fromkeys(p for k in kinds for p in k.presets))
    classes = ", ".join(dict.fromkeys(k.config_cls.__name__ for k in kinds))
    return (f"Tracker settings: a preset name of the tracker ({presets}) or a TOML file of the "
            f"tracker's settings fields ({classes}). Default: the preset named like --tracker.")


def literal_choices(struct: type, field: str, element: bool = False) -> list[str]:
    """The values of the ``Literal`` annotation of ``struct.field`` (``element``: of a list's
    elements), e.g. the pipeline's stage roles from :class:`PipelineConfig`."""
    hint = typing.get_type_hints(struct)[field]
    if element:
        hint = typing.get_args(hint)[0]
    return [str(v) for v in typing.get_args(hint)]


# --------------------------------------------------------------------------- shared option logic


def topic_map(items: tuple[str, ...]) -> dict[str, str]:
    """``--topic SRC=/measurements`` items as ``{SRC: /measurements}`` (the pipeline's
    ``source.topics``; :func:`pipeline.config.parse_topic_item` checks each)."""
    from bnptrack.pipeline.config import parse_topic_item

    out = {}
    for item in items:
        try:
            src, dst = parse_topic_item(item)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--topic") from None
        out[src] = dst
    return out


def require_measurements(log: Path, topics: dict[str, str]) -> None:
    """Exit 2 listing the log's channels when none is (or is mapped to) /measurements, and
    listing its trackable channels when a ``--topic`` names a channel of a type bnptrack
    cannot read (:func:`sources.robot_log.robot_topics`), before anything is tracked."""
    from bnptrack.tracker.messages import TOPIC_MEASUREMENTS
    from bnptrack.sources.mcap_log import missing_measurements_message
    from bnptrack.sources.channels import channel_list
    from bnptrack.sources.robot_log import robot_topics

    channels = channel_list(log)
    try:
        robot_topics(log, topics, channels)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if not any(topics.get(c.topic, c.topic) == TOPIC_MEASUREMENTS for c in channels):
        raise CliError(missing_measurements_message(log, channels))


def one_viewer(view: bool, connect: str | None) -> None:
    """``--view`` and ``--connect URL`` exclude each other (a usage error)."""
    if view and connect:
        raise click.UsageError("--view starts a viewer, --connect URL uses a running one: give one of them")


def live_view(view: bool, connect: str | None) -> str | None:
    """``"spawn"`` (``--view``; checked now: a display and the ``rerun`` CLI, so that a
    command fails before it opens its outputs), a viewer URL (``--connect``; checked now: a
    viewer must be listening there) or None."""
    one_viewer(view, connect)
    if connect:
        from bnptrack.pipeline.live import check_viewer

        return check_viewer(connect)
    if not view:
        return None
    from bnptrack.pipeline.live import viewer_command

    viewer_command()  # no display or no rerun CLI: say so now, before any file is opened
    return "spawn"


def open_live(live: str) -> str:
    """The URL to stream to: ``live``, or that of a viewer started now (``"spawn"``)."""
    if live != "spawn":
        return live
    from bnptrack.pipeline.live import spawn_viewer

    viewer = spawn_viewer()
    click.echo(f"viewer: {viewer.url} (pid {viewer.pid}; it stays open after the run)", err=True)
    return viewer.url


#: ``--start`` / ``--end`` of ``replay`` and ``track`` (:class:`sources.frame_window.FrameWindow`).
START_HELP = ("Start at T seconds of log time after the first frame (12.5 or 12.5s), or at frame number "
              "N (40f).")
END_HELP = "End at T seconds of log time after the first frame, or at frame N (both included)."


def window_of(start: str | None, end: str | None) -> FrameWindow:
    """The frame window of ``--start`` / ``--end`` (:func:`parse_offset` each), checked: an end
    before the start is a usage error naming both options as typed."""
    from bnptrack.sources.frame_window import FrameWindow

    start_s, start_frame = parse_offset(start, "--start")
    end_s, end_frame = parse_offset(end, "--end")
    window = FrameWindow(start_s=start_s, start_frame=start_frame, end_s=end_s, end_frame=end_frame)
    try:
        window.check()
    except ValueError:  # the options cannot mix units at one end: the end is before the start
        raise click.BadParameter(f"{end!r} is before --start {start!r}", param_hint="--end") from None
    return window


def check_window_holds(log: Path, topics: dict[str, str], window: FrameWindow, typed: dict[str, str]) -> None:
    """``track`` / ``replay``: a window that holds none of the log's frames is an error before
    anything is written, naming ``--start`` / ``--end`` as typed (:func:`typed_window`)."""
    from bnptrack.sources.frame_window import FrameWindow
    from bnptrack.sources.mcap_log import iter_frames

    if window != FrameWindow():
        try:
            window.check_not_empty(iter_frames(log, topics), str(log), typed=typed)
        except ValueError as exc:
            raise CliError(str(exc)) from None


def typed_window(window: FrameWindow, start: str | None, end: str | None) -> dict[str, str]:
    """The keys of ``window`` that ``--start`` / ``--end`` set, each as the option was typed
    (``{"start_s": "--start 200s"}``), for errors about the window
    (:meth:`sources.frame_window.FrameWindow.describe`); a key a ``--set source.KEY`` item
    changed afterwards is left out."""
    typed = {}
    for text, opt in ((start, "--start"), (end, "--end")):
        seconds, frame = parse_offset(text, opt)
        key, value = (f"{opt[2:]}_s", seconds) if frame is None else (f"{opt[2:]}_frame", frame)
        if text is not None and getattr(window, key) == value:
            typed[key] = f"{opt} {text}"
    return typed


def parse_offset(text: str | None, opt: str) -> tuple[float | None, int | None]:
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
