"""Where a first run's compile time goes: ``bnptrack track LOG`` with an empty kernel cache, each
numba compilation's CPU seconds.

A child process (``NUMBA_CACHE_DIR`` a fresh temporary folder, ``PYTHONPATH`` = the checkout,
this one or ``--root``) runs ``bnptrack track LOG --tracker NAME -q`` in-process with a numba
event listener on ``numba:compile``: each compilation's thread CPU time minus the compilations
nested in it (a kernel's callees compile inside its own compilation).  Prints the process's CPU
seconds, the number of compilations, the costliest compiled functions (the project's kernels
and numba's own helpers), every kernel compiled for more than one signature, and the count of
numba's string-code compilations (pulled in by an array assigned into a slice of another).
Thread CPU time is less inflated than wall time by a busy machine, but not immune to it: compare
two checkouts in the same sitting.

    python3 benchmarks/compile_times.py                    # ddp, this checkout
    python3 benchmarks/compile_times.py --root /work/wt/base --tracker glmb --top 20
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def listen_to_compilations() -> list[dict]:
    """Register a listener on numba's ``numba:compile`` events; the list it fills, one row per
    compilation: ``name`` (module.qualname), ``args`` (the signature's repr) and ``self`` (thread
    CPU seconds without the nested compilations)."""
    from numba.core import event

    rows: list[dict] = []
    stack: list[list[float]] = []  # [start, nested]

    class Listener(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            stack.append([time.thread_time(), 0.0])

        def on_end(self, ev: event.Event) -> None:
            t0, nested = stack.pop()
            total = time.thread_time() - t0
            if stack:
                stack[-1][1] += total
            data = ev.data or {}
            py = getattr(data.get("dispatcher"), "py_func", None)
            name = f"{py.__module__}.{py.__qualname__}" if py is not None else "?"
            rows.append({"name": name, "args": repr(tuple(data.get("args", ()))), "self": total - nested})

    event.register("numba:compile", Listener())
    return rows


def child(argv: list[str]) -> dict:
    """Run ``bnptrack ARGV`` here with the listener; the compilations and the process's CPU s."""
    rows = listen_to_compilations()
    from bnptrack.pipeline.cli import main

    t0 = time.process_time()
    main.main(args=argv, standalone_mode=False)
    return {"cpu": time.process_time() - t0, "rows": rows}


def report(res: dict, top: int) -> None:
    """Print the figures of one child's result."""
    rows = res["rows"]
    by_name: dict[str, list] = collections.defaultdict(lambda: [0, 0.0])
    for r in rows:
        by_name[r["name"]][0] += 1
        by_name[r["name"]][1] += r["self"]
    print(f"process CPU {res['cpu']:.1f} s; {len(rows)} compilations, {sum(r['self'] for r in rows):.1f} s CPU")
    print(f"{'CPU s':>7} {'n':>3}  compiled function (self: nested compilations excluded)")
    for name, (n, cpu) in sorted(by_name.items(), key=lambda kv: -kv[1][1])[:top]:
        print(f"{cpu:7.2f} {n:3d}  {name}")
    print("project kernels with several signatures:")
    for name, (n, cpu) in sorted(by_name.items()):
        if n > 1 and name.startswith("bnptrack"):
            print(f"  {name}: {n} ({cpu:.2f} s)")
    strings = [r for r in rows if ".unicode." in r["name"] or "raise_with_shape_context" in r["name"]]
    print(f"numba string code: {len(strings)} compilations, {sum(r['self'] for r in strings):.2f} s CPU")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, default=ROOT, help="the checkout to measure")
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--log", default="recordings/vo2017-s1.mcap")
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--child", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(args.root))
        env.pop("BNPTRACK_NO_JIT", None)
        argv = ["track", args.log, "--tracker", args.tracker, "-q", "--out", f"{out}/tracks.mcap"]
        proc = subprocess.run([sys.executable, __file__, "--child", *argv], cwd=args.root, env=env,
                              capture_output=True, text=True, check=True)
    print(f"{args.root} {args.tracker}, load {os.getloadavg()[0]:.1f}")
    report(json.loads(proc.stdout.strip().splitlines()[-1]), args.top)


if __name__ == "__main__":
    main()
