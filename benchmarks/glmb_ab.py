"""A/B speed of the GLMB against an older commit's ``tracker/glmb.py``, in one process.

The old module is taken from ``git archive COMMIT tracker/glmb.py`` into a temporary
directory and imported next to the current one (it uses the current tree's filtering and
models), so both run on the same frames, interleaved, under the same machine load.  Prints
ms per frame (sum over seeds of the minimum over repeats of each seed's run / frames).

    python benchmarks/glmb_ab.py --old ea9f721 --seeds 6 --repeats 3
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import os
import subprocess
import sys
import tarfile
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker import glmb as new  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def load_old(commit: str, tmp: str):
    """Import ``tracker/glmb.py`` of ``commit`` as module ``glmb_old``."""
    blob = subprocess.run(["git", "archive", commit, "tracker/glmb.py"], check=True,
                          capture_output=True, cwd=os.path.join(os.path.dirname(__file__), "..")).stdout
    tarfile.open(fileobj=io.BytesIO(blob)).extractall(tmp)
    spec = importlib.util.spec_from_file_location("glmb_old", os.path.join(tmp, "tracker", "glmb.py"))
    mod = importlib.util.module_from_spec(spec)
    sys.modules["glmb_old"] = mod
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", default="ea9f721", help="commit of the old tracker/glmb.py")
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    params = load_params("vo2017")
    frames = [simulate_all(get_scenario("vo2017"), params, s) for s in range(1, args.seeds + 1)]
    with tempfile.TemporaryDirectory() as tmp:
        old = load_old(args.old, tmp)
        trackers = {f"old ({args.old}), birth regions": old.make_glmb(params),
                    "new defaults, birth regions": new.make_glmb(params),
                    "new defaults, no birth regions (adaptive)": new.make_glmb(params, new.GlmbConfig(birth=[]))}
        for t in trackers.values():  # compile / warm up
            list(run(t, frames[0][:5], 1))
        best = {k: [float("inf")] * len(frames) for k in trackers}
        for _ in range(args.repeats):
            for i, fr in enumerate(frames):
                for k, t in trackers.items():
                    t0 = time.perf_counter()
                    list(run(t, fr, i + 1))
                    best[k][i] = min(best[k][i], time.perf_counter() - t0)
    base = sum(next(iter(best.values())))
    n = sum(len(fr) for fr in frames)
    print("| tracker | ms/frame | ratio to old |\n|---|---|---|")
    for k, v in best.items():
        print(f"| {k} | {1e3 * sum(v) / n:.2f} | {sum(v) / base:.2f} |")


if __name__ == "__main__":
    main()
