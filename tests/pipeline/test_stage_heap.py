"""The stages freeze their start-up heap before they declare themselves ready (otherwise the
first full garbage collections of the tracker and sink stages, 88 and 116 ms with the
modules' and the warm-up's objects, fall among the first frames of a paced run)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from testkit import REPO_ROOT, bnptrack_env

# In a fresh interpreter (nothing frozen yet): a tracker stage on the in-memory bus gets the
# source's info message, builds and warms its tracker and declares itself ready; the probe
# prints how many objects were frozen before and after, and whether the stage is ready.
_PROBE = r"""
import gc, json
from bnptrack.pipeline.config import PipelineConfig, TrackerStageConfig, resolve_run
from bnptrack.pipeline.events import Event
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import StageContext, StageInfo, TrackerStage
from bnptrack.pipeline.stages.health import _JSON
cfg = resolve_run(PipelineConfig(run="r", out={out!r}, tracker=TrackerStageConfig(tracker="ddp")))
net = MemoryNetwork()
stage = TrackerStage(StageContext(cfg, net.bus("r", "tracker"), name="tracker"))
stage._restore()
before = gc.get_freeze_count()
info = StageInfo(stage="source", run="r", kind="sim", metadata={{"scenario": "vo2017", "params": "vo2017"}})
stage._on_event(Event("info/source", _JSON.encode(info), None, 0))
after = gc.get_freeze_count()
ready = "tracker" in net.bus("r", "probe").alive("ready")
print(json.dumps([before, after, ready]))
"""


@pytest.mark.slow
def test_the_tracker_stage_freezes_its_heap_when_it_becomes_ready(tmp_path):
    out = subprocess.run([sys.executable, "-c", _PROBE.format(out=str(tmp_path))], cwd=REPO_ROOT,
                         env=bnptrack_env(), capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    before, after, ready = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == 0  # nothing frozen until the tracker is built
    assert ready
    # the modules, numba's tables and the warmed tracker: far more than a bare interpreter's
    assert after > 50_000


def test_garbage_made_after_the_freeze_is_still_collected():
    import gc

    from bnptrack.pipeline.stages.base import settle_heap

    frozen = gc.get_freeze_count()
    settle_heap()
    assert gc.get_freeze_count() >= frozen
    try:
        a: list = []
        a.append(a)  # a cycle made after the freeze
        del a
        assert gc.collect() >= 1
    finally:
        gc.unfreeze()  # leave the test process as it was
