"""``bnptrack launch`` / ``replay`` validate the whole pipeline before any process starts
(pipeline/preflight.py), ``--set`` keys mean the same in every command, and connection
failures are one line with a hint (issue 16 item 3)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.cli import main
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parent.parent


def bnptrack(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=ROOT)


@pytest.fixture(scope="module")
def vo_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("logs") / "vo2017-s1.mcap"
    res = CliRunner().invoke(main, ["simulate", "--seed", "1", "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    return out


def assert_refused(res: subprocess.CompletedProcess, out: Path, needle: str) -> None:
    """Exit 2, exactly one line ``Error: ...`` naming ``needle``, nothing on stdout, no
    output directory (no stage started: a launch writes pipeline.json and logs/ first)."""
    assert res.returncode == 2, (res.stdout, res.stderr)
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), res.stderr
    assert needle in lines[0], lines[0]
    assert res.stdout == ""
    assert not out.exists()


def test_replay_unknown_tracker_fails_before_starting(vo_log, tmp_path):
    out = tmp_path / "r"
    res = bnptrack("replay", vo_log, "--tracker", "foo", "--out", out)
    assert_refused(res, out, "unknown tracker 'foo'; valid trackers: ddp, dpyp, glmb")


@pytest.mark.parametrize("toml, needle", [
    ('[tracker]\ntracker = "glmbb"\n', "unknown tracker 'glmbb'"),
    ('[tracker]\noverrides = ["sweps=10"]\n', "--set 'sweps=10': unknown key 'sweps'"),
    ('[source]\nkind = "mcap"\n', "source.log: an MCAP log is required when source.kind = 'mcap'"),
    ('[source]\nkind = "mcap"\nlog = "/nonexistent/x.mcap"\n', "source.log: /nonexistent/x.mcap: no such file"),
    ('[source]\nscenario = "vo2071"\n', "unknown scenario 'vo2071'"),
    ('[source]\noverrides = ["p_detect=2"]\n', "p_detect"),
    ('[tracker]\nconfig = "dddp"\n', "--config 'dddp': not a preset of ddp"),
    ('[tracker]\ntracker = "glmb"\noverrides = ["tracker.alpha=2"]\n', "unknown key 'alpha'"),
    ('[zenoh]\nembedded_router = false\n', "zenoh.connect: a client needs router endpoints"),
    ('[zenoh]\nusers_file = "/nonexistent/users.txt"\n', "zenoh.users_file: /nonexistent/users.txt: no such file"),
    ('[sink]\nmcap_name = "../x.mcap"\n', "sink.mcap_name"),
])
def test_launch_pipeline_file_errors_fail_before_starting(tmp_path, toml, needle):
    pipe = tmp_path / "p.toml"
    pipe.write_text(toml)
    out = tmp_path / "out"
    assert_refused(bnptrack("launch", pipe, "--out", out), out, needle)


def test_launch_out_that_is_a_file_is_refused(tmp_path):
    out = tmp_path / "taken"
    out.write_text("x")
    pipe = tmp_path / "p.toml"
    pipe.write_text(f'out = "{out}"\n')
    res = bnptrack("launch", pipe)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert f"--out {out}: exists and is not a directory" in res.stderr
    assert out.read_text() == "x"


def test_check_pipeline_accepts_the_default_and_a_replay(vo_log, tmp_path):
    import msgspec

    from pipeline.pipeline_config import default_pipeline, resolve_run
    from pipeline.preflight import check_pipeline

    cfg = resolve_run(msgspec.structs.replace(default_pipeline(), out=str(tmp_path / "a" / "b")))
    check_pipeline(cfg)  # nothing raised, nothing created
    assert not (tmp_path / "a").exists()
    src = msgspec.structs.replace(cfg.source, kind="mcap", log=str(vo_log))
    check_pipeline(msgspec.structs.replace(cfg, source=src))
