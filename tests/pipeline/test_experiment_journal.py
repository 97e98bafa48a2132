"""Resumable experiments: the run journal, its refusals, and the 95 % intervals of the table."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bnptrack.pipeline import experiment_journal
from bnptrack.pipeline.experiment_journal import JOURNAL_NAME, RunJournal, code_fingerprint
from bnptrack.pipeline.experiment_summary import RunScores, TrackerScores, ci_halfwidth, summarise
from bnptrack.pipeline.experiments import run_experiment
from bnptrack.tracker.config import ConfigError

EXP = "dpy-vs-glmb"  # at most 5 objects: the cheapest of the paper's experiments
SETUP = {"experiment": "x", "seed": 1, "params": "paper", "trackers": ["A"], "variants": ["v"], "code": "c0"}


def table(out: Path) -> list[dict]:
    """summary.csv without its timing columns (ms per frame is a clock reading)."""
    with (out / "summary.csv").open() as fh:
        return [{k: v for k, v in row.items() if not k.startswith("ms")} for row in csv.DictReader(fh)]


def scores(run: int, ospa: float) -> RunScores:
    return RunScores("v", run, {"A": TrackerScores((ospa, 0.0, ospa, ospa, ospa, 0.0, 1.0))})


def test_interval_is_students_t_over_runs():
    assert ci_halfwidth(np.array([1.0, 2.0, 3.0])) == pytest.approx(4.302653 / np.sqrt(3), rel=1e-6)
    assert np.isnan(ci_halfwidth(np.array([5.0])))  # one run: no interval
    row = summarise([scores(0, 1.0), scores(1, 2.0), scores(2, 3.0)])[0]
    assert row["runs"] == 3 and row["ospa"] == 2.0 and row["ospa_std"] == 1.0
    assert row["ospa_ci"] == pytest.approx(2.484138, rel=1e-6)


def test_a_single_run_has_no_interval_in_the_table(tmp_path):
    from bnptrack.pipeline.experiment_summary import write_summary

    md, csv_path = write_summary(summarise([scores(0, 1.5)]), tmp_path, "one run")
    row = next(line for line in md.read_text().splitlines() if line.startswith("| v |"))
    assert row.startswith("| v | A | 1 | 1.50 ± n/a | 0.00 ± n/a | 1.50 ± n/a | 1.50 ± n/a |"), row
    assert table(tmp_path)[0]["ospa_ci"] == "nan"
    md, _ = write_summary(summarise([scores(0, 1.0), scores(1, 2.0)]), tmp_path, "two runs")
    assert "n/a" not in md.read_text()


@pytest.mark.slow
def test_resumed_experiment_equals_an_uninterrupted_one(tmp_path):
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    run_experiment(EXP, runs=3, seed=4, params="vo2017", out=whole, workers=1, quiet=True, rrd=False)
    run_experiment(EXP, runs=2, seed=4, params="vo2017", out=parts, workers=1, quiet=True, rrd=False)
    assert len((parts / JOURNAL_NAME).read_text().splitlines()) == 1 + 2
    res = run_experiment(EXP, runs=3, seed=4, params="vo2017", out=parts, workers=1, quiet=True, rrd=False)
    assert len((parts / JOURNAL_NAME).read_text().splitlines()) == 1 + 3  # only run 2 was added
    assert table(parts) == table(whole)
    assert res.rows[0]["runs"] == 3 and "±" in res.summary_md.read_text()


def test_a_line_cut_short_is_dropped_and_the_run_redone(tmp_path):
    journal, done = RunJournal.open(tmp_path, SETUP)
    assert done == []
    journal.append(scores(0, 1.5))
    journal.close()
    with (tmp_path / JOURNAL_NAME).open("ab") as fh:
        fh.write(b'{"variant":"v","run":1,"trackers":{"A":{"val')  # killed mid-write
    journal, done = RunJournal.open(tmp_path, SETUP)
    assert [(s.run, s.trackers["A"].values[0]) for s in done] == [(0, 1.5)]
    journal.append(scores(1, 2.5))
    journal.close()
    lines = (tmp_path / JOURNAL_NAME).read_text().splitlines()
    assert len(lines) == 3 and json.loads(lines[2])["run"] == 1


@pytest.mark.parametrize("key, value, message", [
    ("params", "vo2017", "params 'paper', not 'vo2017'"),
    ("code", "c1", "other tracker code"),
])
def test_a_journal_of_another_setup_is_refused(tmp_path, key, value, message):
    RunJournal.open(tmp_path, SETUP)[0].close()
    with pytest.raises(ConfigError, match=message):
        RunJournal.open(tmp_path, {**SETUP, key: value})


def test_a_corrupt_middle_line_names_its_line(tmp_path):
    (tmp_path / JOURNAL_NAME).write_text(json.dumps({"format": "bnptrack-experiment-journal/1", **SETUP})
                                         + "\nnot json\n{}\n")
    with pytest.raises(ConfigError, match="line 2: not a run record"):
        RunJournal.open(tmp_path, SETUP)


def test_fingerprint_ignores_prose_but_not_code(tmp_path, monkeypatch):
    src = Path(__file__).resolve().parents[2]
    # every folder and module the fingerprint reads is in the tree (a moved one raises)
    assert len(code_fingerprint(src)) == 16
    # the rules, on a folder and a module of those it reads (each file is read the same way)
    monkeypatch.setattr(experiment_journal, "_CODE", ("tracker/models", "pipeline/resolve.py"))
    shutil.copytree(src / "tracker" / "models", tmp_path / "tracker" / "models",
                    ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "pipeline").mkdir()
    shutil.copy(src / "pipeline" / "resolve.py", tmp_path / "pipeline" / "resolve.py")
    base = code_fingerprint(tmp_path)
    assert base == code_fingerprint(src)
    motion = tmp_path / "tracker" / "models" / "motion.py"
    text = motion.read_text()
    motion.write_text('"""Another module docstring."""\n# a comment\n' + text.split('"""', 2)[2])
    assert code_fingerprint(tmp_path) == base
    motion.write_text(text + "\n_EXTRA = 1\n")
    assert code_fingerprint(tmp_path) != base


@pytest.mark.slow
def test_killed_experiment_resumes_to_the_same_table(tmp_path):
    """A real stop at a random moment: SIGKILL the command once it has journalled two runs, start
    it again, and compare with an uninterrupted run."""
    args = [sys.executable, "-m", "bnptrack", "experiment", EXP, "--runs", "8", "--seed", "2", "--params",
            "vo2017", "--workers", "1", "--no-rrd", "-q"]
    subprocess.run([*args, "--out", str(tmp_path / "whole")], check=True, timeout=600)
    out = tmp_path / "killed"
    proc = subprocess.Popen([*args, "--out", str(out)])
    journal = out / JOURNAL_NAME
    deadline = time.monotonic() + 300
    while not (journal.exists() and journal.read_text().count("\n") >= 3):
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "summary.csv").exists()
    subprocess.run([*args, "--out", str(out)], check=True, timeout=600)
    assert table(out) == table(tmp_path / "whole")


def _set_code(out: Path, code: str) -> None:
    lines = (out / JOURNAL_NAME).read_text().splitlines(keepends=True)
    header = json.loads(lines[0])
    header["code"] = code
    (out / JOURNAL_NAME).write_text(json.dumps(header) + "\n" + "".join(lines[1:]))


@pytest.mark.slow
def test_revalidate_carries_over_a_journal_whose_runs_redo_the_same(tmp_path):
    out = tmp_path / "exp"
    run_experiment(EXP, runs=2, seed=4, params="vo2017", out=out, workers=1, quiet=True, rrd=False)
    before = table(out)
    _set_code(out, "another version")
    with pytest.raises(ConfigError, match="other tracker code"):
        run_experiment(EXP, runs=2, seed=4, params="vo2017", out=out, workers=1, quiet=True, rrd=False)
    run_experiment(EXP, runs=2, seed=4, params="vo2017", out=out, workers=1, quiet=True, rrd=False, revalidate=2)
    assert json.loads((out / JOURNAL_NAME).read_text().splitlines()[0])["code"] == code_fingerprint()
    assert len((out / JOURNAL_NAME).read_text().splitlines()) == 3 and table(out) == before


@pytest.mark.slow
def test_revalidate_refuses_a_journal_whose_runs_differ(tmp_path):
    out = tmp_path / "exp"
    run_experiment(EXP, runs=2, seed=4, params="vo2017", out=out, workers=1, quiet=True, rrd=False)
    lines = (out / JOURNAL_NAME).read_text().splitlines(keepends=True)
    record = json.loads(lines[2])
    record["trackers"]["GLMB"]["values"][0] += 1.0  # run 1's GLMB OSPA, as another version gave it
    (out / JOURNAL_NAME).write_text("".join(lines[:2]) + json.dumps(record) + "\n")
    _set_code(out, "another version")
    with pytest.raises(ConfigError, match="run 1 .* redone by this code gives other scores"):
        run_experiment(EXP, runs=2, seed=4, params="vo2017", out=out, workers=1, quiet=True, rrd=False, revalidate=2)
