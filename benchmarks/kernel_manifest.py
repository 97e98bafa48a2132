"""Write tracker/params/kernel_manifest.pkl: each tracker's kernels with their argument types,
in the order a first run compiles them (tracker/precompile.py compiles them from the other end
in a second process on a first run).

For each tracker, a child process with an empty kernel cache (``NUMBA_CACHE_DIR`` a fresh
temporary folder) runs the tracker stage's warm-up (``pipeline.stages.tracker_warmup.warm_up_tracker``)
and then tracks the 100 frames of ``recordings/vo2017-s1.mcap``, recording every compilation of
a project kernel (numba's ``numba:compile`` events, in the order they end).  Run it again after
changing a kernel's arguments: a stale manifest only costs the second process useless work.

    python3 benchmarks/kernel_manifest.py                  # ddp, dpyp, ddp-mb, dpyp-mb, glmb
    python3 benchmarks/kernel_manifest.py --trackers ddp
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT / "recordings" / "vo2017-s1.mcap"


def child(tracker: str, out: str) -> None:
    """Record the compilations of tracker ``tracker``'s warm-up and a run over :data:`LOG`."""
    from numba.core import event

    rows: list[tuple[str, str, tuple]] = []

    class Listener(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            pass

        def on_end(self, ev: event.Event) -> None:
            data = ev.data or {}
            py = getattr(data.get("dispatcher"), "py_func", None)
            if py is not None and py.__module__.startswith("bnptrack."):
                row = (py.__module__, py.__qualname__, tuple(data.get("args", ())))
                if row not in rows:
                    rows.append(row)

    event.register("numba:compile", Listener())
    from bnptrack.pipeline.offline import track_frames
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.pipeline.stages.tracker_warmup import warm_up_tracker
    from bnptrack.sources.mcap_log import iter_frames, read_metadata

    setup = tracker_setup(tracker, metadata=read_metadata(LOG))
    warm_up_tracker(setup.tracker)
    track_frames(setup.tracker, iter_frames(LOG), 0)
    with open(out, "wb") as f:
        pickle.dump(rows, f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trackers", nargs="+", default=["ddp", "dpyp", "ddp-mb", "dpyp-mb", "glmb"])
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(*args.child)
        return
    import numba

    from bnptrack.tracker.precompile import MANIFEST

    trackers = {}
    for name in args.trackers:
        with tempfile.TemporaryDirectory() as cache:
            out = os.path.join(cache, "rows.pkl")
            env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
            subprocess.run([sys.executable, __file__, "--child", name, out], cwd=ROOT, env=env, check=True)
            with open(out, "rb") as f:
                trackers[name] = pickle.load(f)
        print(f"{name}: {len(trackers[name])} kernel signatures")
    with open(MANIFEST, "wb") as f:
        pickle.dump({"numba": numba.__version__, "trackers": trackers}, f)
    print(f"wrote {MANIFEST}")


if __name__ == "__main__":
    main()
