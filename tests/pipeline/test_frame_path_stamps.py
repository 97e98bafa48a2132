"""The frame path's time stamps: the tracker's /tracks
attachment says when its main thread took the frame off the bus (``t_deq``, between the
receipt ``t_in`` and the publication ``t_out``), and the sink's ``sink.json`` splits the
first hop: the tracker's hand-off (``t_deq - t_in``) and the same /measurements sample's hop
to the sink."""

from __future__ import annotations

import json
from pathlib import Path

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, SUMMARY_NAME

from testkit import ListSink
from testkit import mem_cfg as _mem_cfg
from testkit import run_memory_pipeline as _run_memory_pipeline


def test_tracks_carry_the_dequeue_stamp_and_the_sink_records_the_splits(tmp_path):
    cfg = _mem_cfg(tmp_path, frames=6)
    net = MemoryNetwork()
    codes = _run_memory_pipeline(cfg, net, timeout=120)
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    metas = [json.loads(a) for _, a in ListSink(net, cfg.run).samples("tracks")]
    assert [m["seq"] for m in metas] == list(range(6))
    # t_deq and t_out come from the stage's clock (a ManualClock here): never out of order
    assert all(isinstance(m["t_deq"], int) and 0 < m["t_deq"] <= m["t_out"] for m in metas)
    lat = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())["latency"]
    assert len(lat["tracker_handoff_ms"]) == 6
    assert lat["tracker_handoff_ms"] == [(m["t_deq"] - m["t_in"]) / 1e6 for m in metas]
    assert len(lat["source_to_sink_measurements_ms"]) == 6
