"""Do two versions of the single-level BNP trackers give the same runs?  Dump the per-frame states
and estimates of five settings (vo2017 ddp-mb, dpy5 dpyp-mb, proximity ddp-mb-proximity, vo2017 extended,
vo2017 mixture update; seed 3, 100 frames) from each tree, then compare:

    PYTHONPATH=$PWD python3 benchmarks/state_equivalence.py dump /tmp/new.pkl          # in this tree
    PYTHONPATH=$PWD python3 benchmarks/state_equivalence.py dump /tmp/old.pkl          # in the other tree
    python3 benchmarks/state_equivalence.py compare /tmp/old.pkl /tmp/new.pkl

For each setting it prints the first frame whose labels or measurement assignments differ
(None: none of the 100) and the largest difference of any mean or existence before it.
"""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

SETTINGS = [("vo2017", "ddp-mb", "ddp-mb", {}), ("dpy5", "dpyp-mb", "dpyp-mb", {}),
            ("proximity", "ddp-mb", "ddp-mb-proximity", {}), ("vo2017", "ddp-mb", "ddp-mb", {"extended": True}),
            ("vo2017", "ddp-mb", "ddp-mb", {"state_update": "mixture"})]


def dump(path: str) -> None:
    import msgspec

    from bnptrack.sources.scenarios import get_scenario
    from bnptrack.sources.synthetic import simulate_all
    from bnptrack.tracker.bnp import TRACKER_PRESETS, make_tracker
    from bnptrack.tracker.models.params import load_params
    from bnptrack.tracker.state import run

    out = {}
    for scen, name, preset, extra in SETTINGS:
        params = get_scenario(scen).adapt_params(load_params("vo2017"))
        tr = make_tracker(name, params, msgspec.structs.replace(TRACKER_PRESETS[preset], **extra))
        frames = simulate_all(get_scenario(scen), params, 3)
        out[f"{scen} {preset} {extra}"] = [(st.labels, st.mean.copy(), st.existence.copy(), e.assignments)
                                           for _, e, st in run(tr, frames, 3)]
    with open(path, "wb") as f:
        pickle.dump(out, f)


def compare(path_a: str, path_b: str) -> None:
    with open(path_a, "rb") as f:
        A = pickle.load(f)
    with open(path_b, "rb") as f:
        B = pickle.load(f)
    for key in A:
        first, worst = None, 0.0
        for k, (x, y) in enumerate(zip(A[key], B[key])):
            if x[0] != y[0] or x[3] != y[3]:
                first = k
                break
            if x[1].size:
                worst = max(worst, float(np.abs(x[1] - y[1]).max()), float(np.abs(x[2] - y[2]).max()))
        print(f"{key}: {len(A[key])} frames, first differing frame {first}, largest numeric difference {worst:.1e}")


if __name__ == "__main__":
    if sys.argv[1] == "dump":
        dump(sys.argv[2])
    else:
        compare(sys.argv[2], sys.argv[3])
