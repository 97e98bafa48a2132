"""The tracker stage imports the large frames' modules (``LAZY_IMPORTS``: scipy.spatial,
scipy.sparse.csgraph) in the background once a frame is large, not before it declares itself
ready (0.4-0.75 s of CPU on the launch's critical path that no vo2017 frame needs)."""

from __future__ import annotations

import numpy as np
import pytest

import bnptrack.pipeline.stages.tracker as tracker_stage
import bnptrack.pipeline.stages.tracker_warmup as tracker_warmup
from bnptrack.pipeline.config import DeliveryConfig, PipelineConfig, TrackerStageConfig, resolve_run
from bnptrack.pipeline.events import Event
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import StageContext, TrackerStage
from bnptrack.pipeline.stages.tracker import LAZY_IMPORTS, LAZY_PAIRS, build_stage_tracker
from bnptrack.pipeline.stages.tracker_output import StageOutput
from bnptrack.sources.scenarios import get_scenario, scenario_params
from bnptrack.sources.synthetic import simulate
from bnptrack.tracker.messages import encode
from bnptrack.tracker.types import Frame

META = {"scenario": "vo2017", "params": "vo2017"}


@pytest.fixture()
def imports(monkeypatch):
    """The background imports the stage starts (the modules asked for), run in this thread,
    with LAZY_IMPORTS named as if none were imported yet."""
    asked: list[tuple[str, ...]] = []
    monkeypatch.setattr(tracker_stage, "warm_imports", lambda *mods: asked.append(mods))
    monkeypatch.setattr(tracker_stage, "LAZY_IMPORTS", ("bnptrack_not_imported_a", "bnptrack_not_imported_b"))
    return asked


def _stage(tmp_path):
    cfg = resolve_run(PipelineConfig(run="r", out=str(tmp_path), delivery=DeliveryConfig(),
                                     tracker=TrackerStageConfig(tracker="ddp", seed=3)))
    stage = TrackerStage(StageContext(cfg, MemoryNetwork().bus("r", "tracker"), name="tracker"))
    stage._restore()
    setup = build_stage_tracker(stage.tc, META)
    stage.tracker = setup.tracker
    stage.output = StageOutput(setup.tracker, setup.params, 0)
    stage.state = stage.tracker.initial_state()
    return stage


def _frame(k, m):
    """Frame ``k`` of ``m`` bearing-range measurements spread over the field."""
    z = np.column_stack([np.linspace(-1.0, 1.0, m), np.linspace(500.0, 4000.0, m)])
    return Frame(k, k * 10**9, "s", "bearing_range", z)


def _push(stage, frame, seq):
    stage._on_data(Event("measurements", encode(frame, "r"), {"seq": seq, "t": 1, "frame": frame.frame}, 2))
    if stage.lazy_importing is not None:
        stage.lazy_importing.join(5)


def test_the_stage_is_ready_without_the_large_frames_imports():
    assert LAZY_IMPORTS == ("scipy.sparse.csgraph", "scipy.spatial") and LAZY_PAIRS == 2_000
    # the preload before ready is numba's alone
    assert "warm_imports" not in tracker_warmup.preload_tracker.__code__.co_names


def test_vo2017_frames_never_start_the_imports(tmp_path, imports):
    stage = _stage(tmp_path)
    frames = list(simulate(get_scenario("vo2017"), scenario_params("vo2017", "vo2017"), 1))
    assert max(len(f.z) for f in frames) == 32  # 32 x 32 = 1024 < LAZY_PAIRS
    for seq, frame in enumerate(frames[:30]):
        _push(stage, frame, seq)
    assert stage.counters.processed == 30
    assert imports == [] and stage.lazy_importing is None
    stage._close_journal()


def test_a_large_frame_starts_them_once_before_its_step(tmp_path, imports):
    stage = _stage(tmp_path)
    started_at: list[int] = []

    class Noting:  # the tracker, noting what had been asked when each step ran
        def __init__(self, tracker):
            self.tracker = tracker

        def step(self, state, frame, rng):
            started_at.append(len(imports))
            return self.tracker.step(state, frame, rng)

    stage.tracker = Noting(stage.tracker)
    stage.output = StageOutput(stage.tracker, None, 0)
    _push(stage, _frame(1, 44), 0)  # 44 x 44 = 1936 < 2000: nothing yet
    assert imports == [] and started_at == [0]
    _push(stage, _frame(2, 45), 1)  # 45 x 45 = 2025: started before the frame's step
    assert imports == [("bnptrack_not_imported_a", "bnptrack_not_imported_b")]
    assert started_at == [0, 1] and stage.lazy_importing.name == "lazy-imports"
    _push(stage, _frame(3, 60), 2)  # once
    assert len(imports) == 1 and stage.counters.processed == 3
    stage._close_journal()


def test_the_previous_frames_tracks_count(tmp_path, imports):
    stage = _stage(tmp_path)
    stage.last_tracks = 100  # 20 measurements x 100 tracks = 2000
    assert stage._lazy_imports_due(_frame(5, 20))
    assert not stage._lazy_imports_due(_frame(5, 19))
    stage._close_journal()


def test_nothing_starts_when_they_are_imported_already(tmp_path, monkeypatch):
    monkeypatch.setattr(tracker_stage, "LAZY_IMPORTS", ("numpy", "json"))
    stage = _stage(tmp_path)
    assert not stage._lazy_imports_due(_frame(1, 200))
    stage._close_journal()
