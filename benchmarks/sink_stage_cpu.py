"""The sink stage's own CPU per frame, without transport: 500 vo2017 frames (the log of
``pipeline_latency.py``: 5 runs back to back) and their DDP-EMM tracks, encoded, fed to a
``SinkStage`` on the in-memory bus in this process (intake, sequencing, the sinks, scoring);
``--set`` items are pipeline keys (``sink.rerun=false`` always).

    nice -n 5 python3 benchmarks/sink_stage_cpu.py                        # scoring on (default)
    nice -n 5 python3 benchmarks/sink_stage_cpu.py --set sink.score=false
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import replace

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import msgspec  # noqa: E402

from bnptrack.pipeline.config import load_pipeline, resolve_run  # noqa: E402
from bnptrack.pipeline.events import Event  # noqa: E402
from bnptrack.pipeline.membus import MemoryNetwork  # noqa: E402
from bnptrack.pipeline.resolve import tracker_setup  # noqa: E402
from bnptrack.pipeline.stages import SinkStage, StageContext, StageInfo  # noqa: E402
from bnptrack.sources.scenarios import get_scenario, scenario_params  # noqa: E402
from bnptrack.sources.synthetic import simulate  # noqa: E402
from bnptrack.tracker.messages import encode, from_estimate, from_truth  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402

META = {"scenario": "vo2017", "params": "vo2017", "seed": "1"}


def events(runs: int) -> tuple[int, list[Event]]:
    params = scenario_params("vo2017", "vo2017")
    frames = [replace(f, frame=n, stamp_ns=n * 10**9) for n, f in enumerate(
        (f for r in range(runs) for f in simulate(get_scenario("vo2017"), params, r + 1)), start=1)]
    ests = [e for _, e, _ in run(tracker_setup("ddp", params=params).tracker, frames, 0)]
    out = []
    for i, (f, e) in enumerate(zip(frames, ests)):
        meta = {"seq": i, "t": 1, "frame": f.frame}
        out += [Event("measurements", encode(f, "p"), {**meta, "truth": True}, 0),
                Event("truth", encode(from_truth(f.frame, f.stamp_ns, f.truth, "p")), meta, 0),
                Event("tracks", encode(from_estimate(e, "p")), {**meta, "t_in": 2, "t_out": 3}, 0)]
    return len(frames), out


def cpu_per_frame(sets: list[str], n: int, evs: list[Event], out: str) -> float:
    cfg = msgspec.structs.replace(resolve_run(load_pipeline(None, [*sets, "sink.rerun=false"])), run="p", out=out)
    stage = SinkStage(StageContext(cfg, MemoryNetwork().bus("p", "sink"), name="sink"))
    stage.infos["tracker"] = StageInfo(stage="tracker", run="p", metadata=META)
    stage._open()
    c0 = time.process_time()
    for ev in evs:
        stage._on_data(ev)
        stage._drain_ready()
    cpu = (time.process_time() - c0) * 1e3 / n
    stage.sinks.close()
    return cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--runs", type=int, default=5, help="vo2017 runs of 100 frames")
    args = ap.parse_args()
    n, evs = events(args.runs)
    with tempfile.TemporaryDirectory() as tmp:
        cpus = sorted(cpu_per_frame(args.set, n, evs, tmp) for _ in range(args.repeat))
    print(f"sink stage code, {n} frames, --set {args.set}: CPU per frame median {cpus[len(cpus) // 2]:.3f} ms "
          f"(min {cpus[0]:.3f}, max {cpus[-1]:.3f}); load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
