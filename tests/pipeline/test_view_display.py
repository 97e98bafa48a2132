"""``--view`` with a display set but no server behind it (``DISPLAY=:N`` with no X server) is
refused at once while the command checks its options, on one line; a display that answers
passes the check (pipeline/live.py ``display_unreachable``)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import pytest

from bnptrack.pipeline.live import display_unreachable
from testkit import REPO_ROOT, bnptrack_env

VO2017 = REPO_ROOT / "recordings" / "vo2017-s1.mcap"
linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the display check is Linux's")


def _dead_display() -> str:
    """A local X display number with no server (no socket, abstract or on disk)."""
    for n in range(987, 1100):
        if display_unreachable({"DISPLAY": f":{n}"}):
            return f":{n}"
    pytest.skip("every display number tried has an X server")


@linux_only
@pytest.mark.parametrize("command", [("track", str(VO2017)), ("launch",)], ids=["track", "launch"])
@pytest.mark.slow  # the command line in a process of its own
def test_view_on_a_display_without_server_fails_at_once_on_one_line(tmp_path, command):
    env = bnptrack_env()
    env.pop("WAYLAND_DISPLAY", None)
    env.pop("BNPTRACK_VIEWER_HEADLESS", None)
    env["DISPLAY"] = display = _dead_display()
    out = tmp_path / "out"
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "bnptrack", *command, "--view", "--out", str(out)],
                       cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert time.monotonic() - t0 < 5.0
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"Error: --view: no X server answers on DISPLAY={display}: "
                               "the viewer cannot open a window")
    assert not out.exists()


@linux_only
def test_a_display_that_answers_passes_the_check(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:
        for n in range(60, 200):  # an X server on TCP HOST:N listens on port 6000 + N
            try:
                server.bind(("127.0.0.1", 6000 + n))
                break
            except OSError:
                continue
        else:
            pytest.skip("no free port 6060-6199")
        server.listen(1)
        assert display_unreachable({"DISPLAY": f"127.0.0.1:{n}"}) == ""
    assert display_unreachable({"DISPLAY": f"127.0.0.1:{n}"}) == f"no X server answers on DISPLAY=127.0.0.1:{n}"


def test_a_wayland_socket_passes_and_a_malformed_display_is_named(tmp_path):
    (tmp_path / "wayland-7").write_bytes(b"")
    assert display_unreachable({"WAYLAND_DISPLAY": "wayland-7", "XDG_RUNTIME_DIR": str(tmp_path)}) == ""
    assert display_unreachable({"WAYLAND_DISPLAY": "wayland-8", "XDG_RUNTIME_DIR": str(tmp_path)}) == \
        "the Wayland display wayland-8 has no socket"
    assert display_unreachable({"DISPLAY": "nonsense"}) == "DISPLAY=nonsense is not of the form [HOST]:N"
