"""CPU ms per frame of DDP-EMM on vo2017 (seeds 1-3, 100 frames each; the minimum of 3 repeats).

    taskset -c 0 python3 benchmarks/vo2017_cpu.py

CPU time of this thread (``time.thread_time``), not wall time: on a shared machine wall time also
counts the time other processes hold the core.  For a ratio between two versions, run this
script from both trees alternately (docs/performance.md).
"""

from __future__ import annotations

import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp import make_tracker  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


def main() -> None:
    params = get_scenario("vo2017").adapt_params(load_params("vo2017"))
    tracker = make_tracker("ddp", params)
    runs = [simulate_all(get_scenario("vo2017"), params, seed) for seed in (1, 2, 3)]
    list(run(tracker, runs[0][:3], 1))  # load numba's cache
    best = []
    for _ in range(3):
        t0, n = time.thread_time(), 0
        for seed, frames in enumerate(runs, start=1):
            list(run(tracker, frames, seed))
            n += len(frames)
        best.append((time.thread_time() - t0) * 1e3 / n)
    print(f"ddp vo2017 CPU ms/frame (min of 3 repeats, seeds 1-3): {min(best):.3f}")


if __name__ == "__main__":
    main()
