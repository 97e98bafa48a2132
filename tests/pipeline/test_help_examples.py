"""Every `bnptrack ...` example line of every command's --help parses as written (click's own
parser, from the repository root, on the files the examples name), and the quick ones run.
Files the user brings (a ROS 2 log, a damaged recording) stand for themselves: an empty file
of that name is enough to parse."""

from __future__ import annotations

import shlex
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main

ROOT = Path(__file__).resolve().parents[2]
#: files an example names that the user brings, or that an earlier example writes
USER_FILES = ("robot.mcap", "ros.mcap", "broken.rrd")
#: commands whose examples run in a second or two
QUICK = ("simulate", "info", "schema")


def _commands(group: click.Group = main, path: tuple[str, ...] = ()):
    for name, cmd in group.commands.items():
        yield (*path, name), cmd
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, (*path, name))


def _examples() -> list[tuple[str, str]]:
    """``(command whose --help shows it, example line)`` of every command and of ``bnptrack``."""
    out = []
    for path, _ in [((), main), *_commands()]:
        res = CliRunner().invoke(main, [*path, "--help"], terminal_width=200)
        assert res.exit_code == 0, res.output
        out += [(" ".join(path) or "bnptrack", line.strip()) for line in res.output.splitlines()
                if line.strip().startswith("bnptrack ")]
    return out


EXAMPLES = _examples()


def _argv(line: str) -> list[str]:
    """The arguments after ``bnptrack``: a trailing ``# comment`` and a ``> file`` redirect cut."""
    argv = shlex.split(line, comments=True)
    return argv[1:argv.index(">")] if ">" in argv else argv[1:]


def test_every_command_shows_examples():
    """Every command's --help has an Example(s) block, and the lines are found."""
    for path, _ in _commands():
        res = CliRunner().invoke(main, [*path, "--help"], terminal_width=200)
        assert "Example" in res.output, f"bnptrack {' '.join(path)} --help shows no example"
        assert " ".join(path) in {where for where, _ in EXAMPLES}


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A directory like the repository root: copies of recordings/ (an example may write
    there) and examples/ as shipped, plus the files the examples read that an earlier example
    writes or the user brings."""
    (tmp_path / "recordings").mkdir()
    for log in (ROOT / "recordings").glob("*.mcap"):
        (tmp_path / "recordings" / log.name).write_bytes(log.read_bytes())
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    for name in (*USER_FILES, "recordings/vo2017-ddp.mcap", "recordings/vo2017-ddp.rrd"):
        (tmp_path / name).write_bytes(b"")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize(("where", "line"), EXAMPLES, ids=[line for _, line in EXAMPLES])
def test_help_example_parses(workdir, where, line):
    argv = _argv(line)
    cmd, rest, name = main, argv, "bnptrack"
    while isinstance(cmd, click.Group):
        assert rest and rest[0] in cmd.commands, f"{where} --help: {line!r} names no command"
        cmd, name, rest = cmd.commands[rest[0]], rest[0], rest[1:]
    with cmd.make_context(name, list(rest)) as ctx:  # raises click's usage error on a bad argument
        assert set(ctx.params) == {p.name for p in cmd.params}  # every option and argument resolved
    if name in QUICK and not set(argv) & set(USER_FILES):
        res = CliRunner().invoke(main, argv)
        assert res.exit_code == 0, f"{line}\n{res.output}"
