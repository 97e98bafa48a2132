"""Extensibility: a new sink is one class plus one entry of
:data:`sinks.sink.SINKS`.  A CSV sink defined here (one row per track per frame), added as one
table entry, receives the same records from ``bnptrack track`` (offline, ``--sink csv``) and
from the pipeline's sink stage on the in-memory bus (``sink.outputs = ['csv']``); its rows are
checked against the ``/tracks`` of the MCAP log each run writes."""

from __future__ import annotations

import csv
import json
import threading
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.config import PipelineConfig, apply_pipeline_overrides, resolve_run
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, STAGES, SUMMARY_NAME, ManualClock, StageContext
from bnptrack.sinks.sink import SINKS, SinkEntry
from bnptrack.sinks.records import SinkOptions, SinkRecord
from bnptrack.sources.mcap_log import iter_frames, iter_tracks, read_metadata
from bnptrack.tracker.config import ConfigError

HEADER = ["frame", "n_measurements", "label", "x", "y", "scored"]


class CsvSink:
    """One row per track per frame: frame number, the frame's number of measurements, label,
    position (repr of the floats: exact), whether the record carried an OSPA; a first line
    ``# tracker=NAME`` from the run's metadata."""

    def __init__(self, options: SinkOptions) -> None:
        self.path = options.path
        self.file = None

    def open(self, metadata) -> None:
        self.file = open(self.path, "w", newline="")
        self.file.write(f"# tracker={(metadata or {}).get('tracker', '')}\n")
        self.rows = csv.writer(self.file)
        self.rows.writerow(HEADER)

    def write(self, record: SinkRecord) -> None:
        frame, est = record.frame, record.estimate
        if frame is None or est is None:
            return
        assert frame.frame == est.frame
        scored = record.scores is not None and record.scores.get("ospa") is not None
        for t in est.tracks:
            self.rows.writerow([est.frame, frame.n_measurements, t.label, repr(float(t.position[0])),
                                repr(float(t.position[1])), int(scored)])

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None


@pytest.fixture
def csv_entry(monkeypatch):
    """The one table entry that makes the CSV sink known."""
    monkeypatch.setitem(SINKS, "csv", SinkEntry(CsvSink, "one row per track per frame", "tracks.csv"))


def read_rows(path: Path) -> tuple[str, list[list[str]]]:
    first, *rest = path.read_text().splitlines()
    rows = list(csv.reader(rest))
    assert rows[0] == HEADER
    return first, rows[1:]


def expected_rows(mcap: Path) -> list[list[str]]:
    """The rows the CSV sink must have written, from the MCAP log's frames and /tracks."""
    n_meas = {f.frame: f.n_measurements for f in iter_frames(mcap)}
    return [[str(e.frame), str(n_meas[e.frame]), t.label, repr(float(t.position[0])),
             repr(float(t.position[1])), "1"]
            for e in iter_tracks(mcap) for t in e.tracks]


# --------------------------------------------------------------------------- offline


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_track_records_to_a_sink_added_by_one_table_entry(csv_entry, tmp_path):
    log, out = tmp_path / "vo.mcap", tmp_path / "vo-ddp.tracks.mcap"
    res = invoke("simulate", "--scenario", "vo2017", "--params", "vo2017", "--seed", 1, "--out", log)
    assert res.exit_code == 0, res.output
    res = invoke("track", log, "--tracker", "ddp-mb", "--set", "tracker.sweeps=8", "--set", "tracker.burn_in=2",
                 "--out", out, "--sink", "csv", "-q")
    assert res.exit_code == 0, res.output
    first, rows = read_rows(out.with_suffix(".csv"))  # next to --out, with the entry's suffix
    assert first == "# tracker=ddp-mb" and read_metadata(out)["tracker"] == "ddp-mb"
    want = expected_rows(out)
    assert rows == want
    assert len({r[0] for r in rows}) > 50  # the frames with tracks, of 100 (vo2017)
    assert len({r[2] for r in rows}) >= 3  # several labels


def test_an_unknown_sink_is_a_one_line_error_naming_the_table(csv_entry, tmp_path):
    res = invoke("track", tmp_path / "x.mcap", "--sink", "parquet")
    assert res.exit_code == 2
    assert "unknown sink 'parquet' (known: csv, foxglove, mcap, rerun)" in res.output
    with pytest.raises(ConfigError, match=r"sink.outputs: unknown sink 'parquet' \(known: csv, foxglove, mcap, rerun\)"):
        apply_pipeline_overrides(PipelineConfig(), ["sink.outputs=['parquet']"])


# --------------------------------------------------------------------------- the sink stage


def run_memory_pipeline(cfg: PipelineConfig, timeout: float = 120.0) -> dict[str, int]:
    """source -> tracker -> sink on the in-memory bus, in threads, on one ManualClock that
    stands still until the source's end of stream and then moves 1 s per poll."""
    net, clock = MemoryNetwork(), ManualClock()
    codes: dict[str, int] = {}
    errors: list[BaseException] = []

    def go(role: str) -> None:
        bus = net.bus(cfg.run, role)
        try:
            codes[role] = STAGES[role](StageContext(cfg, bus, name=role, clock=clock)).run()
        except BaseException as exc:  # surfaced below
            errors.append(exc)
        finally:
            bus.close()

    threads = [threading.Thread(target=go, args=(r,), daemon=True) for r in ("sink", "tracker", "source")]
    for t in threads:
        t.start()
    deadline = time.monotonic() + timeout
    while any(t.is_alive() for t in threads) and time.monotonic() < deadline:
        with net.lock:
            ended = any(r == cfg.run and t == "eos/source" for r, t, _, _ in net.history)
        if ended:
            clock.advance(1.0)
        threads[0].join(0.02)
    assert not errors, errors
    assert not any(t.is_alive() for t in threads), "a stage did not finish"
    return codes


def test_sink_stage_records_to_a_sink_added_by_one_table_entry(csv_entry, tmp_path):
    overrides = ["source.frames=12", "tracker.tracker=ddp-mb", "tracker.overrides=['sweeps=8', 'burn_in=2']", "sink.rerun=false",
                 "sink.outputs=['csv']", "delivery.eos_grace_s=0.3", "supervisor.linger_s=0.5"]
    cfg = resolve_run(apply_pipeline_overrides(PipelineConfig(run="csv", out=str(tmp_path / "out")), overrides))
    assert run_memory_pipeline(cfg) == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    out = Path(cfg.out)
    first, rows = read_rows(out / "tracks.csv")
    assert first == "# tracker=ddp-mb"
    assert rows == expected_rows(out / "tracks.mcap")
    assert len({r[0] for r in rows}) >= 6 and len({r[2] for r in rows}) >= 2  # frames, labels
    summary = json.loads((out / SUMMARY_NAME).read_text())
    assert summary["files"][:2] == [str(out / "tracks.mcap"), str(out / "tracks.csv")]
    assert not list(out.glob("*.part"))  # committed like tracks.mcap
