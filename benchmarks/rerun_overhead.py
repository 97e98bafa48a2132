"""Cost of a Rerun recording (.rrd) in an offline `bnptrack track --rrd` run.

Two parts:

1. The whole command, the figure the sink's target names ("the sink adds under 10% to an
   offline `bnptrack track --rrd` run"): ``python -m bnptrack track LOG -q`` and the same with
   ``--rrd FILE``, run alternately (A B A B ...) ``--repeats`` times each, so that the load of
   other processes hits both alike.  For each: wall clock (``time.perf_counter`` around the
   command) and CPU time (user + sys of the command and its children, from
   ``resource.getrusage(RUSAGE_CHILDREN)``).  Prints the medians, the ratio of the medians and
   the median of the per-pair ratios.  With ``--rrd`` the recording is written by a child process
   (``sinks.rerun_process``), so the wall clock shows what the user waits for and the CPU time
   what the recording costs in all.  Each round also runs the command without ``--rrd`` beside
   a process that only imports rerun (``import bnptrack.sinks.rerun_sink``), started with it: the
   machine's floor, the slowdown the recording's unavoidable import alone causes on the other
   core (``--no-floor`` skips it).
2. Per frame, in this process: the tracker's step, the hand-off on the tracker's thread
   (``RecordingProcess.log``: OSPA/OSPA(2) scoring, pickling, writing to the pipe) and the final
   ``close`` (waiting for the child to write the last chunks and the footer; the child is given
   ``--head-start`` seconds to import rerun first, as building the tracker gives it in
   ``bnptrack track``); then the sink's
   own work per frame (``RerunSink.log`` and ``close`` over the same frames, in this process:
   the work the child does beside the tracker).

    python benchmarks/rerun_overhead.py                        # vo2017-s1, ddp, 5 repeats
    python benchmarks/rerun_overhead.py --repeats 10 --part command
    python benchmarks/rerun_overhead.py --log recordings/snr-s1.mcap --part frame

Prints the load average before and after: on a machine whose cores are busy with other work the
child cannot overlap the tracker, and the wall ratio moves towards the CPU ratio.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("CI", "1")  # never phone home from a benchmark (rerun CLI analytics)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


# --------------------------------------------------------------------------- whole command


def _timed(cmd: list[str], env: dict[str, str], beside: list[str] | None = None) -> tuple[float, float]:
    """(wall s, CPU s of the command and its children) of one run of ``cmd``; with ``beside``,
    that other command is started just before it (its CPU is not counted; it is waited for
    after the timing)."""
    other = subprocess.Popen(beside, env=env, stdout=subprocess.DEVNULL) if beside else None
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if other is not None:
        other.wait()
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _ratios(name: str, base: np.ndarray, other: np.ndarray) -> str:
    return (f"  {name:<44} median {np.median(other):6.3f} s   ratio of medians "
            f"{np.median(other) / np.median(base):.3f}   median of pair ratios {np.median(other / base):.3f}   "
            f"(pairs: min {np.min(other / base):.3f}, max {np.max(other / base):.3f})")


def command_part(args: argparse.Namespace, tmp: Path) -> None:
    paths = [str(ROOT), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}  # this tree's code
    base = [sys.executable, "-m", "bnptrack", "track", str(args.log), "--tracker", args.tracker, "-q"]
    plain = [*base, "--out", str(tmp / "plain.tracks.mcap")]
    rrd = [*base, "--out", str(tmp / "rrd.tracks.mcap"), "--rrd", str(tmp / "run.rrd")]
    # the machine's floor: the plain command beside a process that only imports rerun (what the
    # recording process must do on the other core, without recording anything)
    import_only = [sys.executable, "-c", "import numpy; import bnptrack.sinks.rerun_sink"]
    _timed(plain, env)  # warm the page cache and numba's on-disk cache
    _timed(rrd, env)
    a, b, f = [], [], []
    for i in range(args.repeats):
        a.append(_timed(plain, env))
        b.append(_timed(rrd, env))
        if args.floor:
            f.append(_timed(plain, env, beside=import_only))
        if args.verbose:
            print(f"  round {i}: {a[-1][0]:.3f} s / {b[-1][0]:.3f} s wall ({b[-1][0] / a[-1][0]:.3f})"
                  + (f", beside the import {f[-1][0]:.3f} s" if f else "")
                  + f", load average {os.getloadavg()[0]:.2f}")
    wa, ca = np.array(a).T
    wb, cb = np.array(b).T
    print(f"whole command, {args.repeats} alternating rounds: `bnptrack track {args.log} "
          f"--tracker {args.tracker} -q` (median {np.median(wa):.3f} s wall) and:")
    print(_ratios("with --rrd", wa, wb))
    if f:
        print(_ratios("without --rrd, beside `import bnptrack.sinks.rerun_sink`", wa, np.array(f).T[0]))
    print(f"  CPU    median {np.median(ca):6.3f} s / {np.median(cb):6.3f} s   ratio of medians "
          f"{np.median(cb) / np.median(ca):.3f}   (user + sys, the recording process included)")
    print(f"  recording {(tmp / 'run.rrd').stat().st_size / 1024:.0f} KiB")


# --------------------------------------------------------------------------- per frame


def _setup(args: argparse.Namespace):
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.sources.mcap_log import iter_frames, read_metadata

    meta = read_metadata(args.log)
    setup = tracker_setup(args.tracker, metadata=meta)
    return setup.tracker, setup.params, list(iter_frames(args.log))


def _row(name: str, ms: np.ndarray) -> str:
    return (f"  {name:<36} median {np.median(ms):7.3f}  mean {ms.mean():7.3f}  "
            f"p95 {np.percentile(ms, 95):7.3f} ms/frame")


def frame_part(args: argparse.Namespace, tmp: Path) -> None:
    from bnptrack.sinks.rerun_process import RecordingProcess
    from bnptrack.tracker.state import run

    tracker, params, frames = _setup(args)
    step, hand, closes = [], [], []
    for r in range(args.repeats):  # rerun is not imported here yet: the child is a fork
        with RecordingProcess() as rec:
            time.sleep(args.head_start)  # what building the tracker gives it in `bnptrack track`
            rec.open(tmp / f"frame{r}.rrd", params=params)
            it = run(tracker, frames, 0)
            while True:
                t0 = time.perf_counter()
                item = next(it, None)
                t1 = time.perf_counter()
                if item is None:
                    break
                rec.log(item[0], item[1])
                step.append(t1 - t0)
                hand.append(time.perf_counter() - t1)
            t0 = time.perf_counter()
            rec.close()
            closes.append(time.perf_counter() - t0)
    kept = [(f, e) for f, e, _s in run(tracker, frames, 0)]
    score, sink_log, sink_closes = _child_share(args, tmp, params, kept)
    step_ms, hand_ms, score_ms, sink_ms = (np.array(v) * 1e3 for v in (step, hand, score, sink_log))
    print(f"per frame, {len(frames)} frames x {args.repeats} runs of {args.tracker} on {args.log}")
    print(_row("tracker step", step_ms))
    print(_row("hand-off (score, pickle, write)", hand_ms))
    print(_row("  of which scoring (measured apart)", score_ms))
    print(f"  {'close (wait for the recording)':<36} {np.mean(closes) * 1e3:7.1f} ms per run")
    print(f"  hand-off / tracker: medians {np.median(hand_ms) / np.median(step_ms):.3f}, whole run "
          f"{hand_ms.sum() / step_ms.sum():.3f} (with close: "
          f"{(hand_ms.sum() + sum(closes) * 1e3) / step_ms.sum():.3f})")
    print("  the child's work, measured in this process:")
    print(_row("RerunSink.log", sink_ms))
    print(f"  {'RerunSink.close (last flush, footer)':<36} {np.mean(sink_closes) * 1e3:7.1f} ms per run")


def _child_share(args: argparse.Namespace, tmp: Path, params, kept: list) -> tuple[list, list, list]:
    """Scoring (s per frame), and ``RerunSink.log`` (s per frame) and ``close`` (s per run)
    with the child's settings, over the frames and estimates ``kept``, in this process."""
    from bnptrack.sinks.rerun_sink import RerunSink
    from bnptrack.sinks.rerun_process import CHILD_FLUSH_INTERVAL
    from bnptrack.sinks.run_scorer import RunScorer

    score, sink_log, sink_closes = [], [], []
    for r in range(args.repeats):
        scorer = RunScorer()
        scores = []
        for f, e in kept:
            t0 = time.perf_counter()
            scores.append(scorer.update(f, e))
            score.append(time.perf_counter() - t0)
        sink = RerunSink(tmp / f"sink{r}.rrd", params=params, handle_signals=False,
                         flush_interval=CHILD_FLUSH_INTERVAL)
        for (f, e), s in zip(kept, scores):
            t0 = time.perf_counter()
            sink.log(f, e, **s)
            sink_log.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        sink.close()
        sink_closes.append(time.perf_counter() - t0)
    return score, sink_log, sink_closes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", type=Path, default=ROOT / "recordings" / "vo2017-s1.mcap")
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--repeats", type=int, default=5, help="pairs of commands / per-frame runs")
    ap.add_argument("--part", choices=("all", "command", "frame"), default="all")
    ap.add_argument("--verbose", "-v", action="store_true", help="print every pair of commands")
    ap.add_argument("--no-floor", dest="floor", action="store_false",
                    help="skip the third command of each round (plain, beside a process importing rerun)")
    ap.add_argument("--head-start", type=float, default=1.5,
                    help="per-frame part: seconds the recording process gets to import rerun "
                    "before the first frame (bnptrack track builds the tracker meanwhile)")
    args = ap.parse_args()
    print(f"{os.cpu_count()} cpu(s), load average {os.getloadavg()[0]:.2f} (1 min) at the start")
    with tempfile.TemporaryDirectory() as tmp:
        if args.part in ("all", "command"):
            command_part(args, Path(tmp))
        if args.part in ("all", "frame"):
            frame_part(args, Path(tmp))
    print(f"load average {os.getloadavg()[0]:.2f} (1 min) at the end")


if __name__ == "__main__":
    main()
