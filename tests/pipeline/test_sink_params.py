"""The sink draws with the model parameters the tracker resolved (one resolver), not with a
second resolution of its own: a log's overrides, scenario defaults and the tracker's ``--set``
items all reach it."""

from __future__ import annotations

import msgspec

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.resolve import resolve_params, tracker_setup
from bnptrack.pipeline.stages import SinkStage, StageInfo
from testkit import ListSink, mem_cfg, run_memory_pipeline
from bnptrack.tracker.models.params import ModelParams

RECORD = {"scenario": "vo2017", "params": "vo2017", "overrides": "range_max=3000", "seed": "1"}


def test_the_sink_uses_the_params_the_tracker_announced():
    setup = tracker_setup("ddp", overrides=("params.bearing_half_fov_deg=45",), metadata=RECORD)
    info = StageInfo(stage="tracker", run="r", metadata=setup.metadata, params=msgspec.to_builtins(setup.params))
    wire = msgspec.json.decode(msgspec.json.encode(info), type=StageInfo)
    got = SinkStage._params(wire.metadata, wire)
    assert got == setup.params
    assert (got.range_max, got.bearing_half_fov_deg, len(got.birth)) == (3000.0, 45.0, 4)


def test_without_a_tracker_the_sink_resolves_the_input_record_once():
    got = SinkStage._params(RECORD, None)
    assert got == resolve_params(None, RECORD).params
    assert (got.range_max, got.bearing_half_fov_deg) == (3000.0, 90.0)


def test_the_tracker_stage_announces_its_resolved_params(tmp_path):
    cfg = mem_cfg(tmp_path, frames=3, **{"source.overrides": "['range_max=3000']",
                                         "tracker.overrides": "['sweeps=8', 'burn_in=2', 'params.bearing_half_fov_deg=45']"})
    net = MemoryNetwork()
    run_memory_pipeline(cfg, net)
    infos = [msgspec.json.decode(p, type=StageInfo) for p in ListSink(net, cfg.run).payloads("info/tracker")]
    assert infos, "the tracker published no info"
    params = msgspec.convert(infos[-1].params, ModelParams)
    assert (params.range_max, params.bearing_half_fov_deg) == (3000.0, 45.0)
