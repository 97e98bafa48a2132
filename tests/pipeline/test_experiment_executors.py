"""Executors of the Monte Carlo runs: a warm process pool gives the same results
as a run redone alone; Dask is an optional extra: the core install runs experiments on local
processes, ``--cluster`` without Dask says which extra to install, the CLI documents it."""

from __future__ import annotations

import sys
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.experiments import RunJob, Variant, execute_run, run_jobs, warm_pool
from bnptrack.tracker.config import ConfigError
from testkit import REPO_ROOT


def test_dask_is_an_optional_extra_never_a_core_dependency():
    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]
    assert not [d for d in project["dependencies"] if d.startswith(("dask", "distributed"))]
    assert project["optional-dependencies"]["dask"] == ["dask[distributed]>=2024.1"]
    assert "dask[distributed]>=2024.1" in project["optional-dependencies"]["test"]


def test_cluster_without_dask_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # `import distributed` raises ImportError
    job = RunJob("ddp-vs-glmb", 1, 0, "vo2017", Variant("default"))
    with pytest.raises(ConfigError, match=r"pip install 'bnptrack\[dask\]'"):
        run_jobs([job], cluster="tcp://127.0.0.1:1")


def test_experiment_help_documents_the_extra():
    out = CliRunner().invoke(main, ["experiment", "--help"], terminal_width=200).output
    assert "--cluster" in out and "bnptrack[dask]" in out


@pytest.mark.slow
def test_warm_pool_keeps_its_workers_and_gives_the_runs_redone_alone():
    """Two batches on one warm pool: the same worker processes serve both, and every run
    equals the same run executed alone in this process, bit for bit."""
    jobs = [RunJob("dpy-vs-ddp", 3, i, "vo2017", Variant("default")) for i in range(3)]
    pool = warm_pool(2, "dpy-vs-ddp")
    try:
        pids = set(pool._processes)
        first = run_jobs(jobs[:2], executor=pool)
        second = run_jobs(jobs[2:], executor=pool)
        assert set(pool._processes) == pids and len(pids) == 2
    finally:
        pool.shutdown()
    for job, got in zip(jobs, first + second):
        alone = execute_run(job)
        assert got.job == job and np.array_equal(got.n_true, alone.n_true)
        for t, tr in alone.trackers.items():
            for f in ("ospa", "ospa_loc", "ospa_card", "ospa2", "gospa", "n_est"):
                assert np.array_equal(getattr(got.trackers[t], f), getattr(tr, f)), (t, f)
