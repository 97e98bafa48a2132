"""The experiments as the paper ran them: parameter set, SNR, trackers, range scores."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.pipeline.experiments import (
    DEFAULT_EXPERIMENT_PARAMS,
    EXPERIMENTS,
    RunJob,
    RunResult,
    TrackerRun,
    Variant,
    summary_rows,
    write_summary,
)
from bnptrack.tracker.registry import kind


def test_paper_parameter_set_and_snr_by_default():
    from bnptrack.pipeline.cli.tools import experiment

    assert DEFAULT_EXPERIMENT_PARAMS == "paper"
    assert next(p for p in experiment.params if p.name == "params_name").default == "paper"
    for name in ("ddp-vs-glmb", "proximity", "dpy-vs-glmb", "dpy-vs-ddp"):
        assert EXPERIMENTS[name].variants == (Variant("-3 dB", ("snr_db=-3",)),), name


def test_two_level_trackers_beside_the_single_level_ones_and_the_glmb():
    labels = {n: [t.label for t in e.trackers] for n, e in EXPERIMENTS.items()}
    assert labels["ddp-vs-glmb"] == ["DDP-EMM", "DDP-EMM (mb)", "GLMB"]
    assert labels["dpy-vs-ddp"] == ["DPY-STP", "DPY-STP (mb)", "DDP-EMM", "DDP-EMM (mb)"]
    prox = {t.label: (t.name, t.preset) for t in EXPERIMENTS["proximity"].trackers}
    assert prox["DDP-EMM"] == ("ddp", "ddp-proximity")
    assert prox["DDP-EMM (mb)"] == ("ddp-mb", "ddp-mb-proximity")
    for e in EXPERIMENTS.values():  # every preset resolves, and the object level is the named preset's
        for t in e.trackers:
            assert t.preset in kind(t.name).presets, (e.name, t)
    from bnptrack.tracker.bnp.config import TRACKER_PRESETS

    assert kind("ddp").presets["ddp-snr"].objects == TRACKER_PRESETS["ddp-mb-snr"]
    assert kind("ddp-groups").presets["ddp-groups-snr"] == kind("ddp").presets["ddp-snr"]  # the aliases
    assert [m.key for m in EXPERIMENTS["snr"].metrics] == ["within100", "range_ospa"]


def test_the_paper_experiments_score_the_papers_ddp_emm_not_the_product_default():
    from bnptrack.tracker.bnp.config import TRACKER_PRESETS
    from bnptrack.tracker.bnp.group_config import GroupConfig

    for name in ("ddp-vs-glmb", "dpy-vs-ddp"):
        specs = {t.label: (t.name, t.preset) for t in EXPERIMENTS[name].trackers}
        assert specs["DDP-EMM"] == ("ddp", "ddp-paper") and specs["DDP-EMM (mb)"] == ("ddp-mb", "ddp-mb"), name
    paper = kind("ddp").presets["ddp-paper"]
    assert paper == GroupConfig(objects=TRACKER_PRESETS["ddp-mb"]) and paper.share_after == 0
    assert kind("ddp").presets["ddp"].share_after > 0  # the product default guards identities


def _run(label: str, num: list[float], den: list[float]) -> RunResult:
    K = len(num)
    z = np.zeros(K)
    tr = TrackerRun(z, z, z, z, z, z, z, extra={"within100": np.stack([num, den], axis=1),
                                                "range_ospa": np.stack([z + 10.0, z + 1.0], axis=1)})
    return RunResult(RunJob("snr", 1, 0, "paper", Variant("-3 dB")), np.zeros(K, dtype=int), {label: tr})


def test_extra_metrics_are_ratios_of_sums_over_frames(tmp_path):
    rows = summary_rows([_run("GLMB", [1.0, 0.0, 3.0], [2.0, 0.0, 4.0]), _run("GLMB", [0.0], [5.0])])
    assert rows[0]["within100"] == pytest.approx((4 / 6 + 0.0) / 2)  # runs: 4 of 6 object-frames, 0 of 5
    assert rows[0]["within100_std"] == pytest.approx(np.std([4 / 6, 0.0], ddof=1))
    assert rows[0]["range_ospa"] == pytest.approx(10.0)
    md, _ = write_summary(rows, tmp_path, "snr")
    assert "| within 100 m | range OSPA |" in md.read_text()
