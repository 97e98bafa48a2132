"""Start-up time of the ``bnptrack`` commands, beside interpreter baselines from the same run.

Start-up targets: ``bnptrack --help`` <= 0.3 s, ``bnptrack track
recordings/vo2017-s1.mcap`` <= 1.0 s on a warm machine (second run) and ``bnptrack launch``
(100 frames, the default pipeline) <= 3 s.  Each round runs, one after the other (so that a
change of machine load hits every command alike):

* ``python3 -c pass`` and ``python3 -c "import numpy"``: the floor any command stands on;
* ``python3 -m bnptrack --help``;
* ``python3 -m bnptrack track recordings/vo2017-s1.mcap --out TMP/x.mcap`` (one untimed run
  first, so that the numba cache and the file cache are warm);
* ``python3 -m bnptrack launch --out TMP/run --overwrite -q`` (the default: 100 frames);

and prints the median, min and max wall time of each over ``--rounds`` rounds, and the median
CPU time (user + system of the process and those it waited for, e.g. a launch's stages), with
the load average; for ``launch``, also where its wall time went (medians, from the
source's log line ``published N frame(s) in T s``): the first frame published (the source
waits until the tracker and the sink are ready), the last, and the launcher's exit.  ``--pyc`` first byte-compiles the checkout (``compileall``, what ``pip
install`` does for an installed package): where ``PYTHONDONTWRITEBYTECODE=1`` is set (this
machine's sessions set it), Python never writes the ``.pyc`` files of a source checkout, so
without ``--pyc`` every process compiles the project's ~70 modules from source on every run
(about 0.2 s of CPU per process, measured); the line above the table says which was timed.  ``--root DIR`` times the checkout in ``DIR`` instead of this one (e.g. a
``git worktree`` of an older commit, to compare in alternating runs).  With ``--numba`` it also times ``track`` with an empty numba cache directory
(``NUMBA_CACHE_DIR``: every kernel compiles) against the same directory filled (every kernel
loads from the cache).  The children get ``PYTHONPATH`` = this checkout.

    nice -n 5 python3 benchmarks/startup.py --rounds 5 --numba
    nice -n 5 python3 benchmarks/startup.py --rounds 5 --no-launch --json out.json
    nice -n 5 python3 benchmarks/startup.py --rounds 3 --root /tmp/startup_base   # an older checkout
    nice -n 5 python3 benchmarks/startup.py --rounds 3 --pyc                       # .pyc files warm
    python3 benchmarks/startup.py --pairs 8 --base /tmp/base --base-python /tmp/base-venv/bin/python

``--pairs N --base DIR`` times only ``launch``, this checkout against the one in ``DIR`` (run
by ``--base-python``), in ``N`` pairs one right after the other, the order flipped each pair: on a
loaded machine the pairwise ratio is steadier than medians of separate runs.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]  # --root replaces it
LAUNCH = "bnptrack launch (100 frames)"
#: CPU seconds (user + system) of each timed command line, run by run.
CPU: dict[str, list[float]] = {}


def _env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.update(extra or {})
    return env


def wall(argv: list[str], env: dict[str, str] | None = None) -> float:
    """Wall time (s) of one child process run to completion; raises if it fails.  Its CPU
    time (user + system, with the processes it waited for: a launch's stages) goes to
    :data:`CPU` under the same command line."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(argv, cwd=ROOT, env=env or _env(), stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {proc.returncode}: {proc.stderr[-2000:]}")
    CPU.setdefault(" ".join(argv), []).append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
    return elapsed


_PUBLISHED = re.compile(r"^(\d\d):(\d\d):(\d\d)\.(\d{3}) \[source\] INFO \S+ published (\d+) frame\(s\) in ([\d.]+) s")


def launch_phases(run_dir: Path, t_start: float, elapsed: float) -> tuple[float, float, float] | None:
    """Where one launch's wall time went, from its source's log: (start to the first frame
    published, first to last frame published, last frame published to the launcher's exit),
    in seconds.  The source logs ``published N frame(s) in T s`` (ms time stamps, local
    time) after its last frame; the first frame went out ``T`` earlier.  None when the log
    has no such line."""
    try:
        lines = (run_dir / "logs" / "source.log").read_text().splitlines()
    except OSError:
        return None
    hits = [m for m in map(_PUBLISHED.match, lines) if m]
    if not hits:
        return None
    h, mi, sec, ms, _, took = hits[-1].groups()
    day = time.mktime(time.localtime(t_start)[:3] + (0, 0, 0, 0, 0, -1))
    t_last = day + int(h) * 3600 + int(mi) * 60 + int(sec) + int(ms) / 1e3
    last = t_last - t_start
    first = last - float(took)
    return first, float(took), elapsed - last


def launch_pairs(n: int, base: Path, base_python: str) -> None:
    """``launch`` in ``n`` pairs: the checkout in ``base`` (run by ``base_python``, e.g. its
    own venv's) and this one (``sys.executable``), one right after the other, the order
    flipped each pair, so that both see the same load; prints each pair and the medians
    (wall, CPU of the processes, first frame published) and of the pairwise wall ratio."""
    sides = {"base": (base.resolve(), base_python), "this": (ROOT, sys.executable)}
    res: dict[str, list[tuple[float, float, float]]] = {k: [] for k in sides}
    with tempfile.TemporaryDirectory(prefix="bnp-startup-") as d:
        for i in range(n):
            for k in (list(sides) if i % 2 == 0 else list(sides)[::-1]):
                root, py = sides[k]
                argv = [py, "-m", "bnptrack", "launch", "--out", str(Path(d) / k), "--overwrite", "-q"]
                t_start, cpu0 = time.time(), sum(resource.getrusage(resource.RUSAGE_CHILDREN)[:2])
                subprocess.run(argv, cwd=root, env=dict(os.environ, PYTHONPATH=str(root)),
                               stdout=subprocess.DEVNULL, check=True)
                el = time.time() - t_start
                ph = launch_phases(Path(d) / k, t_start, el)
                cpu = sum(resource.getrusage(resource.RUSAGE_CHILDREN)[:2]) - cpu0
                res[k].append((el, cpu, ph[0] if ph else float("nan")))
            print(f"pair {i + 1}: " + " | ".join(f"{k} {res[k][-1][0]:.2f} s (CPU {res[k][-1][1]:.2f} s, first frame "
                                                 f"{res[k][-1][2]:.2f} s)" for k in sides) + f"; load {os.getloadavg()[0]:.2f}")
    for k in sides:
        print(f"{k} ({sides[k][0]}): median wall {statistics.median(r[0] for r in res[k]):.3f} s, CPU "
              f"{statistics.median(r[1] for r in res[k]):.3f} s, first frame {statistics.median(r[2] for r in res[k]):.3f} s")
    ratios = [b[0] / a[0] for a, b in zip(res["base"], res["this"])]
    print(f"wall this / base, pairwise: median {statistics.median(ratios):.3f} (range {min(ratios):.2f}-{max(ratios):.2f})")


def byte_compile() -> None:
    """Write the ``.pyc`` files of the checkout's packages (``python -m compileall``)."""
    dirs = [str(ROOT / d) for d in ("bnptrack", "tracker", "sources", "sinks", "pipeline")]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *dirs], check=True, stdout=subprocess.DEVNULL)


def commands(tmp: Path, launch: bool) -> dict[str, list[str]]:
    """The timed command lines, by name (baselines first)."""
    py = sys.executable
    log = ROOT / "recordings" / "vo2017-s1.mcap"
    cmds = {
        "python3 -c pass": [py, "-c", "pass"],
        "python3 -c 'import numpy'": [py, "-c", "import numpy"],
        "bnptrack --help": [py, "-m", "bnptrack", "--help"],
        "bnptrack track vo2017-s1.mcap": [py, "-m", "bnptrack", "track", str(log), "--out",
                                          str(tmp / "track.mcap")],
    }
    if launch:
        cmds[LAUNCH] = [py, "-m", "bnptrack", "launch", "--out", str(tmp / "run"),
                                                "--overwrite", "-q"]
    return cmds


def numba_cache(tmp: Path, rounds: int) -> dict[str, list[float]]:
    """``track`` with an empty numba cache (compile) and with the same cache filled (load)."""
    out: dict[str, list[float]] = {"track, numba compiles (empty cache)": [],
                                   "track, numba loads (filled cache)": []}
    log = ROOT / "recordings" / "vo2017-s1.mcap"
    argv = [sys.executable, "-m", "bnptrack", "track", str(log), "--out", str(tmp / "nb.mcap")]
    for i in range(rounds):
        cache = tmp / f"numba-{i}"
        cache.mkdir()
        env = _env({"NUMBA_CACHE_DIR": str(cache)})
        out["track, numba compiles (empty cache)"].append(wall(argv, env))
        out["track, numba loads (filled cache)"].append(wall(argv, env))
    return out


def summarise(times: dict[str, list[float]], cpu: dict[str, list[float]]) -> list[dict[str, float | str]]:
    """Per command: median, min and max wall time, and median CPU time (``cpu[name]``)."""
    rows = []
    for name, ts in times.items():
        rows.append({"command": name, "median_s": statistics.median(ts), "min_s": min(ts), "max_s": max(ts),
                     "cpu_median_s": statistics.median(cpu[name]), "runs": len(ts)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--no-launch", dest="launch", action="store_false", help="Skip `bnptrack launch`.")
    ap.add_argument("--numba", action="store_true", help="Also time numba compile vs cache load.")
    ap.add_argument("--json", type=Path, default=None, help="Also write the rows to this file.")
    ap.add_argument("--root", type=Path, default=None, help="Time the checkout in this directory.")
    ap.add_argument("--pyc", action="store_true", help="Byte-compile the checkout first (compileall).")
    ap.add_argument("--pairs", type=int, default=0, metavar="N",
                    help="Only `launch`, in N pairs against --base (alternating order).")
    ap.add_argument("--base", type=Path, default=None, help="With --pairs: the other checkout.")
    ap.add_argument("--base-python", default=sys.executable, help="With --pairs: the base's Python.")
    args = ap.parse_args()
    if args.pairs:
        if args.base is None:
            ap.error("--pairs needs --base DIR")
        return launch_pairs(args.pairs, args.base, args.base_python)
    if args.root is not None:
        global ROOT
        ROOT = args.root.resolve()
    if args.pyc:
        byte_compile()
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bnp-startup-") as d:
        tmp = Path(d)
        cmds = commands(tmp, args.launch)
        wall(cmds["bnptrack track vo2017-s1.mcap"])  # warm-up: numba cache, page cache
        times: dict[str, list[float]] = {name: [] for name in cmds}
        phases: list[tuple[float, float, float]] = []
        for _ in range(args.rounds):
            for name, argv in cmds.items():
                t_start = time.time()
                times[name].append(wall(argv))
                if name == LAUNCH and (ph := launch_phases(tmp / "run", t_start, times[name][-1])):
                    phases.append(ph)
        cpu_by_name = {name: CPU[" ".join(argv)][-args.rounds:] for name, argv in cmds.items()}
        if args.numba:
            CPU.clear()
            times.update(numba_cache(tmp, max(1, args.rounds // 2)))
            runs = list(CPU.values())[0]  # compile, load, compile, load, ...
            cpu_by_name["track, numba compiles (empty cache)"] = runs[0::2]
            cpu_by_name["track, numba loads (filled cache)"] = runs[1::2]
    load1 = os.getloadavg()
    rows = summarise(times, cpu_by_name)
    print(f"load average before {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, "
          f"after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}; {os.cpu_count()} cores; {args.rounds} rounds; {ROOT}")
    print(f"PYTHONDONTWRITEBYTECODE={os.environ.get('PYTHONDONTWRITEBYTECODE', '')!r}; "
          f"{'checkout byte-compiled first (--pyc)' if args.pyc else 'no byte-compilation'}")
    print(f"{'command':40s} {'median s':>9s} {'min s':>7s} {'max s':>7s} {'CPU s':>7s}")
    for r in rows:
        print(f"{r['command']:40s} {r['median_s']:9.3f} {r['min_s']:7.3f} {r['max_s']:7.3f} {r['cpu_median_s']:7.3f}")
    if phases:
        print(f"launch, medians over {len(phases)} runs (from the source's log): first frame published "
              + ", ".join(f"{label} {statistics.median(p[i] for p in phases):.3f} s" for i, label in
                          enumerate(("at", "last frame after", "launcher's exit after the last frame"))))
    if args.json:
        args.json.write_text(json.dumps({"load": [load0, load1], "rows": rows, "launch_phases": phases}, indent=1))
    print(json.dumps({"results": rows}))


if __name__ == "__main__":
    main()
