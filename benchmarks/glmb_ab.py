"""A/B CPU time of the GLMB on vo2017: this tree against another checkout, alternating runs.

Each round runs, one after the other, a fresh process per tree (``taskset -c CPU nice -n 5``,
``PYTHONPATH`` = that tree) that simulates vo2017 seeds 1..``--seeds`` (100 frames each),
tracks them once untimed (numba's cache, file cache), then times ``--repeats`` passes with
``time.thread_time`` (CPU time of the tracking thread; on a shared machine wall time also
counts the time others hold the core) and keeps the fastest.  It prints each run's CPU ms per
frame, the per-round ratio base / this tree and a fingerprint of every frame's hypotheses
(table rows, log weights) and estimate (labels, means, existences, assignment
probabilities): equal fingerprints mean the two trees
computed the same posterior bit for bit.

    python3 benchmarks/glmb_ab.py --base /tmp/glmbspeed-base --rounds 3
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import sys
import time

from _ab import last_json_line

HERE = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))

def measure(seeds: int, repeats: int, birth_regions: bool, overrides: list[str]) -> dict:
    """CPU ms per frame (fastest of ``repeats`` passes over the seeds) and the fingerprint."""
    import numpy as np

    from bnptrack.sources.scenarios import get_scenario
    from bnptrack.sources.synthetic import simulate_all
    from bnptrack.tracker.config import apply_overrides
    from bnptrack.tracker.glmb import GlmbConfig, make_glmb
    from bnptrack.tracker.models.params import load_params

    params = get_scenario("vo2017").adapt_params(load_params("vo2017"))
    config = apply_overrides(GlmbConfig() if birth_regions else GlmbConfig(birth=[]), overrides)
    tracker = make_glmb(params, config)
    runs = [simulate_all(get_scenario("vo2017"), params, s) for s in range(1, seeds + 1)]
    digest = hashlib.sha256()

    def one_pass(record: bool) -> float:
        t0 = time.thread_time()
        for seed, frames in enumerate(runs, start=1):
            state, rng = tracker.initial_state(), np.random.default_rng(seed)
            for fr in frames:
                state, est = tracker.step(state, fr, rng)
                if record:
                    digest.update(state.hyp_tracks.tobytes() + state.log_w.tobytes())
                    digest.update(np.array(est.assignment_prob, dtype=float).tobytes())
                    for t in est.tracks:
                        digest.update(t.label.encode() + t.state.tobytes() + np.float64(t.existence).tobytes())
        return time.thread_time() - t0

    one_pass(True)
    best = min(one_pass(False) for _ in range(repeats))
    return {"ms": 1e3 * best / sum(len(f) for f in runs), "fingerprint": digest.hexdigest()[:16]}

def run_tree(root: str, args: argparse.Namespace, overrides: list[str]) -> dict:
    cmd = ["taskset", "-c", str(args.cpu), "nice", "-n", "5", sys.executable, os.path.abspath(__file__), "--measure",
           "--seeds", str(args.seeds), "--repeats", str(args.repeats)] + ([] if args.birth_regions else ["--no-regions"]) + [f"--set={o}" for o in overrides]
    return last_json_line(cmd, root)

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", help="the other checkout (the baseline)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--cpu", type=int, default=1)
    ap.add_argument("--no-regions", dest="birth_regions", action="store_false",
                    help="without vo2017's birth regions (adaptive births)")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="GLMB setting KEY=V for this tree's runs only (the base runs its defaults)")
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        sys.path.insert(0, os.getcwd())
        print(json.dumps(measure(args.seeds, args.repeats, args.birth_regions, args.overrides)))
        return
    ratios, mins = [], {"base": [], "new": []}
    print("| round | base CPU ms/frame | this tree CPU ms/frame | ratio | fingerprints |\n|---|---|---|---|---|")
    for r in range(1, args.rounds + 1):
        base = run_tree(os.path.abspath(args.base), args, [])
        new = run_tree(HERE, args, args.overrides)
        ratios.append(base["ms"] / new["ms"])
        mins["base"].append(base["ms"])
        mins["new"].append(new["ms"])
        same = "equal" if base["fingerprint"] == new["fingerprint"] else f"{base['fingerprint']} / {new['fingerprint']}"
        print(f"| {r} | {base['ms']:.3f} | {new['ms']:.3f} | {ratios[-1]:.2f} | {same} |", flush=True)
    print(f"median of the per-round ratios {statistics.median(ratios):.2f}; fastest base / fastest this tree "
          f"{min(mins['base']):.3f} / {min(mins['new']):.3f} = {min(mins['base']) / min(mins['new']):.2f} "
          f"(load average {os.getloadavg()[0]:.1f})")

if __name__ == "__main__":
    main()
