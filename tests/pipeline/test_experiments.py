"""Monte Carlo experiments: per-run reproducibility, local vs Dask equality, outputs."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.pipeline.experiment_plots import write_plots
from bnptrack.pipeline.experiments import (
    EXPERIMENTS,
    RunJob,
    Variant,
    execute_run,
    get_experiment,
    run_jobs,
    run_seed,
    summary_rows,
    write_summary,
)
from bnptrack.tracker.config import ConfigError

JOBS = [RunJob("dpy-vs-ddp", 7, i, "vo2017", Variant("default"), keep_tracks=(i == 0)) for i in range(2)]


def same(a, b) -> bool:
    return all(
        np.array_equal(getattr(a.trackers[t], f), getattr(b.trackers[t], f))
        for t in a.trackers for f in ("ospa", "ospa2", "gospa", "n_est")
    ) and np.array_equal(a.n_true, b.n_true)


def test_experiments_cover_the_paper():
    assert set(EXPERIMENTS) == {"ddp-vs-glmb", "proximity", "snr", "dpy-vs-glmb", "dpy-vs-ddp", "random"}
    assert [v.label for v in get_experiment("snr").variants] == ["-3 dB", "-5 dB", "-10 dB"]
    with pytest.raises(ConfigError, match="unknown experiment"):
        get_experiment("nope")


def test_run_seed_depends_on_experiment_seed_and_index():
    seeds = {run_seed(e, s, i) for e in ("a", "b") for s in (1, 2) for i in range(3)}
    assert len(seeds) == 12
    assert run_seed("a", 1, 2) == run_seed("a", 1, 2)


@pytest.fixture(scope="module")
def local_results():
    return run_jobs(JOBS, workers=2)


@pytest.mark.slow
def test_single_run_redone_alone_is_identical(local_results):
    assert same(execute_run(JOBS[1]), local_results[1])


@pytest.mark.slow
def test_dask_cluster_gives_identical_results(local_results):
    import distributed  # a test dependency (pyproject [test], and the [dask] extra): fail, do not skip
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None, host="127.0.0.1") as cluster:
        dask_results = run_jobs(JOBS, cluster=cluster.scheduler_address)
    assert all(same(a, b) for a, b in zip(local_results, dask_results))


@pytest.mark.slow
def test_summary_and_plots(local_results, tmp_path):
    rows = summary_rows(local_results)
    assert [r["tracker"] for r in rows] == ["DPY-STP", "DPY-STP (mb)", "DDP-EMM", "DDP-EMM (mb)"]
    for r in rows:
        assert r["runs"] == 2 and 0 < r["ospa"] < 100 and r["ospa_loc"] + r["ospa_card"] == pytest.approx(r["ospa"])
    md, csv_path = write_summary(rows, tmp_path, "dpy-vs-ddp")
    text = md.read_text()
    assert "DPY-STP" in text and text.count("\n|") == 6
    assert csv_path.read_text().splitlines()[0].startswith("variant,tracker,runs,ospa")
    paths = write_plots(local_results, tmp_path, "dpy-vs-ddp")
    assert {p.name for p in paths} == {"cardinality.png", "ospa.png", "xy.png"}
    assert all(p.stat().st_size > 10_000 for p in paths)


@pytest.mark.slow
def test_experiment_command_writes_outputs(tmp_path):
    from click.testing import CliRunner

    from bnptrack.pipeline.cli import main

    out = tmp_path / "exp"
    res = CliRunner().invoke(main, ["experiment", "dpy-vs-ddp", "--runs", "1", "--workers", "1",
                                    "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "| -3 dB | DPY-STP | 1 |" in res.output and "params paper" in res.output
    assert {p.name for p in out.iterdir()} >= {"summary.md", "summary.csv", "cardinality.png", "ospa.png",
                                               "xy.png", "dpyp-run0.rrd", "ddp-mb-run0.rrd"}
    bad = CliRunner().invoke(main, ["experiment", "nope"])
    assert bad.exit_code == 2 and "nope" in bad.output


@pytest.mark.slow
def test_random_experiment_draws_a_scene_per_run_and_scores_crossings():
    from bnptrack.pipeline.experiments import _run_setup

    jobs = [RunJob("random", 5, i, "vo2017", Variant("default")) for i in range(2)]
    (exp, sc0, p0, s0), (_, sc1, _, s1) = (_run_setup(j) for j in jobs)
    assert [t.name for t in exp.trackers] == ["ddp-mb", "dpyp-mb", "glmb"]
    assert sc0.seed == s0 and sc1.seed == s1 and sc0 != sc1  # each run its own scene
    assert p0.birth == [] and len(sc0.crossings) == 3
    res = execute_run(jobs[0])
    assert set(res.trackers) == {"DDP-EMM (mb)", "DPY-STP (mb)", "GLMB"}
    assert res.n_true.tolist() == sc0.cardinality().tolist()
    for tr in res.trackers.values():
        assert tr.crossings_kept.shape == (3,) and tr.crossings_kept.dtype == bool
    # the summary pools the pairs of all runs: hand-made runs, 3 + 3 pairs, 4 kept
    res2 = execute_run(jobs[1])
    res.trackers["GLMB"].crossings_kept = np.array([True, True, False])
    res2.trackers["GLMB"].crossings_kept = np.array([True, True, False])
    res2.trackers["DDP-EMM (mb)"].crossings_kept = np.array([True, False, False])
    rows = {r["tracker"]: r for r in summary_rows([res, res2])}
    assert rows["GLMB"]["crossings_kept"] == pytest.approx(4 / 6)
    assert rows["GLMB"]["crossings_kept_std"] == 0.0 and rows["GLMB"]["crossing_pairs"] == 6
    k0 = res.trackers["DDP-EMM (mb)"].crossings_kept.mean()
    assert rows["DDP-EMM (mb)"]["crossings_kept"] == pytest.approx((k0 * 3 + 1) / 6)
    assert "crossings_kept" not in summary_rows([execute_run(JOBS[0])])[0]
