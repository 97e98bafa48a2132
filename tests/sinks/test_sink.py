"""The sink interface (sinks/sink.py): the protocol, the table of sinks, SinkSet's order and
closing on errors, and the MCAP and Rerun entries."""

from __future__ import annotations

import os

os.environ.setdefault("CI", "1")  # before `import rerun`: no analytics from any rerun subprocess

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bnptrack.tracker.messages import encode, from_truth  # noqa: E402
from bnptrack.sinks.metrics import ospa  # noqa: E402
from bnptrack.sinks.sink import SINKS, SinkEntry, SinkSet, UnknownSink, make_sink  # noqa: E402
from bnptrack.sinks.records import Payloads, Sink, SinkOptions, SinkRecord  # noqa: E402
from bnptrack.sources.mcap_log import iter_frames, iter_tracks, read_metadata  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp import make_tracker  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402

N_FRAMES = 12
META = {"scenario": "vo2017", "tracker": "ddp", "seed": "1"}


class FakeSink:
    """Notes every call as (name, what, detail) in a shared list; fails where told."""

    def __init__(self, name: str, events: list, fail: str = "") -> None:
        self.name, self.events, self.fail = name, events, fail

    def _note(self, what: str, detail: object = None) -> None:
        self.events.append((self.name, what, detail))
        if what == self.fail:
            raise OSError(f"{self.name}: {what} failed")

    def open(self, metadata):
        self._note("open", dict(metadata) if metadata is not None else None)

    def write(self, record):
        self._note("write", record.frame)

    def close(self):
        self._note("close")


def _record(k: int) -> SinkRecord:
    return SinkRecord(frame=k)  # type: ignore[arg-type]  # the fakes only pass it on


# --------------------------------------------------------------------------- protocol and SinkSet


def test_fake_and_table_sinks_satisfy_the_protocol(tmp_path):
    assert isinstance(FakeSink("a", []), Sink)
    for name in SINKS:
        assert isinstance(make_sink(name, SinkOptions(tmp_path / f"x.{name}")), Sink)


def test_sinkset_order_open_write_close():
    ev: list = []
    with SinkSet([FakeSink("a", ev), FakeSink("b", ev)]) as sinks:
        sinks.open({"k": "v"})
        sinks.write(_record(1))
        sinks.write(_record(2))
    assert ev == [("a", "open", {"k": "v"}), ("b", "open", {"k": "v"}),
                  ("a", "write", 1), ("b", "write", 1), ("a", "write", 2), ("b", "write", 2),
                  ("b", "close", None), ("a", "close", None)]


def test_sinkset_failed_open_closes_those_open_and_skips_the_rest():
    ev: list = []
    sinks = SinkSet([FakeSink("a", ev), FakeSink("b", ev, fail="open"), FakeSink("c", ev)])
    with pytest.raises(OSError, match="b: open failed"):
        sinks.open(None)
    assert ev == [("a", "open", None), ("b", "open", None), ("a", "close", None)]
    sinks.close()  # idempotent: nothing is closed twice
    assert ev[-1] == ("a", "close", None) and len(ev) == 3


def test_sinkset_write_error_still_closes_every_sink():
    ev: list = []
    with pytest.raises(OSError, match="a: write failed"):
        with SinkSet([FakeSink("a", ev, fail="write"), FakeSink("b", ev)]) as sinks:
            sinks.open({})
            sinks.write(_record(7))
    assert ev == [("a", "open", {}), ("b", "open", {}), ("a", "write", 7),
                  ("b", "close", None), ("a", "close", None)]


def test_sinkset_close_error_closes_the_others_then_raises_the_first():
    ev: list = []
    sinks = SinkSet([FakeSink("a", ev, fail="close"), FakeSink("b", ev, fail="close"), FakeSink("c", ev)])
    sinks.open({})
    with pytest.raises(OSError, match="b: close failed") as info:
        sinks.close()
    assert str(info.value) == "b: close failed"  # reverse order: c, b (first error), a
    assert [e for e in ev if e[1] == "close"] == [("c", "close", None), ("b", "close", None),
                                                   ("a", "close", None)]


# --------------------------------------------------------------------------- the table


def test_make_sink_from_a_table_entry_and_unknown_names(tmp_path):
    made: list[SinkOptions] = []

    def factory(options: SinkOptions) -> FakeSink:
        made.append(options)
        return FakeSink("csv", [])

    table = {"csv": SinkEntry(factory, "a CSV file")}
    sink = make_sink("csv", SinkOptions(str(tmp_path / "run.csv"), run_id="r1"), table)
    assert isinstance(sink, FakeSink)
    assert made == [SinkOptions(tmp_path / "run.csv", run_id="r1")]
    assert isinstance(made[0].path, Path)
    with pytest.raises(UnknownSink, match=r"unknown sink 'csv' \(known: foxglove, mcap, rerun\)"):
        make_sink("csv", SinkOptions(tmp_path / "x"))
    assert sorted(SINKS) == ["foxglove", "mcap", "rerun"]


# --------------------------------------------------------------------------- the entries


@pytest.fixture(scope="module")
def vo_run():
    params = load_params("vo2017")
    frames = simulate_all(get_scenario("vo2017"), params, 1)[:N_FRAMES]
    estimates = [est for _f, est, _s in run(make_tracker("ddp-mb", params), frames, 0)]
    return params, frames, estimates


def _payloads(frame, est) -> Payloads:
    truth = encode(from_truth(frame.frame, frame.stamp_ns, frame.truth)) if frame.truth is not None else None
    return Payloads(frame.stamp_ns, frame.frame, encode(frame), truth, encode(est))


def test_mcap_sink_payloads_and_decoded_records_write_the_same_file(vo_run, tmp_path):
    _params, frames, estimates = vo_run
    paths = []
    for raw in (False, True):
        path = tmp_path / f"raw{int(raw)}" / "tracks.mcap"
        with SinkSet([make_sink("mcap", SinkOptions(path))]) as sinks:
            sinks.open(META)
            for f, e in zip(frames, estimates):
                sinks.write(SinkRecord(f, e, payloads=_payloads(f, e) if raw else None))
        paths.append(path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert read_metadata(paths[0]) == META
    back = list(iter_frames(paths[0]))
    assert [f.frame for f in back] == [f.frame for f in frames]
    for a, b in zip(back, frames):
        np.testing.assert_array_equal(a.z, b.z)
        np.testing.assert_array_equal(a.truth.positions, b.truth.positions)
    assert [e.labels for e in iter_tracks(paths[0])] == [e.labels for e in estimates]


def test_mcap_sink_without_metadata_writes_no_record(vo_run, tmp_path):
    _params, frames, estimates = vo_run
    sink = make_sink("mcap", SinkOptions(tmp_path / "t.mcap"))
    sink.open(None)
    sink.write(SinkRecord(frames[0], estimates[0]))
    sink.close()
    assert read_metadata(tmp_path / "t.mcap") is None
    assert [f.frame for f in iter_frames(tmp_path / "t.mcap")] == [frames[0].frame]


def _rrd_by_frame(path: Path, entity: str, column: str) -> dict[int, object]:
    from rerun.chunk import RrdReader

    out: dict[int, object] = {}
    for chunk in RrdReader(path).stream():
        if chunk.entity_path != entity:
            continue
        rb = chunk.to_record_batch()
        if "frame" in rb.schema.names and column in rb.schema.names:
            for f, v in zip(rb.column("frame").to_pylist(), rb.column(column).to_pylist()):
                if v is not None:
                    out[f] = v
    return out


def test_rerun_entry_scores_records_and_skips_those_without_estimate(vo_run, tmp_path):
    params, frames, estimates = vo_run
    path = tmp_path / "run.rrd"
    sink = make_sink("rerun", SinkOptions(path, params=params, run_id="run-1"))
    sink.open(META)
    for i, (f, e) in enumerate(zip(frames, estimates)):
        sink.write(SinkRecord(f, None if i == 3 else e))  # frame 4: no tracker output
    sink.close()
    rec = _rrd_by_frame(path, "/metrics/ospa", "Scalars:scalars")
    want = {f.frame: ospa(f.truth.positions, e.positions, c=100.0, p=1.0)
            for i, (f, e) in enumerate(zip(frames, estimates)) if i != 3}
    assert set(rec) == set(want) and frames[3].frame not in rec
    for k, o in want.items():
        assert rec[k] == [o.total, o.localisation, o.cardinality]  # exact


def test_rerun_entry_logs_the_callers_scores_and_health(vo_run, tmp_path):
    params, frames, estimates = vo_run
    path = tmp_path / "run.rrd"
    sink = make_sink("rerun", SinkOptions(path, params=params))
    sink.open(None)
    fake = ospa(np.zeros((1, 2)), np.array([[3.0, 4.0]]), c=100.0, p=1.0)  # 5 m, 0 cardinality
    sink.write(SinkRecord(frames[0], estimates[0], scores={"ospa": fake, "ospa2": 0.25},
                          health={"received": 9.0}))
    sink.close()
    assert _rrd_by_frame(path, "/metrics/ospa", "Scalars:scalars") == {frames[0].frame: [5.0, 5.0, 0.0]}
    assert _rrd_by_frame(path, "/metrics/ospa2", "Scalars:scalars") == {frames[0].frame: [0.25]}
    assert _rrd_by_frame(path, "/health/received", "Scalars:scalars") == {frames[0].frame: [9.0]}
