"""The launcher starts each stage in a process group of its own but in the launcher's session:
a terminal's Ctrl-C still reaches the launcher alone, and with Linux's
autogroup scheduling (one scheduling group per session) the stages share the router's group,
as the two-hop floor's processes do, instead of one group each (``--only session-floor`` of
benchmarks/pipeline_latency.py: separate sessions double the floor's p99 at load 8-12)."""

from __future__ import annotations

import json
import os
import sys

import pytest
from bnptrack.pipeline.supervisor import StageProcess


@pytest.mark.slow  # a process of its own (signals, exit, a child interpreter)
def test_a_stage_runs_in_its_own_process_group_and_the_launchers_session(tmp_path):
    probe = "import json, os; print(json.dumps([os.getpid(), os.getpgid(0), os.getsid(0)]))"
    sp = StageProcess("tracker", [sys.executable, "-c", probe], tmp_path / "tracker.log")
    sp.start(dict(os.environ))
    assert sp.proc.wait(60) == 0
    line = sp.log_path.read_text().strip().splitlines()[-1]
    pid, pgid, sid = json.loads(line)
    assert pid == sp.pid
    assert pgid == pid != os.getpgid(0)  # its own group: the terminal's signals go to the launcher's
    assert sid == os.getsid(0) != pid  # the launcher's session (a session leader would have sid == pid)
