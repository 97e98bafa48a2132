"""Issue 16's start-up targets: the time to the first progress line of ``bnptrack launch`` (stderr,
not a terminal; target 3 s) and the time of configuration errors (exit 2, one line; target 1 s),
each ``N`` times, with the load average beside (the machine is shared: read them with it).

    nice -n 5 python3 benchmarks/startup_errors.py 3
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
LOG = str(ROOT / "recordings" / "vo2017-s1.mcap")


def first_progress(out: str) -> tuple[float | None, str, int, float]:
    """(seconds to the first progress line, that line, exit code, total seconds) of a 20-frame launch."""
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "bnptrack", "launch", "--set", "source.frames=20",
                          "--set", "sink.rerun=false", "--out", out], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, env=ENV, text=True, cwd=ROOT)
    first, first_line = None, ""
    for line in p.stderr:
        if line.startswith("[") and first is None:
            first, first_line = time.perf_counter() - t0, line.strip()
    p.wait()
    return first, first_line, p.returncode, time.perf_counter() - t0


def config_error(args: list[str]) -> tuple[float, int, str]:
    """(seconds, exit code, last stderr line) of a command that must fail at once."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "bnptrack", *args], capture_output=True, text=True, env=ENV, cwd=ROOT)
    return time.perf_counter() - t0, r.returncode, (r.stderr.strip().splitlines() or [""])[-1][:100]


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    print("load average", os.getloadavg())
    tmp = tempfile.mkdtemp()
    try:
        for i in range(n):
            f, line, rc, total = first_progress(f"{tmp}/r{i}")
            print(f"launch: first progress line after {f:.2f} s ({line[:60]!r}); exit {rc} after {total:.1f} s; "
                  f"load {os.getloadavg()[0]:.2f}")
        cases = [["replay", LOG, "--tracker", "foo"], ["launch", "--set", "tracker.tracker='glmbb'"],
                 ["launch", "--set", "source.kind='mcap'"], ["replay", LOG, "--set", "sweps=10"],
                 ["replay", LOG, "--topic", "/x=/tracks"]]
        for _ in range(n):
            for j, c in enumerate(cases):
                t, rc, last = config_error([*c, "--out", f"{tmp}/e{j}"])
                print(f"config error {' '.join(c)}: exit {rc} after {t:.2f} s: {last}")
        print("load average", os.getloadavg())
    finally:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
