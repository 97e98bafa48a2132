"""The benchmark suite's runner (``python3 -m benchmarks``): its table of benchmarks and sets,
and one real run of a small benchmark."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("benchmarks_runner", ROOT / "benchmarks" / "__main__.py")
runner = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = runner  # its dataclasses look their module up
spec.loader.exec_module(runner)


def test_every_entry_names_an_existing_script_and_every_set_known_entries():
    assert all((ROOT / "benchmarks" / b.script).is_file() for b in runner.SUITE)
    assert {n for members in runner.SETS.values() for n in members} <= set(runner.BY_NAME)
    assert runner._names(["quick", "scale"]) == list(runner.SETS["quick"])
    with pytest.raises(SystemExit, match="unknown benchmark or set 'nope'"):
        runner._names(["nope"])


def test_the_last_json_line_is_the_result():
    assert runner._last_json('table\n{"a": 1}\n{"results": [2]}\n') == {"results": [2]}
    assert runner._last_json("no json here\n") is None


@pytest.mark.slow
def test_a_run_records_exit_code_command_and_result(capsys):
    bench = runner.Benchmark("scale", "scale.py", "q", ("--ns", "10", "--frames", "3"))
    record = runner.run_one(bench, full=False)
    assert record["exit_code"] == 0 and record["command"] == "python3 benchmarks/scale.py --ns 10 --frames 3"
    (row,) = record["result"]["results"]
    assert row["n"] == 10 and row["frames"] == 3
    assert json.loads(json.dumps(record)) == record
