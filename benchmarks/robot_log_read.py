"""Reading a ROS 2 log against reading bnptrack's JSON log of the same measurements.

Writes two logs of ``--messages`` scans of ``--returns`` bearing-range measurements each
(seeded; float32 values, as a RadarScan carries them): a bnptrack JSON log
(``sinks.mcap_writer.McapLogWriter``) and a ROS 2 log (``radar_msgs/msg/RadarScan`` on
``/radar/scan`` with ``mcap_ros2.writer`` and the definitions of tests/data/ros2msg), checks
that both read to the same frames, then times ``list(iter_frames(...))`` of each, interleaved
A/B/A/B over ``--repeats`` rounds, and prints the median times and their ratio (ROS 2 / JSON)
as the last line (JSON).

    nice -n 5 python benchmarks/robot_log_read.py --messages 10000 --repeats 7

Needs the test extra (rosbags, for the ROS 2 schema text).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import robotlogs  # noqa: E402  (tests/robotlogs.py: the ROS 2 writer of the tests)

from bnptrack.sinks.mcap_writer import McapLogWriter  # noqa: E402
from bnptrack.sources.mcap_log import iter_frames  # noqa: E402
from bnptrack.tracker.types import Frame  # noqa: E402

TOPICS = {"/radar/scan": "/measurements"}


def make_frames(n: int, returns: int, seed: int) -> list[Frame]:
    """``n`` scans of ``returns`` measurements (float32 values), 0.1 s apart."""
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(1, n + 1):
        z = np.c_[rng.uniform(-1.5, 1.5, returns), rng.uniform(10.0, 2000.0, returns)]
        frames.append(Frame(k, k * 100_000_000, "radar0", "bearing_range", z.astype(np.float32).astype(np.float64)))
    return frames


def write_logs(frames: list[Frame], d: Path) -> tuple[Path, Path]:
    json_log = d / "scan.json.mcap"
    with McapLogWriter(json_log) as w:
        for f in frames:
            w.write_frame(f)
    ros = robotlogs.write_ros2(d / "scan.ros2.mcap",
                               robotlogs.ros2_items(frames, "/radar/scan", "radar_msgs/msg/RadarScan", robotlogs.radar_scan))
    return json_log, ros


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--messages", type=int, default=10_000)
    ap.add_argument("--returns", type=int, default=12)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    frames = make_frames(args.messages, args.returns, args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        json_log, ros = write_logs(frames, Path(tmp))
        a, b = list(iter_frames(json_log)), list(iter_frames(ros, TOPICS))
        assert len(a) == len(b) == args.messages
        assert all(x.frame == y.frame and x.stamp_ns == y.stamp_ns and np.array_equal(x.z, y.z) for x, y in zip(a, b))
        t_json, t_ros = [], []
        for _ in range(args.repeats):
            t_json.append(timed(lambda: list(iter_frames(json_log))))
            t_ros.append(timed(lambda: list(iter_frames(ros, TOPICS))))
        sizes = (json_log.stat().st_size, ros.stat().st_size)
    mj, mr = statistics.median(t_json), statistics.median(t_ros)
    ratios = [r / j for j, r in zip(t_json, t_ros)]
    print(f"{args.messages} messages x {args.returns} returns; JSON log {sizes[0]} bytes, ROS 2 log {sizes[1]} bytes")
    print(f"JSON  median {mj:.3f} s ({1e6 * mj / args.messages:.1f} us/message)")
    print(f"ROS 2 median {mr:.3f} s ({1e6 * mr / args.messages:.1f} us/message)")
    print(f"ratio ROS 2 / JSON: median of pairs {statistics.median(ratios):.2f} (min {min(ratios):.2f}, max {max(ratios):.2f})")
    print(json.dumps({"messages": args.messages, "json_s": mj, "ros2_s": mr, "ratio": statistics.median(ratios)}))


if __name__ == "__main__":
    main()
