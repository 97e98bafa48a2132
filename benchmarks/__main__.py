"""The benchmark suite's runner: ``python3 -m benchmarks list | run NAME|SET ... [--full] | report``.

Each benchmark is a script in this folder that prints a table and, where it has one, a JSON
line last. ``run`` executes the named benchmarks (or every benchmark of a named set) with
this checkout's code, each in its own process, prints each one's output, then one table (name,
exit code, seconds) and one JSON line per benchmark, and writes that line to
``benchmarks/results/NAME.json``.  Without ``--full`` every benchmark runs with small
arguments (a few seeds or rounds), enough to check it works and to see rough figures; with
``--full``, the arguments its figures in the docs were measured with.

``report`` regenerates docs/results.md (``benchmarks/report.py``: the paper's five experiments,
their tables and the verdict on each claim).

benchmarks/README.md lists the benchmarks and the question each one answers.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


@dataclass(frozen=True)
class Benchmark:
    name: str
    script: str
    question: str
    quick: tuple[str, ...]
    full: tuple[str, ...] = ()


SUITE = (
    Benchmark("accuracy", "accuracy.py", "How accurate is each tracker on a scene, over seeds?",
              ("--trackers", "ddp", "glmb", "--params", "vo2017", "--seeds", "2", "--workers", "1"),
              ("--trackers", "ddp", "dpyp", "glmb", "--params", "vo2017", "--seeds", "20")),
    Benchmark("births", "births.py", "How fast are new objects confirmed, and at what cost in false tracks?",
              ("--seeds", "2", "--workers", "1"), ("--seeds", "20")),
    Benchmark("groups", "groups.py", "What does the two-level model buy on objects moving in groups?",
              ("--trackers", "ddp", "ddp-mb", "--seeds", "2", "--workers", "1"), ("--seeds", "20")),
    Benchmark("pitman-yor", "pitman_yor.py", "Does DPY-STP beat DDP-EMM where the true partition is Pitman-Yor?",
              ("--analyse", "--journal", "benchmarks/pitman_yor/runs.jsonl"),
              ("--first-seed", "1", "--seeds", "40", "--journal", "benchmarks/pitman_yor/runs.jsonl")),
    Benchmark("sensors", "sensors.py", "How well does one scene track when measured by other sensors?",
              ("--seeds", "1", "--workers", "1"), ("--seeds", "10")),
    Benchmark("vs-stonesoup", "vs_stonesoup.py", "How do the trackers compare with Stone Soup's (needs the compare extra)?",
              ("--seeds", "1", "--anchors", "--json"), ("--seeds", "20", "--workers", "2", "--json")),
    Benchmark("scale", "scale.py", "How does the time per frame grow with the number of objects?",
              ("--ns", "10,100", "--frames", "10"), ()),
    Benchmark("scale-dense", "scale.py", "How fast is a dense scene: N objects in one radar's own field?",
              ("--mode", "dense", "--tracker", "ddp", "--ns", "100,300", "--frames", "10"),
              ("--mode", "dense", "--tracker", "ddp", "--ns", "100,300,1000", "--frames", "30")),
    Benchmark("startup", "startup.py", "How long do the commands take to start (warm kernel cache)?",
              ("--rounds", "1", "--no-launch"), ("--rounds", "5", "--pyc")),
    Benchmark("rerun-overhead", "rerun_overhead.py", "What does writing a Rerun recording cost an offline run?",
              ("--repeats", "1", "--part", "command"), ()),
    Benchmark("robot-log-read", "robot_log_read.py", "Is reading a ROS 2 log as cheap as reading bnptrack's JSON log?",
              ("--messages", "1000", "--repeats", "2"), ("--messages", "10000", "--repeats", "15")),
    Benchmark("experiment-throughput", "experiment_throughput.py", "How many Monte Carlo runs per minute, on 1 and 2 workers?",
              ("--runs", "4", "--workers", "1"), ()),
    Benchmark("pipeline-latency", "pipeline_latency.py", "What throughput and added latency does the Zenoh pipeline have?",
              ("--runs", "1", "--rounds", "1", "--only", "throughput"), ("--paced", "5")),
    Benchmark("faults", "faults.py", "What survives a killed stage, a killed router, hostile samples?",
              ("--points", "1", "--malformed", "100"), ()),
)

SETS = {
    "accuracy": ("accuracy", "births", "groups", "pitman-yor", "sensors", "vs-stonesoup"),
    "speed": ("scale", "scale-dense", "startup", "rerun-overhead", "robot-log-read", "experiment-throughput"),
    "pipeline": ("pipeline-latency", "faults"),
    "quick": ("accuracy", "groups", "scale", "startup", "robot-log-read"),
}
SETS["all"] = tuple(b.name for b in SUITE)
BY_NAME = {b.name: b for b in SUITE}


def _last_json(text: str) -> dict | None:
    for line in reversed(text.strip().splitlines()):
        if line.startswith("{"):
            try:
                return json.loads(line)
            except ValueError:
                return None
    return None


def run_one(bench: Benchmark, full: bool) -> dict:
    """Run one benchmark with this checkout's code; its record (name, command, exit code,
    seconds, the JSON line it printed last or None)."""
    args = bench.full if full else bench.quick
    cmd = [sys.executable, str(HERE / bench.script), *args]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seconds = time.perf_counter() - t0
    sys.stdout.write(proc.stdout)
    return {"benchmark": bench.name, "command": " ".join(["python3", f"benchmarks/{bench.script}", *args]),
            "exit_code": proc.returncode, "seconds": round(seconds, 1), "result": _last_json(proc.stdout)}


def _names(items: list[str]) -> list[str]:
    out: list[str] = []
    for item in items:
        if item in SETS:
            out += [n for n in SETS[item] if n not in out]
        elif item in BY_NAME:
            out += [item] if item not in out else []
        else:
            raise SystemExit(f"unknown benchmark or set {item!r}; benchmarks: {', '.join(BY_NAME)}; "
                             f"sets: {', '.join(SETS)}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python3 -m benchmarks", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the benchmarks, their sets and questions")
    run = sub.add_parser("run", help="run benchmarks or sets")
    run.add_argument("names", nargs="+", metavar="NAME|SET")
    run.add_argument("--full", action="store_true", help="the arguments of the documented figures")
    sub.add_parser("report", help="regenerate docs/results.md (benchmarks/report.py; its options follow)")
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["report"]:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        return subprocess.run([sys.executable, str(HERE / "report.py"), *argv[1:]], cwd=ROOT, env=env).returncode
    ns = ap.parse_args(argv)
    if ns.command == "list":
        for b in SUITE:
            print(f"{b.name:<22} {b.question}")
        for name, members in SETS.items():
            print(f"set {name:<18} {' '.join(members)}")
        return 0
    records = []
    for name in _names(ns.names):
        print(f"== {name}", flush=True)
        records.append(run_one(BY_NAME[name], ns.full))
    results = HERE / "results"
    results.mkdir(exist_ok=True)
    print(f"\n{'benchmark':<22} {'exit':>4} {'seconds':>8}  command")
    for r in records:
        print(f"{r['benchmark']:<22} {r['exit_code']:>4} {r['seconds']:>8.1f}  {r['command']}")
    for r in records:
        line = json.dumps(r)
        print(line)
        (results / f"{r['benchmark']}.json").write_text(line + "\n")
    return max((r["exit_code"] for r in records), default=0)


if __name__ == "__main__":
    sys.exit(main())
