"""CPU seconds of every process of one command, read from ``/proc`` until each ends: where a
cold first run spends its CPU (the tracker stage, the second compiling process, the launcher,
the sink and the source).

The command runs with ``NUMBA_CACHE_DIR`` a fresh temporary folder (an empty kernel cache)
unless ``--warm``; every 0.2 s each descendant's user + system time is read from
``/proc/PID/stat``; the last reading of each process is printed with its command line, largest
first, after the command's wall time and exit code.  Linux only.

    python3 benchmarks/process_cpu.py bnptrack launch --out /tmp/cold-launch
    python3 benchmarks/process_cpu.py --warm bnptrack track recordings/vo2017-s1.mcap --out /tmp/t.mcap --overwrite
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import time

TICK = os.sysconf("SC_CLK_TCK")


def processes() -> dict[int, tuple[int, float, str]]:
    """Every process: pid -> (parent pid, CPU seconds, command line)."""
    out = {}
    for p in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            with open(f"/proc/{p}/cmdline") as f:
                cmd = f.read().replace("\0", " ").strip()
        except OSError:  # the process ended meanwhile
            continue
        out[int(p)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / TICK, cmd)
    return out


def descendants(root: int, table: dict[int, tuple[int, float, str]]) -> set[int]:
    """``root`` and every process below it in ``table``."""
    found, grew = {root}, True
    while grew:
        new = {p for p, (parent, _, _) in table.items() if parent in found} - found
        found |= new
        grew = bool(new)
    return found


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--warm", action="store_true", help="keep the kernel cache as it is")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    ns = ap.parse_args()
    env = dict(os.environ) if ns.warm else dict(os.environ, NUMBA_CACHE_DIR=tempfile.mkdtemp())
    t0 = time.monotonic()
    proc = subprocess.Popen(ns.command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen: dict[int, tuple[float, str]] = {}
    while proc.poll() is None:
        table = processes()
        for p in descendants(proc.pid, table):
            if p in table:
                seen[p] = (table[p][1], table[p][2] or seen.get(p, (0.0, ""))[1])
        time.sleep(0.2)
    print(f"wall {time.monotonic() - t0:.1f} s, exit {proc.returncode}")
    for cpu, cmd in sorted(seen.values(), reverse=True):
        print(f"{cpu:7.1f} s  {cmd[:110]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
