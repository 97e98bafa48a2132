"""The stage-level fakes and the waiting helper of tests/testkit.py: ``ListSource`` feeds the
tracker and sink stages exactly what the source stage would (so a stage can be tested
without its upstream), ``ListSink`` collects what the stages publish, ``wait_until`` fails
with the awaited condition named."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, SUMMARY_NAME, source_frames
from bnptrack.sources.mcap_log import read_log

from testkit import ListSink, ListSource, mem_cfg, offline, run_memory_pipeline, strip, wait_until


def test_list_source_feeds_the_tracker_and_sink_stages_like_the_source_stage(tmp_path):
    """The frames of the synthetic source, fed by a ListSource instead of the source stage:
    the recording and the tracks equal the offline run, and the samples on the wire are those
    the source stage publishes (same payloads, same seq/frame attachments)."""
    cfg = mem_cfg(tmp_path, frames=8)
    meta, frames = source_frames(cfg)
    frames = list(frames)
    net = MemoryNetwork()
    ListSource.of_frames(net, cfg.run, frames, metadata=meta).publish()
    codes = run_memory_pipeline(cfg, net, roles=("sink", "tracker"))
    assert codes == {"sink": EXIT_OK, "tracker": EXIT_OK}
    log = read_log(Path(cfg.out) / "tracks.mcap")
    want_frames, ests = offline(cfg)
    assert [f.frame for f in log.frames] == [f.frame for f in want_frames] == list(range(1, 9))
    assert all(np.array_equal(a.z, b.z) for a, b in zip(log.frames, want_frames, strict=True))
    assert [strip(e) for e in log.tracks] == [strip(e) for e in ests]
    assert json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())["complete"]
    # the same samples as the real source stage
    real = MemoryNetwork()
    alone = mem_cfg(tmp_path / "real", frames=8, **{"source.wait_for": "[]", "source.done_by": "[]"})
    assert run_memory_pipeline(alone, real, roles=("source",)) == {"source": EXIT_OK}
    for topic in ("measurements", "truth"):
        fake, live = ListSink(net, cfg.run).samples(topic), ListSink(real, cfg.run).samples(topic)
        assert [p for p, _ in fake] == [p for p, _ in live] and len(fake) == 8
        assert [{k: v for k, v in json.loads(a).items() if k != "t"} for _, a in fake] == \
               [{k: v for k, v in json.loads(a).items() if k != "t"} for _, a in live]
    [eos] = ListSink(net, cfg.run).docs("eos/source", msgspec.json.decode)
    assert eos["last_seq"] == 7 and eos["frames"] == 8


def test_list_sink_collects_published_samples_and_the_wire_of_one_run():
    sink = ListSink()
    sink.publish("deadletter", b'{"stage":"tracker"}', {"seq": 3})
    sink.publish("tracks", b"{}")
    assert sink.docs("deadletter") == [{"stage": "tracker"}]
    assert sink.samples("deadletter") == [(b'{"stage":"tracker"}', b'{"seq": 3}')]
    net = MemoryNetwork()
    net.tap = lambda run, topic, payload, att: [] if payload == b"[2]" else [(payload, att)]  # lost on the way
    ListSource(net, "a", [("x", b"[1]", {"seq": 0}), ("x", b"[2]", {"seq": 1}), ("y", b"[3]", None)]).publish()
    ListSource(net, "b", [("x", b"[9]", None)]).publish()
    assert ListSink(net, "a").docs("x") == [[1]] and ListSink(net, "a").payloads("y") == [b"[3]"]
    assert ListSink(net).docs("x") == [[1], [9]]  # every run


def test_wait_until_returns_the_value_and_names_what_it_waited_for():
    flag = threading.Event()
    threading.Timer(0.05, flag.set).start()
    assert wait_until(lambda: flag.is_set() and "set", 10, "the flag") == "set"
    t0 = time.monotonic()
    with pytest.raises(AssertionError, match=r"timed out after 0.1 s waiting for the impossible"):
        wait_until(lambda: False, 0.1, "the impossible")
    assert time.monotonic() - t0 >= 0.1
    with pytest.raises(AssertionError, match="gave up waiting for the file: the awaited party ended first"):
        wait_until(lambda: False, 60, "the file", abort=lambda: True)
