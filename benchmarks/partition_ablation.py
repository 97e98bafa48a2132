"""The two-level tracker's object -> cluster Gibbs kernels on the inputs of a real run: time, tables
scored per move, and equality of the outputs (ablation of the gated kernel's parts).

    taskset -c 0 python3 benchmarks/partition_ablation.py [--ns 100,1000,3000] [--frames 12] [--repeats 3]

For each N the ``scale-N`` scene (:mod:`benchmarks.scale`) runs ``--frames`` frames of ``ddp``;
the inputs of :func:`tracker.bnp.groups.sample_partition` of the last ``--keep`` frames are
recorded (the module's function wrapped; the tracker calls it by that name) and each kernel of
:data:`tracker.bnp.groups.PARTITION_KERNELS` runs on them ``--repeats`` times, interleaved:

* ``scan``: every table scored per move, urn weights recounted over all tables, dense (L, T)
  last-sweep records (sessions 5-9);
* ``urn``: the urn state kept incrementally (K, the lowest free slot), sparse records, every
  occupied table still scored;
* ``gated``: ``urn`` plus the grid and the bound (only tables the bound cannot exclude scored;
  since session 11 also the exact quadratic form of the indexed block before each score, so
  "tables scored" counts only the tables fully scored).

Figures per kernel: CPU ms per frame (median over repeats of the sum over the kept frames,
``time.thread_time``), tables scored per move (``urn``, ``gated``), the peak RSS of one
subprocess per kernel that runs only that kernel on the saved inputs, and whether its sample and
shares equal ``scan``'s bit for bit.  The last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(__file__))


def record_inputs(n: int, frames: int, keep: int) -> list[tuple]:
    """``sample_partition``'s arguments (with the random stream's state) of the last ``keep`` frames."""
    import scale

    from bnptrack.tracker.bnp import groups
    from bnptrack.tracker.registry import build
    from bnptrack.tracker.state import tracker_frame_rng

    params, fr = scale.simulate(n, frames, 1, 1.0)
    tracker = build("ddp", params)
    state, calls, inner = tracker.initial_state(), [], groups.sample_partition

    def recording(rng, blocks, v_star, alpha, d, init, sweeps, flat_share=False, occupied=False):
        calls.append((rng.bit_generator.state, blocks, np.array(v_star), alpha, d, np.array(init), sweeps,
                      flat_share, occupied))
        return inner(rng, blocks, v_star, alpha, d, init, sweeps, flat_share, occupied)

    groups.sample_partition = recording
    try:
        for f in fr:
            state, _ = tracker.step(state, f, tracker_frame_rng(1, f.frame))
    finally:
        groups.sample_partition = inner
    return calls[-keep:]


def run_kernel(calls: list[tuple], kernel: str, stats: np.ndarray | None = None) -> tuple[float, list]:
    """CPU seconds of ``kernel`` over the recorded calls and its outputs."""
    from bnptrack.tracker.bnp.groups import sample_partition

    out, cpu = [], 0.0
    for state, blocks, v_star, alpha, d, init, sweeps, flat, occ in calls:
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = state
        c0 = time.thread_time()
        z, sh = sample_partition(rng, blocks, v_star, alpha, d, init, sweeps, flat, occ, kernel=kernel, stats=stats)
        cpu += time.thread_time() - c0
        out.append((z, sh))
    return cpu, out


def _same(a: list, b: list) -> bool:
    return all(np.array_equal(za, zb) and all(np.array_equal(getattr(sa, f), getattr(sb, f), equal_nan=True)
                                              for f in ("obj", "w", "mu", "cov"))
               for (za, sa), (zb, sb) in zip(a, b))


def _status_kib(key: str) -> float:
    """A ``/proc/self/status`` figure in KiB (Linux)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return float(line.split()[1])
    raise RuntimeError(f"/proc/self/status has no {key}")


def peak_rss(path: str, kernel: str) -> float:
    """Peak RSS (MiB) added by ``kernel`` on the last recorded call, in a subprocess (after a run on
    two members of it, which loads numba and the kernel): the peak reset by ``/proc/self/clear_refs``
    (Linux) to the RSS before the call."""
    out = subprocess.run([sys.executable, __file__, "--rss-of", path, "--kernel", kernel], capture_output=True,
                         text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ns", default="100,1000,3000")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--keep", type=int, default=3, help="frames (the last ones) whose partitions are timed")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rss-of", help=argparse.SUPPRESS)
    ap.add_argument("--kernel", help=argparse.SUPPRESS)
    args = ap.parse_args()
    from bnptrack.tracker.bnp.groups import PARTITION_KERNELS

    if args.rss_of:
        with open(args.rss_of, "rb") as fh:
            calls = pickle.load(fh)
        state, blocks, v_star, alpha, d, init, sweeps, flat, occ = calls[-1]
        small = [replace(b, v=b.v[:2], R=b.R[:2]) for b in blocks]
        run_kernel([(state, small, v_star, alpha, d, init[:2], sweeps, flat, occ)], args.kernel)  # loads numba
        with open("/proc/self/clear_refs", "w") as fh:  # resets the peak (VmHWM) to the current RSS
            fh.write("5")
        base = _status_kib("VmRSS")
        run_kernel(calls[-1:], args.kernel)
        print((_status_kib("VmHWM") - base) / 1024.0)
        return
    rows = []
    print("| N | objects in the partition | kernel | CPU ms/frame | tables scored/move | extra peak RSS MiB "
          "| equal to scan |")
    print("|---|---|---|---|---|---|---|")
    for n in [int(x) for x in args.ns.split(",")]:
        calls = record_inputs(n, args.frames, args.keep)
        for k in PARTITION_KERNELS:  # compile / load every kernel before timing
            run_kernel(calls[:1], k)
        cpu = {k: [] for k in PARTITION_KERNELS}
        outs, stats = {}, {k: np.zeros(2, dtype=np.int64) for k in PARTITION_KERNELS}
        for rep in range(args.repeats):
            for k in (PARTITION_KERNELS if rep % 2 == 0 else PARTITION_KERNELS[::-1]):
                c, outs[k] = run_kernel(calls, k, stats[k] if rep == 0 else None)
                cpu[k].append(c)
        with tempfile.NamedTemporaryFile(suffix=".pkl", delete=False) as fh:
            pickle.dump(calls, fh)
        try:
            rss = {k: peak_rss(fh.name, k) for k in PARTITION_KERNELS}
        finally:
            os.unlink(fh.name)
        L = float(np.mean([c[1][0].v.shape[0] for c in calls]))
        for k in PARTITION_KERNELS:
            ms = float(np.median(cpu[k])) * 1e3 / len(calls)
            per_move = float(stats[k][1] / stats[k][0]) if stats[k][0] else None
            row = {"n": n, "members": L, "kernel": k, "cpu_ms_per_frame": round(ms, 2),
                   "scored_per_move": None if per_move is None else round(per_move, 1),
                   "extra_rss_mib": round(rss[k], 1), "equal_to_scan": _same(outs[k], outs["scan"])}
            rows.append(row)
            print(f"| {n} | {L:.0f} | {k} | {row['cpu_ms_per_frame']} | {row['scored_per_move'] or 'all'} "
                  f"| {row['extra_rss_mib']} | {row['equal_to_scan']} |", flush=True)
    print(json.dumps({"results": rows}))


if __name__ == "__main__":
    main()
