"""Checks of a run's output files before anything is written: a place where no file can be
written (:func:`check_writable`), an output that is the input log (:func:`check_output_path`), outputs that would overwrite one another (:func:`check_outputs`),
and files that exist already (:func:`refuse_existing`, unless ``--overwrite``); and the commands
printed for an output (:func:`view_command`: paths shell-quoted, so that they can be pasted)."""

from __future__ import annotations

import os
import shlex
import tempfile
from collections.abc import Mapping
from pathlib import Path

from bnptrack.tracker.config import ConfigError

__all__ = ["check_writable", "check_output_path", "check_outputs", "refuse_existing", "sink_option", "view_command"]


def check_writable(path: str | os.PathLike, option: str, folder: bool = False, renamed: bool = False) -> None:
    """Refuse, naming ``option`` as typed, an output ``path`` (a file; ``folder``: a folder the
    run creates or fills) that cannot be written: a folder where a file is wanted or the
    reverse, a parent that is a file, a folder where no file can be created (read-only, ``/proc``).
    An existing file the run may write (``/dev/null``, a file in a read-only folder) passes,
    unless the run writes beside it and renames onto it (``renamed``): then only a regular file
    does (a rename would put a file in a device's place).  Checked by creating an unnamed file in
    the nearest existing folder, which leaves nothing behind."""
    path = Path(path)
    if path.exists() and path.is_dir() != folder:
        raise ConfigError(f"{option} {path}: " + ("a file, not a folder" if folder else "a folder, not a file"))
    if not folder and path.exists():
        if renamed and not path.is_file():
            raise ConfigError(f"{option} {path}: not a regular file (a device or a pipe); give a file name")
        if not renamed and os.access(path, os.W_OK):
            return
    where = path if folder and path.exists() else _nearest_existing(path)
    if not where.is_dir():
        raise ConfigError(f"{option} {path}: cannot create it: {where} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=where):
            pass
    except OSError as exc:
        raise ConfigError(f"{option} {path}: cannot write there ({where}: {exc.strerror or exc})") from None


def _nearest_existing(path: Path) -> Path:
    """The nearest parent of ``path`` that exists (as typed when one does, e.g. ``vo.mcap`` of
    ``vo.mcap/x.mcap``)."""
    return next((p for p in path.parents if p.exists()), None) or next(p for p in path.absolute().parents if p.exists())


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
