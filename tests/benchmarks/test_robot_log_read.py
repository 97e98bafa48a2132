"""benchmarks/robot_log_read.py: its two logs read to the same frames, and a small run reports
the figures docs/performance.md quotes."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import benchmarks.robot_log_read as rlr
from bnptrack.sources.mcap_log import iter_frames
from testkit import REPO_ROOT, bnptrack_env


def test_the_two_logs_hold_the_same_frames(tmp_path):
    frames = rlr.make_frames(30, 5, seed=3)
    assert all(np.array_equal(f.z, f.z.astype(np.float32).astype(np.float64)) for f in frames)
    json_log, ros = rlr.write_logs(frames, tmp_path)
    a, b = list(iter_frames(json_log)), list(iter_frames(ros, rlr.TOPICS))
    assert [(f.frame, f.stamp_ns, f.sensor, f.kind) for f in a] == [(f.frame, f.stamp_ns, f.sensor, f.kind) for f in b]
    assert all(np.array_equal(x.z, y.z) for x, y in zip(a, b))


@pytest.mark.slow  # a benchmark script in a process of its own
def test_a_small_run_reports_its_ratios():
    out = subprocess.run([sys.executable, "benchmarks/robot_log_read.py", "--messages", "40", "--repeats", "2"],
                         cwd=REPO_ROOT, env=bnptrack_env(), capture_output=True, text=True, check=True).stdout
    last = json.loads(out.strip().splitlines()[-1])
    assert last["messages"] == 40 and last["json_s"] > 0 and last["ros2_s"] > 0
    assert last["ratio_of_medians"] > 0 and set(last["decode_s"]) == {"rosbags", "mcap_ros2"}
