"""``bnptrack track / launch / replay / stage`` end their process with ``os._exit`` once done
(:func:`pipeline.cli.exit_now`): no teardown of numba, scipy, Zenoh; but the exit code, the
output files, the ``atexit`` handlers and the buffered stdout are the same as a normal exit."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import FAST_EXIT, _command_name, main
from bnptrack.sources.mcap_log import read_log

from testkit import REPO_ROOT, bnptrack_env

VO2017 = REPO_ROOT / "recordings" / "vo2017-s1.mcap"

#: ``bnptrack ARGS`` as the console script runs it, with an ``atexit`` handler that prints
#: ``atexit ran`` and an unflushed line on stdout (a file, so fully buffered) before the command.
_PROGRAM = textwrap.dedent("""
    import atexit, sys
    atexit.register(lambda: print("atexit ran", file=sys.stderr, flush=True))
    sys.stdout.write("buffered line\\n")
    from bnptrack.pipeline.cli import main
    sys.argv = ["bnptrack", *sys.argv[1:]]
    main()
""")


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _PROGRAM, *args], cwd=REPO_ROOT, env=bnptrack_env(),
                          capture_output=True, text=True, timeout=300)


def test_the_command_word_is_found_after_the_group_options():
    assert _command_name(["--version"]) == ""
    assert _command_name(["-h"]) == ""
    assert _command_name(["track", "x.mcap", "-q"]) == "track"
    assert {"track", "launch", "replay", "stage"} == FAST_EXIT


@pytest.mark.slow
def test_track_exits_fast_with_its_code_output_and_exit_handlers(tmp_path):
    out = tmp_path / "t.mcap"
    r = _run("track", str(VO2017), "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("buffered line\n") and "wrote" in r.stdout  # flushed before os._exit
    assert "atexit ran" in r.stderr
    log = read_log(out)  # closed: summary and footer written
    assert len(log.frames) == 100 and len(log.tracks) == 100


@pytest.mark.slow  # the command line in a process of its own
def test_a_failing_command_keeps_its_exit_code_2():
    r = _run("track", str(REPO_ROOT / "no-such.mcap"), "--out", "/dev/null")
    assert r.returncode == 2
    assert "does not exist" in r.stderr and "atexit ran" in r.stderr


def test_a_caller_of_main_with_arguments_gets_control_back(tmp_path):
    """A test's CliRunner passes ``args``: ``main`` returns (SystemExit caught by the runner),
    the calling process goes on."""
    r = CliRunner().invoke(main, ["track", str(REPO_ROOT / "no-such.mcap"), "--out", str(tmp_path / "x.mcap")])
    assert r.exit_code == 2 and "does not exist" in r.output
