"""The tracker stage imports before it is ready what a step would import on first need
(a first ``scipy.optimize`` import inside frame 3's step, 0.2-0.7 s, would queue the frames
behind it and make the paced run's added-latency p99)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from testkit import REPO_ROOT, bnptrack_env

# In a fresh interpreter (sys.modules must start clean): build and warm the stage's tracker
# as the stage does, then step it over the first 40 frames of vo2017 seed 1 (which hold two
# clusters preferring one measurement at frame 3) and list the modules those steps imported.
_PROBE = r"""
import json, sys
from bnptrack.pipeline.config import TrackerStageConfig
from bnptrack.pipeline.stages.tracker import build_stage_tracker
from bnptrack.pipeline.stages.tracker_warmup import {preload}warm_up_tracker
from bnptrack.sources.scenarios import get_scenario, scenario_params
from bnptrack.sources.synthetic import simulate
from bnptrack.tracker.state import tracker_frame_rng
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


@pytest.mark.slow
def test_after_the_stage_preload_the_first_frames_import_nothing():
    # the compiled DDP-EMM step (its JPDA* assignment does not call scipy's
    # linear_sum_assignment) imports nothing even without the preload ...
    assert _imported_by_steps(preload=False) == []
    # ... with it, nothing
    assert _imported_by_steps(preload=True) == []


def test_the_stream_built_ahead_is_the_frames_own_and_is_used_once(tmp_path):
    """The tracker stage builds frame k+1's generator after frame k's tracks are out; frame k+1
    gets exactly ``tracker_frame_rng(seed, k + 1)``, and any other frame (a jump) a fresh one."""
    import numpy as np

    from bnptrack.pipeline.config import PipelineConfig, TrackerStageConfig, resolve_run
    from bnptrack.pipeline.membus import MemoryNetwork
    from bnptrack.pipeline.stages import StageContext, TrackerStage
    from bnptrack.tracker.state import tracker_frame_rng

    cfg = resolve_run(PipelineConfig(run="r", out=str(tmp_path), tracker=TrackerStageConfig(seed=7)))
    stage = TrackerStage(StageContext(cfg, MemoryNetwork().bus("r", "tracker"), name="tracker"))

    def draws(rng):
        return rng.random(4).tolist()

    want = {k: draws(tracker_frame_rng(7, k)) for k in (5, 6, 9)}
    stage.next_rng = (5, tracker_frame_rng(7, 5))
    ahead = stage.next_rng[1]
    got5 = stage._frame_rng(5)
    assert got5 is ahead and draws(got5) == want[5]
    assert stage.next_rng is None  # used once
    stage.next_rng = (6, tracker_frame_rng(7, 6))
    got9 = stage._frame_rng(9)  # a jump: the stream built ahead is not used
    assert draws(got9) == want[9] and stage.next_rng is None
    assert draws(stage._frame_rng(6)) == want[6]
    assert not np.allclose(want[5], want[6])
