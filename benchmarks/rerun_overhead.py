"""Cost of recording a run to Rerun (.rrd) next to the tracker's own cost, frame by frame.

Runs the DDP-EMM tracker over a simulated scenario (default vo2017, seed 1, 100 frames) and,
interleaved frame by frame in the same process, logs every frame to a RerunSink.  The
tracker's step, the scoring (OSPA, OSPA(2): sinks.metrics) and the sink's ``log`` are timed
separately with ``time.perf_counter``, so machine load affects all of them alike.  Prints ms per
frame (median, mean, p95) for each and the logging/tracker ratio; ``close()`` (footer) is
timed apart.  Interleaving matters: Rerun encodes and writes on background threads, which
compete with the tracker on the same cores exactly as they would in a real run.

    python benchmarks/rerun_overhead.py                     # vo2017, seed 1, ddp, 3 repeats
    python benchmarks/rerun_overhead.py --flush-interval 0  # send every frame at once
    python benchmarks/rerun_overhead.py --scenario snr --repeats 5
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("CI", "1")  # never phone home from a benchmark (rerun CLI analytics)

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from sinks.rerun_sink import RerunSink, RunScorer  # noqa: E402
from sources.scenarios import get_scenario  # noqa: E402
from sources.synthetic import simulate_all  # noqa: E402
from tracker.bnp_tracker import make_tracker  # noqa: E402
from tracker.models.params import load_params  # noqa: E402
from tracker.state import frame_rng  # noqa: E402


def one_run(args: argparse.Namespace, out: Path) -> dict[str, np.ndarray | float]:
    scenario = get_scenario(args.scenario)
    params = scenario.adapt_params(load_params(args.params))
    frames = simulate_all(scenario, params, args.seed)
    tracker = make_tracker(args.tracker, params)
    state = tracker.initial_state()
    scorer = RunScorer()
    meta = {"scenario": args.scenario, "params": args.params, "tracker": args.tracker,
            "seed": str(args.seed)}
    t_trk, t_score, t_log = [], [], []
    cpu_trk = cpu_log = 0.0
    sink = RerunSink(out, metadata=meta, params=params, flush_interval=args.flush_interval)
    proc0, thr0 = time.process_time(), time.thread_time()
    for frame in frames:
        c0, t0 = time.thread_time(), time.perf_counter()
        state, est = tracker.step(state, frame, frame_rng(args.tracker_seed, frame.frame))
        c1, t1 = time.thread_time(), time.perf_counter()
        scores = scorer.update(frame, est)
        c2, t2 = time.thread_time(), time.perf_counter()
        sink.log(frame, est, **scores)
        c3, t3 = time.thread_time(), time.perf_counter()
        t_trk.append(t1 - t0)
        t_score.append(t2 - t1)
        t_log.append(t3 - t2)
        cpu_trk += c1 - c0
        cpu_log += c3 - c2
    c4, t4 = time.thread_time(), time.perf_counter()
    sink.close()
    c5, t5 = time.thread_time(), time.perf_counter()
    cpu_log += c5 - c4
    # CPU of every other thread of the process (Rerun's batcher and file writer, which only
    # exist because of the sink), charged to logging
    background = (time.process_time() - proc0) - (time.thread_time() - thr0)
    return {"tracker": np.array(t_trk) * 1e3, "score": np.array(t_score) * 1e3,
            "log": np.array(t_log) * 1e3, "close": (t5 - t4) * 1e3, "frames": len(frames),
            "bytes": out.stat().st_size, "cpu_trk": cpu_trk * 1e3, "cpu_log": cpu_log * 1e3,
            "cpu_bg": max(background, 0.0) * 1e3}


def _row(name: str, ms: np.ndarray) -> str:
    return (f"{name:<22} median {np.median(ms):7.3f}  mean {ms.mean():7.3f}  "
            f"p95 {np.percentile(ms, 95):7.3f} ms/frame")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="vo2017")
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--tracker", default="ddp", choices=("ddp", "dpyp"))
    ap.add_argument("--seed", type=int, default=1, help="simulation seed")
    ap.add_argument("--tracker-seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3, help="runs; the figures pool all frames")
    ap.add_argument("--flush-interval", type=float, default=1.0,
                    help="RerunSink flush_interval in seconds (0: flush after every frame)")
    args = ap.parse_args()

    pooled: dict[str, list] = {"tracker": [], "score": [], "log": []}
    closes, size, n = [], 0, 0
    cpu = {"cpu_trk": 0.0, "cpu_log": 0.0, "cpu_bg": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            res = one_run(args, Path(tmp) / f"run{r}.rrd")
            for k in pooled:
                pooled[k].append(res[k])
            closes.append(res["close"])
            for k in cpu:
                cpu[k] += res[k]
            size, n = res["bytes"], res["frames"]
    trk, score, log = (np.concatenate(pooled[k]) for k in ("tracker", "score", "log"))
    print(f"{args.scenario} seed {args.seed}, tracker {args.tracker}, {n} frames x {args.repeats} runs, "
          f"flush_interval {args.flush_interval:g} s, {os.cpu_count()} cpu(s), "
          f"load average {os.getloadavg()[0]:.2f}")
    print(_row("tracker step", trk))
    print(_row("scoring (OSPA, OSPA2)", score))
    print(_row("rerun logging", log))
    print(f"{'close (footer)':<22} {np.mean(closes):7.1f} ms per run; file {size / 1024:.0f} KiB per run")
    frames_total = n * args.repeats
    print("CPU time per frame (immune to other processes' load): "
          f"tracker {cpu['cpu_trk'] / frames_total:.3f} ms, logging {cpu['cpu_log'] / frames_total:.3f} ms "
          f"(incl. flushes and close) + Rerun background threads {cpu['cpu_bg'] / frames_total:.3f} ms")
    print(f"logging / tracker: wall median {np.median(log) / np.median(trk):.3f}, "
          f"wall total {log.sum() / trk.sum():.3f} "
          f"(with close: {(log.sum() + sum(closes)) / trk.sum():.3f}), "
          f"CPU {(cpu['cpu_log'] + cpu['cpu_bg']) / cpu['cpu_trk']:.3f}")


if __name__ == "__main__":
    main()
