"""The tracker stage imports before it is ready what a step would import on first need
(issue 16: a first ``scipy.optimize`` import inside frame 3's step, 0.2-0.7 s, queued the
frames behind it and made the paced run's added-latency p99)."""

from __future__ import annotations

import json
import subprocess
import sys

from testkit import REPO_ROOT, bnptrack_env

# In a fresh interpreter (sys.modules must start clean): build and warm the stage's tracker
# as the stage does, then step it over the first 40 frames of vo2017 seed 1 (which hold two
# clusters preferring one measurement at frame 3) and list the modules those steps imported.
_PROBE = r"""
import json, sys
from pipeline.config import TrackerStageConfig
from pipeline.stages.tracker import {preload}build_stage_tracker, warm_up_tracker
from sources.scenarios import get_scenario, scenario_params
from sources.synthetic import simulate
from tracker.state import tracker_frame_rng
frames = list(simulate(get_scenario("vo2017"), scenario_params("vo2017", "vo2017"), 1))[:40]
setup = build_stage_tracker(TrackerStageConfig(tracker="ddp"), {{"scenario": "vo2017", "params": "vo2017"}})
{call}
warm_up_tracker(setup.tracker)
before = set(sys.modules)
state = setup.tracker.initial_state()
for f in frames:
    state, _ = setup.tracker.step(state, f, tracker_frame_rng(0, f.frame))
print(json.dumps(sorted(m for m in set(sys.modules) - before if m.startswith("scipy"))))
"""


def _imported_by_steps(preload: bool) -> list[str]:
    code = _PROBE.format(preload="preload_tracker, " if preload else "",
                         call="preload_tracker()" if preload else "")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, env=bnptrack_env(),
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_after_the_stage_preload_the_first_frames_import_nothing():
    # without the preload, the steps import scipy.optimize (the probe can see the fault) ...
    assert "scipy.optimize" in _imported_by_steps(preload=False)
    # ... with it, nothing
    assert _imported_by_steps(preload=True) == []
