"""RunJob(trackers=...) (Monte Carlo throughput: the paper's pair timed alone): a
tracker's series are those it has when the whole experiment runs, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.pipeline.experiments import RunJob, execute_run, get_experiment, select_trackers
from bnptrack.tracker.config import ConfigError

SERIES = ("ospa", "ospa_loc", "ospa_card", "ospa2", "gospa", "n_est")


@pytest.mark.slow
def test_selected_trackers_give_the_series_of_the_full_run():
    exp = get_experiment("ddp-vs-glmb")
    full = execute_run(RunJob("ddp-vs-glmb", 3, 0, "vo2017", exp.variants[0]))
    pair = execute_run(RunJob("ddp-vs-glmb", 3, 0, "vo2017", exp.variants[0], trackers=("glmb", "DDP-EMM")))
    assert list(full.trackers) == ["DDP-EMM", "DDP-EMM (mb)", "GLMB"]
    assert list(pair.trackers) == ["DDP-EMM", "GLMB"]  # the experiment's order, by name or label
    assert np.array_equal(full.n_true, pair.n_true)
    for label in pair.trackers:
        for name in SERIES:
            assert np.array_equal(getattr(full.trackers[label], name), getattr(pair.trackers[label], name))


def test_select_trackers_names_and_errors():
    exp = get_experiment("ddp-vs-glmb")
    assert select_trackers(exp, ()) == exp.trackers
    assert [s.name for s in select_trackers(exp, ["ddp-mb"])] == ["ddp-mb"]
    with pytest.raises(ConfigError, match="no tracker 'gmphd'"):
        select_trackers(exp, ["glmb", "gmphd"])
