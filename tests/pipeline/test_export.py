"""bnptrack export RUN --csv / --parquet."""

from __future__ import annotations

import csv

import numpy as np
import pyarrow.parquet as pq
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.sources.mcap_log import iter_tracks


def test_export_rows_match_the_run(tmp_path):
    log, run = tmp_path / "vo.mcap", tmp_path / "vo-ddp.mcap"
    r = CliRunner()
    assert r.invoke(main, ["simulate", "--seed", "1", "--out", str(log), "-q"]).exit_code == 0
    res = res_track = r.invoke(main, ["track", str(log), "--tracker", "ddp-mb", "--set", "tracker.sweeps=8",
                                         "--set", "tracker.burn_in=2", "--out", str(run)])
    assert res.exit_code == 0, res.output
    printed_ospa = float(res.output.split("mean OSPA")[1].split()[0])
    res = r.invoke(main, ["export", str(run), "--csv", str(tmp_path / "t.csv"), "--parquet", str(tmp_path / "t.parquet")])
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader(open(tmp_path / "t.csv")))
    ests = list(iter_tracks(run))
    assert len(rows) == sum(len(e.tracks) for e in ests)
    first = next(e for e in ests if e.tracks)
    t = first.tracks[0]
    row = rows[0]
    assert int(row["frame"]) == first.frame and row["label"] == t.label
    # one display name everywhere: the export's, the summary's and the Python API's
    assert all(r["name"] == f"T{r['label']}" for r in rows) and row["name"] == t.name
    last = [tr.name for tr in ests[-1].tracks]
    assert last and f"final tracks      {len(last)}: {' '.join(last[:12])}" in res_track.output
    np.testing.assert_allclose([float(row[k]) for k in ("px", "vx", "py", "vy", "omega")], t.state, rtol=1e-15)
    np.testing.assert_allclose(float(row["var_py"]), t.covariance[2, 2], rtol=1e-15)
    assert float(row["existence"]) == t.existence
    assert all(r["cluster"] == "" for r in rows)  # a one-level tracker: no motion cluster
    metrics = list(csv.DictReader(open(tmp_path / "t.metrics.csv")))
    assert len(metrics) == 100
    assert abs(np.mean([float(m["ospa"]) for m in metrics]) - printed_ospa) <= 0.005  # printed with 2 decimals
    table = pq.read_table(tmp_path / "t.parquet")
    assert table.num_rows == len(rows) and table.column_names[:4] == ["frame", "stamp_ns", "label", "name"]
    assert table.column("name").to_pylist() == [r["name"] for r in rows]


def test_export_has_each_track_s_motion_cluster(tmp_path):
    log, run = tmp_path / "vo.mcap", tmp_path / "vo-ddp.mcap"
    r = CliRunner()
    assert r.invoke(main, ["simulate", "--seed", "1", "--out", str(log), "-q"]).exit_code == 0
    assert r.invoke(main, ["track", str(log), "--tracker", "ddp", "--end", "30f", "--out", str(run), "-q"]).exit_code == 0
    assert r.invoke(main, ["export", str(run), "--csv", str(tmp_path / "t.csv"),
                           "--parquet", str(tmp_path / "t.parquet")]).exit_code == 0
    want = [t.cluster for e in iter_tracks(run) for t in e.tracks]
    assert sum(c is not None for c in want) > len(want) // 2
    assert [None if row["cluster"] == "" else int(row["cluster"])
            for row in csv.DictReader(open(tmp_path / "t.csv"))] == want
    assert pq.read_table(tmp_path / "t.parquet").column("cluster").to_pylist() == want


def test_export_needs_tracks(tmp_path):
    log = tmp_path / "vo.mcap"
    r = CliRunner()
    assert r.invoke(main, ["simulate", "--seed", "1", "--out", str(log), "-q"]).exit_code == 0
    res = r.invoke(main, ["export", str(log), "--csv", str(tmp_path / "t.csv")])
    assert res.exit_code == 2 and "has no /tracks" in res.output
