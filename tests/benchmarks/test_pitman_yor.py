"""The Pitman-Yor test's analysis (benchmarks/pitman_yor.py) and its rows in docs/results.md
(benchmarks/report.py), on hand-made journals."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load(name: str, file: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / file)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


py = _load("benchmarks_pitman_yor", "pitman_yor.py")
report = _load("benchmarks_report_py", "report.py")


def _record(d, seed, ari, ospa, ospa2):
    series = [[0.1 * d, 0.0, 0.2]] * 50
    base = dict(ospa=30.0, ospa2=40.0, card_err=1.0, ari=0.5, ari_sample=0.4, rhat_median=1.0, rhat_ok=1.0,
                d=[[0.0, 0.0, 0.0]] * 50)
    a = dict(base, ospa=30.0 + ospa, ospa2=40.0 + ospa2, ari=0.5 + ari, d=series)
    return {"d": d, "seed": seed, "objects": 200, "groups": 10, "cpu_s": 10.0, "ddp": base, "dpyp": a}


def test_paired_hand_values():
    recs = [_record(0.6, s, a, 0.0, 0.0) for s, a in enumerate([0.01, 0.03, 0.05])]
    c = py.paired(recs, "ari", 0.02)
    # differences 0.01, 0.03, 0.05: mean 0.03, sd 0.02, SE 0.02 / sqrt 3, t(0.975, 2) = 4.3027
    assert c["n"] == 3 and c["mean"] == pytest.approx(0.03)
    assert c["se"] == pytest.approx(0.02 / np.sqrt(3))
    assert c["half"] == pytest.approx(4.302653 * 0.02 / np.sqrt(3), rel=1e-5)
    # ((1.96 + 0.8416) * 0.02 / 0.02)^2 = 7.85 -> 8 runs
    assert c["need"] == 8
    assert c["a"] == pytest.approx(0.53) and c["b"] == pytest.approx(0.5)


def test_verdicts():
    good = [_record(0.6, s, 0.05 + 0.001 * s, -1.0 - 0.01 * s, -1.0 + 0.01 * s) for s in range(6)]
    assert py.analyse(good, py.EFFECTS)["0.6"]["verdict"] == "holds"
    worse = [_record(0.6, s, 0.05 + 0.001 * s, 1.0 + 0.01 * s, -1.0) for s in range(6)]
    assert py.analyse(worse, py.EFFECTS)["0.6"]["verdict"] == "does not hold"
    open_ = [_record(0.6, s, (-1) ** s * 0.05, -1.0 - 0.01 * s, -1.0 - 0.01 * s) for s in range(6)]
    assert py.analyse(open_, py.EFFECTS)["0.6"]["verdict"] == "not decided"


def test_analysis_per_discount_and_the_report_rows(tmp_path):
    recs = [_record(d, s, 0.02, -0.5, -0.5 + 0.1 * (s % 2)) for d in (0.0, 0.6) for s in range(1, 5)]
    journal = tmp_path / "runs.jsonl"
    journal.write_text("".join(json.dumps(r) + "\n" for r in recs))
    res = report.pitman_yor_result(journal)
    assert set(res) == {"0.0", "0.6"} and res["0.6"]["runs"] == 4 and res["0.6"]["seeds"] == [1, 4]
    # DPY-STP's d: each run's mean 0.06 at every frame, interval [0, 0.2]
    assert res["0.6"]["d_post"][50] == pytest.approx([0.06, 0.0, 0.2])
    rows = report.pitman_yor_rows(res).strip().splitlines()
    assert len(rows) == 2 and "true d 0.6 | 4 |" in rows[1] and "ARI +0.020" in rows[1]
    text = py.markdown(res)
    assert "| 0.6 | 4 (1-4) | 0.520 / 0.500 |" in text
    assert report.pitman_yor_result(tmp_path / "absent.jsonl") is None
    # ARI +0.02 exactly, no spread: its interval is not inside (-0.02, +0.02); OSPA -0.5 is not either
    assert py.verdict_text(res).startswith('On `groups-py`, the claim "DPY-STP beats DDP-EMM": true d = ')


def test_verdict_text_names_the_small_intervals():
    recs = [_record(0.3, s, 0.001 * (s % 3 - 1), -1.0 - 0.01 * s, -1.0 - 0.01 * s) for s in range(8)]
    text = py.verdict_text(py.analyse(recs, py.EFFECTS))
    # ARI differences -0.001, 0, +0.001: interval well inside +-0.02; OSPA's at -1: outside +-0.5
    assert "true d = 0.3: **not decided**." in text and "d = 0.3: ARI." in text
