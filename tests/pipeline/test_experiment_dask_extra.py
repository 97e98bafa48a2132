"""Dask is an optional extra (issue 15): the core install runs experiments on local processes;
``--cluster`` without Dask says which extra to install; the CLI documents it."""

from __future__ import annotations

import sys
import tomllib

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.experiments import RunJob, Variant, run_jobs
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
