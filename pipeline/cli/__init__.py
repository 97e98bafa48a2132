"""The ``bnptrack`` command line (``bnptrack = "bnptrack.pipeline.cli:main"``; also ``python -m bnptrack``).

Subcommands are thin: they parse options, call the library and print a summary.

\b
- :mod:`pipeline.cli.common`: error handling (one line, exit code 2), summary rows, shared
  option texts and registry-derived choices;
- :mod:`pipeline.cli.option_types`: the types of the options that name something (an empty
  value refused);
- :mod:`pipeline.cli.offline_commands`: ``simulate``, ``track``;
- :mod:`pipeline.cli.tools`: ``info``, ``export``, ``view``, ``experiment``, ``schema``;
- :mod:`pipeline.cli.pipeline_commands`: ``launch``, ``replay``, ``stage``, ``router``;
- :mod:`pipeline.cli.monitor`: ``monitor``.
"""

from __future__ import annotations

import atexit
import importlib
import os
import sys
import threading
from collections.abc import Iterator, MutableMapping
from gettext import gettext as _
from typing import Any

import click

__all__ = ["main", "CliError", "IncompleteError", "EXIT_ERROR", "EXIT_INCOMPLETE"]

#: Each command: the module that defines it and the first paragraph of its help (what
#: ``bnptrack --help`` lists; ``tests/pipeline/test_cli_startup.py`` checks it against the
#: command's docstring).  A command's module is imported only when the command is looked up,
#: so ``bnptrack --help`` imports no tracker, numpy or codec, and ``bnptrack track`` only the
#: offline commands (docs/performance.md, start-up).
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("bnptrack.pipeline.cli.offline_commands",
                 "Simulate a scenario and write its measurements and truth to an MCAP log."),
    "track": ("bnptrack.pipeline.cli.offline_commands", "Run a tracker over an MCAP log offline and write its tracks."),
    "info": ("bnptrack.pipeline.cli.tools", "Describe an MCAP log: channels, frames, sensors, time, and its record."),
    "export": ("bnptrack.pipeline.cli.tools", "Export a run's tracks (the output of `track`) as a table."),
    "view": ("bnptrack.pipeline.cli.tools", "Open a Rerun recording (.rrd) in the Rerun viewer, or render it to a PNG."),
    "experiment": ("bnptrack.pipeline.cli.tools", "Run one of the paper's simulation experiments as a Monte Carlo study."),
    "schema": ("bnptrack.pipeline.cli.tools", "Print the JSON Schema of a channel's messages."),
    "launch": ("bnptrack.pipeline.cli.pipeline_commands",
               "Run the streaming pipeline: every stage in its own process, linked by Zenoh."),
    "replay": ("bnptrack.pipeline.cli.pipeline_commands", "Replay an MCAP measurement log through the streaming pipeline."),
    "stage": ("bnptrack.pipeline.cli.pipeline_commands",
              "Run one pipeline stage in this process (to place stages on different hosts)."),
    "router": ("bnptrack.pipeline.cli.pipeline_commands",
               "Run a Zenoh router for pipeline stages on several hosts (until Ctrl-C)."),
    "monitor": ("bnptrack.pipeline.cli.monitor",
                "Watch a run's stages: liveliness, health counters, dead letters, end of stream."),
}


class _LazyCommands(MutableMapping):
    """``main.commands``: every name of :data:`COMMANDS`; a command's module is imported on
    first access (``main.commands["track"]``); ``add_command`` adds eager ones."""

    def __init__(self) -> None:
        self._loaded: dict[str, click.Command] = {}

    def __getitem__(self, name: str) -> click.Command:
        if name not in self._loaded:
            if name not in COMMANDS:
                raise KeyError(name)
            self._loaded[name] = getattr(importlib.import_module(COMMANDS[name][0]), name)
        return self._loaded[name]

    def __setitem__(self, name: str, cmd: click.Command) -> None:
        self._loaded[name] = cmd

    def __delitem__(self, name: str) -> None:
        raise TypeError("bnptrack's commands cannot be removed")

    def __iter__(self) -> Iterator[str]:
        return iter(dict.fromkeys([*COMMANDS, *self._loaded]))

    def __len__(self) -> int:
        return len(set(COMMANDS) | set(self._loaded))


#: Commands whose process, run as ``bnptrack`` / ``python -m bnptrack``, ends with
#: :func:`exit_now` once the command is done (files closed, exit handlers run): the
#: interpreter's teardown of what they loaded (numba and LLVM, scipy, Zenoh, Rerun) cost
#: ``track`` about 0.2 s of CPU, and a pipeline stage 0.4-1.6 s between its last log line and
#: its exit under load (docs/performance.md, start-up).
FAST_EXIT = frozenset({"track", "launch", "replay", "stage"})


def exit_now(code: object) -> None:
    """End the process as the interpreter would at exit with ``code`` (``SystemExit``'s
    rules), less the teardown of the modules: wait for the non-daemon threads, run the
    ``atexit`` handlers (logging's flush, Rerun's), flush stdout and stderr, ``os._exit``."""
    for t in threading.enumerate():
        if t is not threading.main_thread() and not t.daemon:
            t.join()
    if code is not None and not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(code or 0)


def one_line_usage_error(exc: click.UsageError) -> click.UsageError:
    """``exc`` printed as one line ``Error: ...`` (exit code 2), without click's usage and
    ``Try ... --help`` lines."""
    return click.UsageError(" ".join(exc.format_message().split()))


def _command_name(argv: list[str]) -> str:
    """The command of a ``bnptrack`` command line (its first word that is no option)."""
    return next((a for a in argv if not a.startswith("-")), "")


class _LazyGroup(click.Group):
    """A group whose listing (``bnptrack --help``) uses :data:`COMMANDS`' help paragraphs, so
    that it imports no command module; every other use loads the command itself.  Run as the
    process's command line (no ``args`` given: not a test's ``CliRunner``), a command of
    :data:`FAST_EXIT` ends the process with :func:`exit_now`, and its numba leaves out the
    optional yaml and cffi support (``tracker.numerics.LEAN_NUMBA``: the process runs no
    numba code but the project's kernels)."""

    def main(self, args: Any = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:
        if args is not None or not standalone_mode or _command_name(sys.argv[1:]) not in FAST_EXIT:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        from bnptrack.tracker import numerics

        numerics.LEAN_NUMBA = True
        try:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        except SystemExit as exc:
            exit_now(exc.code)

    def make_context(self, info_name: str | None, args: list[str], parent: click.Context | None = None,
                     **extra: Any) -> click.Context:
        try:
            return super().make_context(info_name, args, parent, **extra)
        except click.UsageError as exc:
            raise one_line_usage_error(exc) from None

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:
            raise one_line_usage_error(exc) from None

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        names = self.list_commands(ctx)
        limit = formatter.width - 6 - max(len(n) for n in names)
        rows = []
        for name in names:
            loaded = self.commands._loaded.get(name)
            cmd = loaded if loaded is not None else click.Command(name, help=COMMANDS[name][1])
            if not cmd.hidden:
                rows.append((name, cmd.get_short_help_str(limit)))
        with formatter.section(_("Commands")):
            formatter.write_dl(rows)


@click.group(cls=_LazyGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="bnptrack", prog_name="bnptrack")
def main() -> None:
    """bnptrack: streaming multi-object tracking with Bayesian nonparametric priors.

    Simulate the paper's scenarios into MCAP logs and run the two-level DDP-EMM (ddp) or
    DPY-STP (dpyp) tracker, their single-level ddp-mb / dpyp-mb or the GLMB over a log offline. Logs hold /measurements, /truth and /tracks as
    JSON messages (see docs/formats.md and `bnptrack schema`).

    \b
    Example:
      bnptrack simulate --scenario vo2017 --params vo2017 --seed 1 --out recordings/vo2017-s1.mcap --overwrite
      bnptrack track recordings/vo2017-s1.mcap --tracker ddp --out recordings/vo2017-ddp.mcap --rrd recordings/vo2017-ddp.rrd
      bnptrack schema /tracks

    Errors are reported on one line with exit code 2 (BNPTRACK_DEBUG=1 shows the traceback).
    """


main.commands = _LazyCommands()


def __getattr__(name: str) -> Any:
    """``CliError``, ``IncompleteError``, ``EXIT_ERROR``, ``EXIT_INCOMPLETE`` from
    :mod:`pipeline.cli.common`, imported on first use (it imports the codec and numpy)."""
    if name in ("CliError", "IncompleteError", "EXIT_ERROR", "EXIT_INCOMPLETE"):
        from bnptrack.pipeline.cli import common

        return getattr(common, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if __name__ == "__main__":  # pragma: no cover
    main()
