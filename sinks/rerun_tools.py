"""The ``rerun`` command-line tool shipped with rerun-sdk: where it is (:func:`rerun_cli`), the
environment it runs in (:func:`rerun_env`), and the checks and repairs of ``.rrd`` files it
does (:func:`verify`, :func:`repair`).  Does not import rerun (starting the viewer does not pay
for the SDK's import).

Analytics: the Rerun *SDK* sends nothing; the ``rerun`` *CLI/viewer* binary would.  Every
subprocess started from here runs with :func:`rerun_env`, which turns the CLI's analytics off
(see its docstring).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

__all__ = ["RerunToolError", "rerun_cli", "rerun_env", "verify", "repair"]


class RerunToolError(RuntimeError):
    """The ``rerun`` command-line tool is missing, failed or timed out."""



def rerun_cli() -> list[str]:
    """Command prefix that runs the ``rerun`` CLI shipped with the installed rerun-sdk.

    ``RERUN_CLI_PATH`` overrides it; otherwise the binary inside the ``rerun_cli`` package (the
    same version as the SDK), else ``rerun`` on ``PATH``.  Raises :class:`RerunToolError`.
    """
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return [override]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        exe = Path(spec.origin).with_name("rerun")
        if exe.is_file() and os.access(exe, os.X_OK):
            return [str(exe)]
    found = shutil.which("rerun")
    if found:
        return [found]
    raise RerunToolError(
        "the `rerun` command-line tool was not found: install rerun-sdk "
        "(pip install 'rerun-sdk>=0.41,<0.42'), which ships it"
    )


def rerun_env(*, analytics: bool = False, quiet: bool = True) -> dict[str, str]:
    """Environment for a ``rerun`` subprocess.

    rerun 0.41 has no analytics environment switch of its own (``RERUN_ANALYTICS`` is not read);
    its analytics pipeline is skipped when ``CI`` is set (any value) or after
    ``rerun analytics disable``.  With ``analytics=False`` (the default) ``CI`` is set if absent,
    so the CLI neither phones home nor writes an analytics config.  ``quiet`` sets ``RUST_LOG``
    to ``error`` unless already set (the viewer otherwise shows log toasts over screenshots).
    """
    env = dict(os.environ)
    if not analytics:
        env.setdefault("CI", "1")
    if quiet:
        env.setdefault("RUST_LOG", "error")
    return env


def _run_cli(args: Sequence[str], timeout: float, what: str) -> subprocess.CompletedProcess[str]:
    cmd = [*rerun_cli(), *map(str, args)]
    try:
        return subprocess.run(
            cmd, capture_output=True, text=True, timeout=timeout, env=rerun_env(),
            stdin=subprocess.DEVNULL, check=False,
        )
    except subprocess.TimeoutExpired as exc:
        raise RerunToolError(f"{what}: `{' '.join(cmd)}` timed out after {timeout:g} s") from exc
    except OSError as exc:
        raise RerunToolError(f"{what}: cannot run `{cmd[0]}`: {exc}") from exc


def verify(path: str | os.PathLike, *, timeout: float = 60.0) -> None:
    """``rerun rrd verify PATH`` (footer checked); raises :class:`RerunToolError` on failure."""
    res = _run_cli(["rrd", "verify", os.fspath(path)], timeout, "verify")
    if res.returncode != 0:
        raise RerunToolError(f"rerun rrd verify {path} failed: {(res.stderr or res.stdout).strip()}")


def repair(path: str | os.PathLike, out: str | os.PathLike, *, timeout: float = 120.0) -> Path:
    """Rewrite a damaged recording (e.g. a writer killed before its footer) into ``out``.

    Runs ``rerun rrd merge --continue-on-error -o OUT PATH``: every chunk that can be decoded is
    kept, the rest dropped, and ``out`` gets a proper footer (``rerun rrd verify`` accepts it).
    Raises :class:`RerunToolError` when the tool fails, times out or writes nothing.
    """
    path, out = Path(path), Path(out)
    if out.resolve() == path.resolve():
        raise ValueError(f"repair: the output {out} would overwrite the input")
    if not path.is_file():
        raise FileNotFoundError(2, "No such file", str(path))
    out.parent.mkdir(parents=True, exist_ok=True)
    res = _run_cli(["rrd", "merge", "--continue-on-error", "-o", os.fspath(out), os.fspath(path)],
                   timeout, "repair")
    if res.returncode != 0 or not out.is_file() or out.stat().st_size == 0:
        raise RerunToolError(
            f"rerun rrd merge --continue-on-error failed on {path} (exit {res.returncode}): "
            f"{(res.stderr or res.stdout).strip()}"
        )
    return out
