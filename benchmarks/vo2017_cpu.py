"""CPU ms per frame of a BNP tracker's ``step`` on vo2017 (default the single-level ``ddp-mb``), alone or A/B against another checkout.

Alone (this tree)::

    taskset -c 0 nice -n 10 python3 benchmarks/vo2017_cpu.py

simulates vo2017 seeds 1..``--seeds`` (100 frames each), tracks them once untimed (numba's
cache, file cache), then ``--repeats`` timed passes; each frame's ``step`` is timed with
``time.thread_time`` (CPU time of this thread: on a shared machine wall time also counts the
time other processes hold the core).  It prints the median over frames of each frame's fastest
time, the mean CPU ms per frame of the fastest pass, and a fingerprint
of every estimate (labels, means, covariances, existences, assignments and their
probabilities, cardinality pmf, every diagnostic but ``ms``).

A/B (``--base DIR``): each round runs a fresh process per tree, alternately (``PYTHONPATH`` =
that tree; the other tree first in odd rounds), and prints both figures, their ratio this tree
/ base, and whether the fingerprints are equal (equal: the two trees computed the same
estimates bit for bit)::

    taskset -c 1 nice -n 10 python3 benchmarks/vo2017_cpu.py --base /tmp/ddpspeed-base --rounds 5
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))


def _digest_estimate(digest, est) -> None:
    import numpy as np

    digest.update(repr((est.frame, est.assignments, est.assignment_prob)).encode())
    digest.update(repr(sorted((k, v) for k, v in est.diagnostics.items() if k != "ms")).encode())
    for t in est.tracks:
        digest.update(repr((t.label, t.existence)).encode() + t.state.tobytes() + t.covariance.tobytes())
    if est.cardinality_pmf is not None:
        digest.update(np.ascontiguousarray(est.cardinality_pmf).tobytes())


def measure(tracker_name: str, seeds: int, repeats: int) -> dict:
    """Per-frame CPU ms of ``step`` (fastest over the repeats), its median and mean, and the
    fingerprint of the estimates."""
    import numpy as np

    from bnptrack.sources.scenarios import get_scenario
    from bnptrack.sources.synthetic import simulate_all
    from bnptrack.tracker.models.params import load_params
    from bnptrack.tracker.registry import build
    from bnptrack.tracker.state import tracker_frame_rng

    params = get_scenario("vo2017").adapt_params(load_params("vo2017"))
    tracker = build(tracker_name, params)
    runs = [simulate_all(get_scenario("vo2017"), params, s) for s in range(1, seeds + 1)]
    digest = hashlib.sha256()

    def one_pass(record: bool) -> list[float]:
        out = []
        for seed, frames in enumerate(runs, start=1):
            state = tracker.initial_state()
            for fr in frames:
                rng = tracker_frame_rng(seed, fr.frame)
                t0 = time.thread_time_ns()
                state, est = tracker.step(state, fr, rng)
                out.append((time.thread_time_ns() - t0) * 1e-6)
                if record:
                    _digest_estimate(digest, est)
        return out

    one_pass(True)
    passes = [one_pass(False) for _ in range(repeats)]
    fastest = np.min(passes, axis=0)
    return {"median_ms": float(np.median(fastest)), "mean_ms": float(min(np.mean(p) for p in passes)),
            "frames": len(fastest), "fingerprint": digest.hexdigest()[:16]}


def _child(root: str, args) -> dict:
    cmd = [sys.executable, os.path.join(HERE, "benchmarks", "vo2017_cpu.py"), "--child", "--tracker", args.tracker,
           "--seeds", str(args.seeds), "--repeats", str(args.repeats)]
    env = dict(os.environ, PYTHONPATH=root)
    out = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracker", default="ddp-mb", choices=("ddp-mb", "dpyp-mb", "ddp", "dpyp"))
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--base", help="another checkout to time alternately with this one (A/B)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child or not args.base:
        if not args.child:
            sys.path.insert(0, HERE)
        res = measure(args.tracker, args.seeds, args.repeats)
        if args.child:
            print(json.dumps(res))
        else:
            print(f"{args.tracker} vo2017 step CPU ms/frame (seeds 1-{args.seeds}, {res['frames']} frames, fastest of "
                  f"{args.repeats}): median {res['median_ms']:.3f}, mean {res['mean_ms']:.3f}; "
                  f"fingerprint {res['fingerprint']}")
        return
    base = os.path.abspath(args.base)
    print(f"{args.tracker} vo2017 seeds 1-{args.seeds}: step CPU ms/frame, median over frames (mean), "
          f"fastest of {args.repeats} passes; base {base}")
    print("| round | base median (mean) | this tree median (mean) | ratio median | ratio mean | estimates |")
    print("|---|---|---|---|---|---|")
    ratios = []
    for r in range(1, args.rounds + 1):
        order = (base, HERE) if r % 2 else (HERE, base)
        res = {root: _child(root, args) for root in order}
        a, b = res[base], res[HERE]
        ratios.append(b["median_ms"] / a["median_ms"])
        same = "equal" if a["fingerprint"] == b["fingerprint"] else "DIFFERENT"
        print(f"| {r} | {a['median_ms']:.3f} ({a['mean_ms']:.3f}) | {b['median_ms']:.3f} ({b['mean_ms']:.3f}) "
              f"| {ratios[-1]:.3f} | {b['mean_ms'] / a['mean_ms']:.3f} | {same} |", flush=True)
    print(f"median ratio (this tree / base): {statistics.median(ratios):.3f}")


if __name__ == "__main__":
    main()
