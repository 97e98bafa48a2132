"""Start-up of the ``bnptrack`` command line: what ``bnptrack --help`` and
``bnptrack track`` import, and that the lazily loaded command table lists exactly the commands'
own help.  Checks of ``sys.modules`` in a fresh interpreter, not timings (docs/performance.md
has the timings, from ``benchmarks/startup.py``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import click
import pytest
from click.testing import CliRunner

from testkit import REPO_ROOT

#: Modules that ``bnptrack --help`` must not import: the numerical stack, the transport, the
#: viewer SDK, the message codec, and the project's packages below the command line.
HEAVY = ("numpy", "scipy", "numba", "rerun", "zenoh", "pyarrow", "msgspec", "mcap", "dask", "matplotlib",
         "pandas", "tracker", "sources", "sinks")

_PROBE = """
import json, sys
from bnptrack.pipeline.cli import main
try:
    main({argv!r}, prog_name="bnptrack")
except SystemExit as e:
    code = e.code
print(json.dumps({{"code": code, "modules": sorted(sys.modules)}}), file=sys.stderr)
"""


def imported_by(*argv: str) -> tuple[int, set[str], str]:
    """Exit code, modules imported (full names) and stdout of ``bnptrack ARGV`` in a new interpreter."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    proc = subprocess.run([sys.executable, "-c", _PROBE.format(argv=list(argv))], cwd=REPO_ROOT, env=env,
                          capture_output=True, text=True, timeout=120)
    report = json.loads(proc.stderr.strip().splitlines()[-1])
    return report["code"], set(report["modules"]), proc.stdout


def top_level(modules: set[str]) -> set[str]:
    return {m.split(".")[0] for m in modules}


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_help_imports_no_heavy_module():
    code, modules, out = imported_by("--help")
    assert code == 0
    assert "Commands:" in out and "track" in out
    assert sorted(top_level(modules) & set(HEAVY)) == []


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_track_help_loads_only_the_offline_commands():
    """``track --help`` loads the offline commands only: no Zenoh, no Rerun SDK, no numba or
    scipy (its help lists the trackers' settings classes, so it imports the trackers, whose
    kernels import numba at their first call), and not the other command modules."""
    code, modules, out = imported_by("track", "--help")
    assert code == 0 and "Usage: bnptrack track" in out
    assert sorted(top_level(modules) & {"zenoh", "rerun", "numba", "scipy", "dask", "matplotlib", "pyarrow"}) == []
    assert "bnptrack.pipeline.cli.offline_commands" in modules
    assert sorted(modules & {"bnptrack.pipeline.cli.tools", "bnptrack.pipeline.cli.pipeline_commands", "bnptrack.pipeline.cli.monitor",
                             "bnptrack.pipeline.experiments", "bnptrack.pipeline.launch", "bnptrack.pipeline.transport"}) == []


def test_command_table_matches_each_commands_help():
    """The listing of ``bnptrack --help`` comes from :data:`pipeline.cli.COMMANDS`: each entry
    names the module that defines the command and the first paragraph of its help."""
    from bnptrack.pipeline.cli import COMMANDS, main

    assert set(main.commands) == set(COMMANDS)
    for name, (module, summary) in COMMANDS.items():
        cmd = main.commands[name]
        assert cmd.callback.__module__ == module, name
        first = cmd.help.split("\n\n")[0]
        assert " ".join(first.split()) == summary, name
        assert not cmd.hidden and not cmd.deprecated and cmd.short_help is None, name


def test_help_listing_is_the_eager_groups_listing():
    """``bnptrack --help`` prints what a group holding the loaded commands prints (same
    options, same width), at the default width and a narrow one."""
    from bnptrack.pipeline.cli import main

    eager = click.Group(name=main.name, help=main.help, params=main.params,
                        context_settings=main.context_settings,
                        commands={name: main.commands[name] for name in main.commands})
    for width in (None, 60):
        runner = CliRunner()
        lazy_out = runner.invoke(main, ["--help"], prog_name="bnptrack", terminal_width=width).output
        eager_out = runner.invoke(eager, ["--help"], prog_name="bnptrack", terminal_width=width).output
        assert lazy_out == eager_out
        assert "Commands:" in lazy_out and "Run a tracker over an MCAP log offline" in lazy_out


def test_cli_error_names_resolve_lazily():
    from bnptrack.pipeline.cli import EXIT_ERROR, EXIT_INCOMPLETE, CliError, IncompleteError
    from bnptrack.pipeline.cli import common

    assert (EXIT_ERROR, EXIT_INCOMPLETE) == (2, 3)
    assert CliError is common.CliError and IncompleteError is common.IncompleteError


_KERNEL_PROBE = """
import sys
import numpy as np
import bnptrack.tracker.bnp.gibbs_setup as g
import bnptrack.tracker.bnp.gibbs_sweeps as s
from bnptrack.tracker.numerics import JIT
before = "numba" in sys.modules
keys = g._group_pairs(np.array([4, 7, 9], dtype=np.int64), np.array([0], dtype=np.int64),
                      np.array([3], dtype=np.int64), 10, 3)
print(JIT, before, "numba" in sys.modules, type(s._sweeps).__module__.split(".")[0], keys.tolist())
"""


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_kernels_import_numba_at_their_first_call():
    """Importing a tracker's kernels does not import numba; the first call does, and then the
    module's kernel names are numba dispatchers (the compiled driver calls compiled helpers).
    Pairs within one group of measurements 4, 7, 9 (M = 10): keys 4*10+7, 4*10+9, 7*10+9."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    env.pop("BNPTRACK_NO_JIT", None)
    out = subprocess.run([sys.executable, "-c", _KERNEL_PROBE], cwd=REPO_ROOT, env=env, capture_output=True,
                         text=True, timeout=300, check=True).stdout.split(maxsplit=4)
    assert out[:4] == ["True", "False", "True", "numba"]
    assert out[4].strip() == "[47, 49, 79]"
