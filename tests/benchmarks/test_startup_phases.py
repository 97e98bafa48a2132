"""``benchmarks/startup.py`` reads where a launch's wall time went from its source's log."""

from __future__ import annotations

import time

import pytest

import benchmarks.startup as startup


def test_launch_phases_from_the_source_log(tmp_path):
    t_start = time.mktime((2026, 12, 2, 15, 21, 22, 0, 0, -1)) + 0.5  # 15:21:22.500 local time
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "source.log").write_text(
        "--- start #0 15:21:23\n"
        "15:21:24.100 [source] INFO source: waiting for tracker, sink to be ready\n"
        "15:21:26.600 [source] INFO source: published 100 frame(s) in 0.25 s; waiting for sink to finish\n")
    first, publishing, exit_after = startup.launch_phases(tmp_path, t_start, 5.0)
    # last frame at 26.600 - 22.500 = 4.1 s, the first 0.25 s before it
    assert first == pytest.approx(3.85, abs=1e-6)
    assert publishing == pytest.approx(0.25)
    assert exit_after == pytest.approx(0.9, abs=1e-6)


def test_no_phases_without_the_line(tmp_path):
    assert startup.launch_phases(tmp_path, time.time(), 1.0) is None  # no log at all
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "source.log").write_text("15:21:24.100 [source] INFO source: stopped after 3 frame(s)\n")
    assert startup.launch_phases(tmp_path, time.time(), 1.0) is None
