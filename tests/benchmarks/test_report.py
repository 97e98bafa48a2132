"""docs/results.md's verdicts: a claim decided on paired per-run differences, by hand."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from bnptrack.pipeline.experiment_summary import RunScores, TrackerScores

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("benchmarks_report", ROOT / "benchmarks" / "report.py")
report = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = report
spec.loader.exec_module(report)

CLAIM = report.Claim("x", "A beats B", "A", "B")


def runs(diffs_ospa, diffs_ospa2):
    out = []
    for i, (d1, d2) in enumerate(zip(diffs_ospa, diffs_ospa2)):
        b = TrackerScores((20.0, 0, 0, 30.0, 0, 0.5, 1.0))
        a = TrackerScores((20.0 + d1, 0, 0, 30.0 + d2, 0, 0.5, 1.0))
        out.append(RunScores("v", i, {"A": a, "B": b}))
    return out


def test_differences_below_zero_on_every_metric_hold():
    (row,) = report.decide(runs([-1.0, -2.0, -3.0], [-1.0, -1.0, -1.0]), CLAIM)
    # OSPA: mean -2, sd 1, t(0.975, 2) = 4.3027: interval -2 +- 2.484 crosses 0 -> not decided
    assert row["verdict"] == "not decided" and row["runs"] == 3
    assert "OSPA -2.00 ± 2.48 (SE 0.58;" in row["cells"]
    (row,) = report.decide(runs([-1.0, -1.1, -0.9, -1.0], [-1.0, -1.2, -0.8, -1.0]), CLAIM)
    assert row["verdict"] == "**holds**"


def test_an_interval_above_zero_refutes():
    (row,) = report.decide(runs([-1.0, -1.1, -0.9], [1.0, 1.1, 0.9]), CLAIM)
    assert row["verdict"] == "**does not hold**"


def test_runs_needed_for_half_a_metre():
    # sd 1: ((1.96 + 0.84) * 1 / 0.5)^2 = 31.36 -> 32 runs
    (row,) = report.decide(runs([-1.0, -2.0, -3.0], [0.0, 0.0, 0.0]), CLAIM)
    assert "OSPA -2.00 ± 2.48 (SE 0.58; 32 runs for 0.5 m)" in row["cells"]


def test_the_template_has_every_placeholder_the_report_fills():
    text = report.TEMPLATE.read_text()
    for key in ["{{machine}}", "{{claims}}", "{{runs}}", *("{{table:" + c.experiment + "}}" for c in report.CLAIMS)]:
        assert key in text
    with pytest.raises(KeyError):
        report.METRIC_INDEX["nope"]
