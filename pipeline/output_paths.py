"""Checks of a run's output files before anything is written: an output that is the input log
(:func:`check_output_path`), outputs that would overwrite one another (:func:`check_outputs`),
and files that exist already (:func:`refuse_existing`, unless ``--overwrite``); and the commands
printed for an output (:func:`view_command`: paths shell-quoted, so that they can be pasted)."""

from __future__ import annotations

import os
import shlex
from collections.abc import Mapping
from pathlib import Path

from bnptrack.tracker.config import ConfigError

__all__ = ["check_output_path", "check_outputs", "refuse_existing", "sink_option", "view_command"]


def check_output_path(log: str | os.PathLike, out: str | os.PathLike, option: str = "--out") -> None:
    """Refuse an output path (given as ``option``) that is the input log itself."""
    if Path(out).resolve() == Path(log).resolve():
        raise ConfigError(f"{option} {out}: the output would overwrite the input log {log}")


def sink_option(name: str) -> str:
    """The option of ``track`` that chose the sink ``name``'s file: ``--out`` (the MCAP log),
    ``--rrd`` (the Rerun recording), else ``--sink NAME`` (a file next to ``--out``)."""
    return {"mcap": "--out", "rerun": "--rrd"}.get(name, f"--sink {name}")


def refuse_existing(outputs: Mapping[str, Path], overwrite: bool, option: str = "--out") -> None:
    """Refuse output files that exist already (a finished run would be replaced by this one,
    complete or not) unless ``overwrite``; the error suggests another ``option`` (``--rrd`` for
    the ``rerun`` output)."""
    if overwrite:
        return
    taken = {name: str(p) for name, p in outputs.items() if Path(p).exists()}
    if taken:
        files = sorted(set(taken.values()))
        which = files[0] if len(files) == 1 else f"{', '.join(files[:-1])} and {files[-1]}"
        options = " or ".join(sorted({"--rrd" if name == "rerun" else option for name in taken}))
        raise ConfigError(f"{which} exist{'s' if len(files) == 1 else ''}: give --overwrite to replace "
                          f"{'it' if len(files) == 1 else 'them'}, or another {options}")


def check_outputs(log: str | os.PathLike, outputs: Mapping[str, Path]) -> None:
    """Refuse outputs (sink name -> file) that overwrite the input log or one another, naming
    the options that chose them (:func:`sink_option`)."""
    from bnptrack.sinks.sink import SINKS

    seen: dict[Path, str] = {}
    for name, path in outputs.items():
        check_output_path(log, path, sink_option(name))
        other = seen.setdefault(Path(path).resolve(), name)
        entry = SINKS.get(name)
        if other != name and not (entry is not None and entry.beside == other):
            raise ConfigError(f"{sink_option(name)} {path}: the same file as {sink_option(other)}; "
                              "give each output its own name")


def view_command(rrd: str | os.PathLike) -> str:
    """``bnptrack view RRD``, the path shell-quoted (a path with a space or a quote pastes as one
    argument)."""
    return f"bnptrack view {shlex.quote(str(rrd))}"
