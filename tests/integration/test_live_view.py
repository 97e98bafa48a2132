"""Watching a run live (pipeline/live.py, ``RerunSink(live=URL)``, ``track --view/--connect``).

No window is needed: the "viewer" is ``rerun --serve-grpc --save FILE`` (the gRPC server a
viewer runs, saving what it receives), or the viewer started with ``--headless``
(``BNPTRACK_VIEWER_HEADLESS=1``) and asked over its control API what it holds.
"""

from __future__ import annotations

import os

os.environ.setdefault("CI", "1")  # before `import rerun`: no analytics from any rerun subprocess
os.environ.setdefault("RUST_LOG", "error")

import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from bnptrack.pipeline.live import check_viewer, is_viewer_url, viewer_url  # noqa: E402
from bnptrack.sinks.rerun_sink import write_recording  # noqa: E402
from bnptrack.sinks.rerun_tools import rerun_cli, rerun_env  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp import make_tracker  # noqa: E402
from bnptrack.tracker.config import ConfigError  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402

from testkit import REPO_ROOT, require_renderer, rrd_verify, wait_until  # noqa: E402

REPO = REPO_ROOT
SHORT_LOG = REPO / "recordings" / "vo2017-s1.mcap"


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rows(path: Path) -> dict[str, list]:
    """Entity path -> its rows (every column but the row id and log_time), sorted: what a
    viewer shows, whatever the chunking."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = defaultdict(list)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a file still being written has no footer yet
        chunks = list(RrdReader(path).stream())
    for ch in chunks:
        rb = ch.to_record_batch()
        names = [n for n in rb.schema.names if n not in ("rerun.controls.RowId", "log_time")]
        cols = {n: rb.column(n).to_pylist() for n in names}
        for i in range(rb.num_rows):
            out[ch.entity_path].append(tuple((n, repr(cols[n][i])) for n in names if cols[n][i] is not None))
    return {k: sorted(v) for k, v in out.items()}


class Receiver:
    """``rerun --serve-grpc --save FILE`` on a free loopback port: a viewer's gRPC server
    without the window, writing what it receives to FILE."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.port = _free_port()
        self.url = f"rerun+http://127.0.0.1:{self.port}/proxy"
        self.proc = subprocess.Popen([*rerun_cli(), "--serve-grpc", "--bind", "127.0.0.1", "--port",
                                      str(self.port), "--save", str(path)], env=rerun_env(),
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + 30

        def up() -> bool:
            try:
                check_viewer(self.url, timeout=0.2)
                return True
            except ConfigError:
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    self.stop()
                    raise  # the viewer's own error, not a timeout of ours
                return False

        wait_until(up, 60, "the gRPC server to answer", interval=0.05)

    def rows(self, want: dict[str, list], timeout: float = 60.0) -> dict[str, list]:
        """The rows received so far, once they equal ``want`` or after ``timeout`` seconds
        (the server writes what it receives on its own schedule: it may lag behind the
        sender's flush on a busy machine)."""
        def current() -> dict[str, list]:
            return rows(self.path) if self.path.exists() else {}

        try:
            wait_until(lambda: current() == want, timeout, "the server to save the rows sent", interval=0.2)
        except AssertionError:
            pass  # the caller compares (and shows the difference)
        return current()

    def stop(self) -> None:
        """Stop it (Ctrl-C: it finishes the file)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)


@pytest.fixture
def receiver(tmp_path):
    r = Receiver(tmp_path / "received.rrd")
    try:
        yield r
    finally:
        r.stop()


def test_viewer_urls():
    assert viewer_url("9876") == "rerun+http://127.0.0.1:9876/proxy"
    assert viewer_url("rerun+http://10.0.0.5:9877/proxy") == "rerun+http://10.0.0.5:9877/proxy"
    for bad in ("http://127.0.0.1:9876/proxy", "rerun+http://127.0.0.1/proxy", "rerun+http://h:9876/x"):
        with pytest.raises(ConfigError, match="expected a Rerun viewer URL"):
            viewer_url(bad)
    assert is_viewer_url("rerun+http://h:1/proxy") and is_viewer_url("rerun://h:1/proxy")
    assert not is_viewer_url("tcp/127.0.0.1:7447") and not is_viewer_url("tls/h:7447")
    assert is_viewer_url("9876") and viewer_url("9876") == "rerun+http://127.0.0.1:9876/proxy"  # a port: a viewer
    with pytest.raises(ConfigError, match=r"no Rerun viewer at rerun\+http://127.0.0.1:\d+/proxy"):
        check_viewer(str(_free_port()))


def test_live_stream_carries_the_same_rows_as_the_file(tmp_path, receiver):
    params = load_params("vo2017")
    frames = simulate_all(get_scenario("vo2017"), params, 1)[:12]
    estimates = [est for _f, est, _s in run(make_tracker("ddp-mb", params), frames, 0)]
    path = tmp_path / "run.rrd"
    write_recording(path, frames, estimates, {"scenario": "vo2017"}, params=params, live=receiver.url,
                    handle_signals=False)
    want = rows(path)
    assert sum(map(len, want.values())) > 100 and "/world/measurements" in want
    assert receiver.rows(want) == want


def test_track_connect_streams_and_fails_fast_without_a_viewer(tmp_path, receiver):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = tmp_path / "t.mcap"
    cmd = [sys.executable, "-m", "bnptrack", "track", str(SHORT_LOG), "--out", str(out), "-q",
           "--tracker", "ddp-mb", "--set", "tracker.sweeps=5", "--set", "tracker.burn_in=1"]
    res = subprocess.run([*cmd, "--connect", receiver.url], env=env, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    want = rows(out.with_suffix(".rrd"))  # --connect without --rrd: next to --out
    assert receiver.rows(want) == want
    # no viewer there: one line, exit code 2, nothing written
    t0 = time.monotonic()
    res = subprocess.run([*cmd, "--connect", str(_free_port()), "--out", str(tmp_path / "u.mcap")],
                         env=env, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stderr.startswith("Error: no Rerun viewer at rerun+http://127.0.0.1:")
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "u.mcap").exists()
    assert time.monotonic() - t0 < 10


def test_track_view_spawns_a_viewer_that_receives_the_run(tmp_path):
    """``--view`` with the viewer headless: the viewer it started holds the recording (the
    viewer renders even headless: skipped without a Vulkan driver, failed under CI)."""
    from rerun.experimental import ViewerClient

    require_renderer()

    env = {**os.environ, "PYTHONPATH": str(REPO), "BNPTRACK_VIEWER_HEADLESS": "1"}
    out = tmp_path / "t.mcap"
    res = subprocess.run([sys.executable, "-m", "bnptrack", "track", str(SHORT_LOG), "--out", str(out),
                          "--view", "--tracker", "ddp-mb", "--set", "tracker.sweeps=5", "--set", "tracker.burn_in=1"],
                         env=env, capture_output=True, text=True, timeout=300)
    line = next((ln for ln in res.stderr.splitlines() if ln.startswith("viewer: ")), "")
    assert line, res.stderr
    url = line.split()[1]
    pid = int(line.split("(pid ")[1].split(";")[0])
    try:
        assert res.returncode == 0, res.stderr
        client = ViewerClient(url)
        def frame_timeline():  # the viewer ingests the stream on its own schedule
            state = client.get_state()
            tl = [t for r in state.recordings for t in r.timelines if t.name == "frame"]
            return tl if tl and tl[0].end == 100 else None

        tl = wait_until(frame_timeline, 60, "the viewer to hold frames up to 100", interval=0.2)
        assert tl[0].start == 1 and out.with_suffix(".rrd").stat().st_size > 0
    finally:
        os.kill(pid, signal.SIGTERM)


def test_a_frozen_viewer_neither_holds_the_run_nor_the_file(tmp_path, receiver):
    """A viewer that stops reading (SIGSTOP): the recording still ends within seconds, with a
    complete file (its footer written), and the viewer is left behind."""
    import threading

    params = load_params("vo2017")
    frames = simulate_all(get_scenario("vo2017"), params, 1)[:30]
    estimates = [est for _f, est, _s in run(make_tracker("ddp-mb", params), frames, 0)]
    path = tmp_path / "run.rrd"
    os.kill(receiver.proc.pid, signal.SIGSTOP)
    try:
        t0 = time.monotonic()
        worker = threading.Thread(target=write_recording, daemon=True, args=(path, frames, estimates),
                                  kwargs={"params": params, "live": receiver.url, "handle_signals": False})
        worker.start()
        worker.join(60)
        elapsed = time.monotonic() - t0
        assert not worker.is_alive(), "the recording waited for the frozen viewer"
        assert elapsed < 20
    finally:
        os.kill(receiver.proc.pid, signal.SIGCONT)
    verify = rrd_verify(path)
    assert verify.returncode == 0, verify.stderr
    got = rows(path)
    assert "/world/measurements" in got and sum(map(len, got.values())) > 100
