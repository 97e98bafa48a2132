"""The tracker stage's warm-up reaches every compiled kernel the tracker hits on real scenes
(otherwise the contested JPDA* assignment is first compiled at vo2017's frame 4 inside a paced
run, a 2.5 s stall on a cold kernel cache and 23-40 ms on a warm one; the two-level trackers'
group kernels at frames 2-23)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from testkit import REPO_ROOT, bnptrack_env

# In a fresh interpreter (no kernel called yet): build the stage's tracker as the stage does,
# warm it up (the stage's warm-up, or with {contests}=False the registry's alone), count each
# kernel's compiled signatures, step it over two scenes and list the kernels that gained one.
_PROBE = r"""
import json
from bnptrack.pipeline.config import TrackerStageConfig
import bnptrack.pipeline.stages.tracker_warmup as warmup
from bnptrack.pipeline.stages.tracker import build_stage_tracker
from bnptrack.pipeline.stages.tracker_warmup import warm_up_tracker
from bnptrack.sources.scenarios import get_scenario, scenario_params
from bnptrack.sources.synthetic import simulate
from bnptrack.tracker.numerics import JIT
from bnptrack.tracker.state import tracker_frame_rng
assert JIT, "numba must be on: the check counts compiled kernels"
if not {contests}:
    warmup.warm_up_contests = lambda tracker: None
setup = build_stage_tracker(TrackerStageConfig(tracker={tracker!r}), {{"scenario": {scene!r}, "params": "vo2017"}})
warm_up_tracker(setup.tracker)
before = warmup.compiled_kernels()
late = set()
for seed in (1, 2):
    state = setup.tracker.initial_state()
    for f in simulate(get_scenario({scene!r}), scenario_params({scene!r}, "vo2017"), seed):
        state, _ = setup.tracker.step(state, f, tracker_frame_rng(0, f.frame))
        after = warmup.compiled_kernels()
        late |= {{k for k, n in after.items() if n > before.get(k, 0)}}
print(json.dumps({{"late": sorted(late), "ready": sum(1 for n in before.values() if n)}}))
"""


def _late_kernels(tracker: str, scene: str, contests: bool = True) -> dict:
    code = _PROBE.format(tracker=tracker, scene=scene, contests=contests)
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, env=bnptrack_env(),
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("tracker,scene", [("ddp", "vo2017"), ("dpyp", "proximity"), ("ddp-groups", "proximity")])
def test_no_kernel_is_compiled_after_the_stage_warm_up(tracker, scene):
    got = _late_kernels(tracker, scene)
    assert got["late"] == [], got
    assert got["ready"] >= 10  # the count sees the kernels (not an empty table)


@pytest.mark.slow
def test_without_the_contests_a_kernel_is_compiled_inside_a_frame():
    """The check above is not blind: with the registry's warm-up alone the scenes compile the
    single level's contested assignment (JPDA*), the default's velocity and turn sharing and the
    two-level tracker's group kernels inside a frame."""
    assert "bnptrack.tracker.bnp._update_kernels.jpda_solve" in _late_kernels("ddp-mb", "vo2017", contests=False)["late"]
    assert "bnptrack.tracker.bnp.group_share._share_turn_kernel" in _late_kernels("ddp", "vo2017", contests=False)["late"]
    late = _late_kernels("ddp-groups", "proximity", contests=False)["late"]
    assert "bnptrack.tracker.bnp.group_partition.gated_kernel" in late


def test_contest_frames_close_in_then_share_one_measurement():
    from bnptrack.pipeline.stages.tracker_warmup import BORN_FRAMES, CONTEST, EMPTY_FRAMES, contest_frames

    frames = list(contest_frames("bearing_range", (0.1, 500.0), 16.0))
    # 5 frames 200 m apart, then 180, 160 (closest 16 units = 160 m), 2 frames of the middle, 3 empty
    assert [f.frame for f in frames] == list(range(1, 13))
    assert len(frames) == BORN_FRAMES + 2 + CONTEST + EMPTY_FRAMES
    assert frames[0].stamp_ns == 10**9 and frames[-1].stamp_ns == 12 * 10**9
    np.testing.assert_allclose(frames[0].z, [[0.1, 400.0], [0.1, 600.0]])
    np.testing.assert_allclose(frames[4].z, [[0.1, 400.0], [0.1, 600.0]])
    np.testing.assert_allclose(frames[5].z, [[0.1, 410.0], [0.1, 590.0]])
    np.testing.assert_allclose(frames[6].z, [[0.1, 420.0], [0.1, 580.0]])
    np.testing.assert_allclose(frames[7].z, [[0.1, 500.0]])
    np.testing.assert_allclose(frames[8].z, [[0.1, 500.0]])
    assert all(f.z.shape == (0, 2) for f in frames[9:])
    assert {f.kind for f in frames} == {"bearing_range"}
