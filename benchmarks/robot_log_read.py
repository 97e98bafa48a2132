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
        for i in range(args.repeats):  # A B, then B A: a drift of the machine's load cancels
            order = [(t_json, json_log, None), (t_ros, ros, TOPICS)]
            for times, log, topics in (order if i % 2 == 0 else order[::-1]):
                times.append(timed(lambda: list(iter_frames(log, topics))))
        sizes = (json_log.stat().st_size, ros.stat().st_size)
        decode = decode_times(ros)
    mj, mr = statistics.median(t_json), statistics.median(t_ros)
    ratios = [r / j for j, r in zip(t_json, t_ros)]
    n = args.messages
    print(f"{n} messages x {args.returns} returns; JSON log {sizes[0]} bytes, ROS 2 log {sizes[1]} bytes")
    print(f"JSON  median {mj:.3f} s ({1e6 * mj / n:.1f} us/message)")
    print(f"ROS 2 median {mr:.3f} s ({1e6 * mr / n:.1f} us/message)")
    print(f"ratio ROS 2 / JSON: of the medians {mr / mj:.2f}; of the minima {min(t_ros) / min(t_json):.2f}; "
          f"median of the {len(ratios)} pairs "
          f"{statistics.median(ratios):.2f} (min {min(ratios):.2f}, max {max(ratios):.2f})")
    print(f"CDR decode alone (median of 3): rosbags {1e6 * decode['rosbags'] / n:.1f} us/message, "
          f"mcap_ros2 DecoderFactory {1e6 * decode['mcap_ros2'] / n:.1f} us/message")
    print(json.dumps({"messages": n, "json_s": mj, "ros2_s": mr, "ratio_of_medians": mr / mj,
                      "ratio_of_minima": min(t_ros) / min(t_json),
                      "ratio_median_pair": statistics.median(ratios), "decode_s": decode}))


def decode_times(ros: Path) -> dict[str, float]:
    """Median time to decode every message of ``ros`` with each CDR library (no reading)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    with open(ros, "rb") as f:
        msgs = [(schema, m.data) for schema, _, m in make_reader(f).iter_messages()]
    schema = msgs[0][0]
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(schema.data.decode(), schema.name))
    decoder = DecoderFactory().decoder_for("cdr", schema)
    out = {}
    for name, fn in (("rosbags", lambda d: store.deserialize_cdr(d, schema.name)), ("mcap_ros2", decoder)):
        out[name] = statistics.median(timed(lambda: [fn(d) for _, d in msgs]) for _ in range(3))
    return out


if __name__ == "__main__":
    main()
