"""``--view`` where no viewer can start (no display, not headless) is refused while the
command checks its options: one line, exit code 2, and no output opened, so an existing
``--out`` file keeps its bytes (``track --view`` does not truncate it first)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from testkit import REPO_ROOT, bnptrack_env

VO2017 = REPO_ROOT / "recordings" / "vo2017-s1.mcap"
KEPT = b"an earlier run's tracks: not to be lost\n"


def _no_display_env() -> dict[str, str]:
    env = bnptrack_env()
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "BNPTRACK_VIEWER_HEADLESS"):
        env.pop(name, None)
    return env


def _bnptrack(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bnptrack", *args], cwd=REPO_ROOT, env=_no_display_env(),
                          capture_output=True, text=True, timeout=120)


def _refused(r: subprocess.CompletedProcess) -> None:
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: --view: no display"), r.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the display test is Linux's")
@pytest.mark.slow  # the command line in a process of its own
def test_track_view_without_a_display_keeps_an_existing_out_file(tmp_path):
    out = tmp_path / "tracks.mcap"
    out.write_bytes(KEPT)
    r = _bnptrack("track", str(VO2017), "--view", "--out", str(out), "--tracker", "ddp-mb")
    _refused(r)
    assert out.read_bytes() == KEPT
    assert not out.with_suffix(".rrd").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracks.mcap"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the display test is Linux's")
@pytest.mark.parametrize("command", [("launch",), ("replay", str(VO2017))], ids=["launch", "replay"])
@pytest.mark.slow  # the command line in a process of its own
def test_pipeline_view_without_a_display_starts_nothing(tmp_path, command):
    out = tmp_path / "run"
    _refused(_bnptrack(*command, "--view", "--out", str(out)))
    assert not out.exists()


@pytest.mark.parametrize("command", [("launch",), ("replay", str(VO2017)), ("replay", str(VO2017), "--loop", "2"),
                                     ("track", str(VO2017))], ids=["launch", "replay", "replay-loop", "track"])
@pytest.mark.slow  # the command line in a process of its own
def test_view_and_connect_together_are_a_usage_error(tmp_path, command):
    """One rule (``cli.common.one_viewer``) for every command that streams to a viewer."""
    out = tmp_path / "run"
    r = _bnptrack(*command, "--view", "--connect", "rerun+http://127.0.0.1:1/proxy", "--out", str(out))
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1] == (
        "Error: --view starts a viewer, --connect URL uses a running one: give one of them")
    assert not out.exists()
