"""``bnptrack launch`` / ``replay`` validate the whole pipeline before any process starts
(pipeline/preflight.py), ``--set`` keys mean the same in every command, and connection
failures are one line with a hint."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bnptrack.pipeline.cli import main
from click.testing import CliRunner

from testkit import REPO_ROOT

ROOT = REPO_ROOT


def bnptrack(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "bnptrack", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=ROOT)


def cli(*args) -> subprocess.CompletedProcess:
    """``bnptrack ARGS`` run in this process (click's runner): the exit code, stdout and
    stderr the command line gives (the refusals below need no process of their own)."""
    res = CliRunner().invoke(main, [str(a) for a in args])
    return subprocess.CompletedProcess(args, res.exit_code, res.stdout, res.stderr)


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
    res = cli("replay", vo_log, "--tracker", "ddpp", "--out", out)
    # the same error as track's: the option's choices and the closest one
    assert_refused(res, out, "Invalid value for '--tracker': 'ddpp' is not one of 'ddp', 'dpyp', 'glmb'")
    assert res.stderr.rstrip().endswith("(did you mean 'ddp'?)")


@pytest.mark.parametrize("toml, needle", [
    ('[tracker]\ntracker = "glmbb"\n', "unknown tracker 'glmbb'"),
    ('[tracker]\noverrides = ["sweps=10"]\n', "--set 'sweps=10': unknown key 'sweps'"),
    ('[source]\nkind = "mcap"\n', "source.log: an MCAP log is required when source.kind = 'mcap'"),
    ('[source]\nkind = "mcap"\nlog = "/nonexistent/x.mcap"\n', "source.log: /nonexistent/x.mcap: no such file"),
    ('[source]\nscenario = "vo2071"\n', "unknown scenario 'vo2071'"),
    ('[source]\noverrides = ["p_detect=2"]\n', "p_detect"),
    ('[tracker]\nconfig = "dddp"\n', "--config 'dddp': not a preset of ddp"),
    ('[tracker]\ntracker = "glmb"\noverrides = ["tracker.alpha=2"]\n', "unknown key 'tracker.alpha'"),
    ('[zenoh]\nembedded_router = false\n', "zenoh.connect: a client needs router endpoints"),
    ('[zenoh]\nusers_file = "/nonexistent/users.txt"\n', "zenoh.users_file: /nonexistent/users.txt: no such file"),
    ('[sink]\nmcap_name = "../x.mcap"\n', "sink.mcap_name"),
])
def test_launch_pipeline_file_errors_fail_before_starting(tmp_path, toml, needle):
    pipe = tmp_path / "p.toml"
    pipe.write_text(toml)
    out = tmp_path / "out"
    res = cli("launch", pipe, "--out", out)
    assert_refused(res, out, needle)
    assert res.stderr.startswith(f"Error: {pipe}: "), res.stderr  # the file is named


def test_launch_out_that_is_a_file_is_refused(tmp_path):
    out = tmp_path / "taken"
    out.write_text("x")
    pipe = tmp_path / "p.toml"
    pipe.write_text(f'out = "{out}"\n')
    res = cli("launch", pipe)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert f"--out {out}: a file, not a folder" in res.stderr
    assert out.read_text() == "x"


def test_check_pipeline_accepts_the_default_and_a_replay(vo_log, tmp_path):
    import msgspec

    from bnptrack.pipeline.config import default_pipeline, resolve_run
    from bnptrack.pipeline.preflight import check_pipeline

    cfg = resolve_run(msgspec.structs.replace(default_pipeline(), out=str(tmp_path / "a" / "b")))
    check_pipeline(cfg)  # nothing raised, nothing created
    assert not (tmp_path / "a").exists()
    src = msgspec.structs.replace(cfg.source, kind="mcap", log=str(vo_log))
    check_pipeline(msgspec.structs.replace(cfg, source=src))


# --------------------------------------------------------------------------- --set keys


def test_set_keys_route_like_track_plus_the_pipeline_tables():
    from bnptrack.pipeline.config import load_pipeline, split_pipeline_overrides

    items = ["p_detect=0.9", "tracker.sweeps=5", "params.clutter_rate=3", "source.frames=2",
             "tracker.seed=3", "run=abc", "sink.rerun=false", "tracker.tracker=dpyp", "burn_in=1"]
    pipe, model = split_pipeline_overrides(items)
    assert pipe == ("source.frames=2", "tracker.seed=3", "run=abc", "sink.rerun=false", "tracker.tracker=dpyp")
    assert model == ("p_detect=0.9", "tracker.sweeps=5", "params.clutter_rate=3", "burn_in=1")
    cfg = load_pipeline(None, items)
    assert cfg.tracker.overrides == list(model)
    assert (cfg.tracker.seed, cfg.tracker.tracker, cfg.source.frames, cfg.run, cfg.sink.rerun) == (
        3, "dpyp", 2, "abc", False)
    # the explicit pipeline key still works, and the tracker's items come after it
    cfg = load_pipeline(None, ["tracker.overrides=['sweeps=9']", "p_detect=0.8"])
    assert cfg.tracker.overrides == ["sweeps=9", "p_detect=0.8"]
    with pytest.raises(Exception, match="expected key=value"):
        split_pipeline_overrides(["p_detect"])


def test_unknown_bare_set_key_gives_tracks_error(vo_log, tmp_path):
    out = tmp_path / "r"
    res = cli("replay", vo_log, "--set", "foo=1", "--out", out)
    assert_refused(res, out, "--set 'foo=1': unknown key 'foo': not a model parameter")
    res = cli("launch", "--set", "source.foo=1", "--out", out)
    assert_refused(res, out, "unknown key 'source.foo'")


@pytest.mark.parametrize("item, page", [
    ("source.foo=1", "(docs/pipeline.md, 'The pipeline file', lists the keys)"),
    ("zenoh.foo=1", "(docs/pipeline.md, 'The pipeline file', lists the keys)"),
    ("params.foo=1", "(docs/models.md lists the keys)"),
    ("tracker.foo=1", "(docs/trackers.md lists the keys)"),
    ("objects.foo=1", "(docs/trackers.md lists the keys)"),
])
def test_unknown_key_names_the_page_that_lists_its_table(item, page, tmp_path):
    """An unknown key of a table too large to list is sent to the page documenting that table:
    pipeline keys to docs/pipeline.md, model parameters to docs/models.md, tracker settings to
    docs/trackers.md."""
    out = tmp_path / "r"
    res = cli("launch", "--set", item, "--out", out)
    assert_refused(res, out, f"unknown key '{item.partition('=')[0]}' {page}")


@pytest.mark.integration  # a real replay: stage processes over Zenoh
def test_replay_set_bare_keys_equal_track_with_the_same_set(vo_log, tmp_path):
    """``replay LOG --set p_detect=0.9 --set sweeps=8 --set tracker.burn_in=2`` runs the tracker
    ``track LOG`` runs with the same ``--set`` items: the same /tracks (first 6 frames)."""
    from bnptrack.sources.mcap_log import iter_tracks

    sets = ["--tracker", "ddp-mb", "--set", "p_detect=0.9", "--set", "sweeps=8", "--set", "tracker.burn_in=2"]
    off = tmp_path / "off.mcap"
    res = bnptrack("track", vo_log, *sets, "--out", off, "-q")
    assert res.returncode == 0, res.stderr
    out = tmp_path / "r"
    res = bnptrack("replay", vo_log, "--as-fast-as-possible", *sets, "--set", "source.frames=6",
                   "--set", "sink.rerun=false", "--out", out, "-q", "--timeout", "150", timeout=180)
    assert res.returncode == 0, res.stderr
    strip = lambda e: (e.frame, e.labels, e.assignments, [t.state.tolist() for t in e.tracks])  # noqa: E731
    got = [strip(e) for e in iter_tracks(out / "tracks.mcap")]
    want = [strip(e) for e in iter_tracks(off)][:6]
    assert len(got) == 6 and got == want
    meta = __import__("bnptrack.sources.mcap_log", fromlist=["read_metadata"]).read_metadata(out / "tracks.mcap")
    assert meta["tracker_overrides"] == "p_detect=0.9;sweeps=8;tracker.burn_in=2"


# --------------------------------------------------------------------------- no router


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # bnptrack processes that try a real connection
def test_monitor_without_a_router_is_one_line_exit_2_without_the_10_s_wait():
    import time

    ep = f"tcp/127.0.0.1:{_free_port()}"
    t0 = time.monotonic()
    res = bnptrack("monitor", "--run", "r1", "--connect", ep, "--duration", "30")
    elapsed = time.monotonic() - t0
    assert res.returncode == 2, res.stderr
    assert res.stderr.splitlines() == [
        f"Error: no router at {ep}: start one with `bnptrack router --listen {ep}`, "
        "or connect to the endpoint `bnptrack launch` printed"]
    assert elapsed < 9.0  # the connect timeout is 1 s, not the stages' 10 s (generous bound)


@pytest.mark.slow  # bnptrack processes that try a real connection
def test_stage_and_launch_without_a_router_are_one_line_exit_2(tmp_path):
    ep = f"tcp/127.0.0.1:{_free_port()}"
    out = tmp_path / "s"
    res = bnptrack("stage", "sink", "--run", "r1", "--connect", ep, "--out", out,
                   "--set", "zenoh.connect_timeout_s=0.5")
    assert res.returncode == 2
    assert res.stderr.splitlines()[-1].startswith(f"Error: no router at {ep}: start one with")
    assert_refused(bnptrack("launch", "--connect", ep, "--out", out), out,
                   f"no router at {ep}: start one with `bnptrack router --listen {ep}`")


def test_launcher_reports_a_stage_configuration_error_on_one_line(tmp_path):
    from bnptrack.pipeline.supervisor import StageProcess

    log = tmp_path / "tracker.log"
    sp = StageProcess("tracker", [], log)
    log.write_text("--- start #0 17:05:42\n17:05:44.083 [tracker] ERROR tracker: configuration error: "
                   "unknown tracker 'foo'; valid trackers: ddp\n17:05:44.086 [tracker] INFO tracker: cpu\n")
    assert sp.error_line() == "unknown tracker 'foo'; valid trackers: ddp"
    log.write_text("17:05:44.083 [tracker] INFO x\nError: no router at tcp/h:1: start one\n")
    assert sp.error_line() == "no router at tcp/h:1: start one"
    log.write_text("a\nb\nc\nd\n")
    assert sp.error_line() == "b / c / d"


def test_listening_probes_tcp_and_tls_endpoints_only():
    import socket

    from bnptrack.pipeline.preflight import listening

    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        port = srv.getsockname()[1]
        assert listening([f"tcp/127.0.0.1:{port}"]) is True
        assert listening([f"tcp/127.0.0.1:{_free_port()}", f"tls/localhost:{port}"]) is True
    assert listening([f"tcp/127.0.0.1:{_free_port()}"]) is False
    assert listening(["udp/127.0.0.1:7447"]) is None and listening([]) is None


def test_replay_and_launch_with_a_window_past_the_end_fail_before_starting(vo_log, tmp_path):
    """A window that holds no frame is an error before any process starts (not a
    pipeline of 0 frames that runs for about 10 s and writes empty outputs)."""
    out = tmp_path / "r"
    res = cli("replay", vo_log, "--start", "500f", "--out", out)
    assert_refused(res, out, f"{vo_log}: no frame in the window --start 500f; `bnptrack info LOG`")
    res = cli("launch", "--set", "source.end_s=10", "--set", "source.start_s=200", "--out", out)
    assert_refused(res, out, "source.end_s = 10 is before source.start_s = 200")
    res = cli("launch", "--set", "source.start_frame=101", "--out", out)
    assert_refused(res, out, "source.scenario 'vo2017' (seed 1): no frame in the window source.start_frame = 101")
