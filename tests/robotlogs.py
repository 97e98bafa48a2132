"""Real ROS 2 and Foxglove MCAP logs made from bnptrack frames (importable as ``robotlogs``).

The messages are written with the libraries' writers (``mcap_ros2.writer``,
``mcap_protobuf.writer``; Foxglove JSON with ``mcap.writer``) and the real message definitions
as schema text: ``rosbags``' bundled ROS 2 Humble definitions, plus the ``radar_msgs`` and
``vision_msgs`` definitions shipped under ``tests/data/ros2msg``.  Each frame becomes one
message: its ``sensor`` the ``frame_id``, its stamp the header stamp (the MCAP log time is
``stamp + LOG_DELAY_NS``, so a reader that used the log time would be caught).
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Iterable
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

MSG_DIR = Path(__file__).resolve().parent / "data" / "ros2msg"
LOG_DELAY_NS = 5_000_000


@cache
def typestore():
    """rosbags' ROS 2 Humble types plus the shipped radar_msgs / vision_msgs definitions."""
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    ts = get_typestore(Stores.ROS2_HUMBLE)
    types: dict = {}
    for p in sorted(MSG_DIR.glob("*/msg/*.msg")):
        types.update(get_types_from_msg(p.read_text(), f"{p.parent.parent.name}/msg/{p.stem}"))
    ts.register(types)
    return ts


def msgdef(datatype: str) -> str:
    """The ``ros2msg`` schema text of ``datatype`` (with its dependencies), as ROS 2 writes it."""
    return typestore().generate_msgdef(datatype, ros_version=2)[0]


def header(stamp_ns: int, frame_id: str) -> dict:
    return {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": frame_id}


def radar_scan(frame) -> dict:
    """A RadarScan of a bearing_range frame: azimuth = -bearing (REP 103, anticlockwise)."""
    returns = [{"range": float(r), "azimuth": float(-b), "elevation": 0.0, "doppler_velocity": 0.0,
                "amplitude": 0.0} for b, r in frame.z]
    return {"header": header(frame.stamp_ns, frame.sensor), "returns": returns}


def pointcloud2(frame, z_value: float = 1.5) -> dict:
    """A PointCloud2 (float64 x, y, z fields; an intensity field) of an xy frame."""
    n = frame.z.shape[0]
    pts = np.zeros(n, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("intensity", "<f4")])
    pts["x"], pts["y"], pts["z"], pts["intensity"] = frame.z[:, 0], frame.z[:, 1], z_value, 7.0
    fields = [{"name": "x", "offset": 0, "datatype": 8, "count": 1}, {"name": "y", "offset": 8, "datatype": 8, "count": 1},
              {"name": "z", "offset": 16, "datatype": 8, "count": 1},
              {"name": "intensity", "offset": 24, "datatype": 7, "count": 1}]
    return {"header": header(frame.stamp_ns, frame.sensor), "height": 1, "width": n, "fields": fields,
            "is_bigendian": False, "point_step": pts.itemsize, "row_step": pts.itemsize * n,
            "data": pts.tobytes(), "is_dense": True}


def _pose(x: float, y: float) -> dict:
    return {"position": {"x": float(x), "y": float(y), "z": 0.5},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def pose_array(frame) -> dict:
    return {"header": header(frame.stamp_ns, frame.sensor), "poses": [_pose(x, y) for x, y in frame.z]}


def detection3d_array(frame) -> dict:
    dets = [{"header": header(frame.stamp_ns, frame.sensor),
             "results": [{"hypothesis": {"class_id": "car", "score": 0.9},
                          "pose": {"pose": _pose(x, y), "covariance": [0.0] * 36}}],
             "bbox": {"center": _pose(x, y), "size": {"x": 4.0, "y": 2.0, "z": 1.5}}, "id": ""}
            for x, y in frame.z]
    return {"header": header(frame.stamp_ns, frame.sensor), "detections": dets}


def tf_static(transforms: Iterable[tuple[str, str, float, float, float]], stamp_ns: int = 0) -> dict:
    """A TFMessage of ``(parent, child, x, y, yaw)`` transforms (yaw anticlockwise from +x)."""
    out = []
    for parent, child, x, y, yaw in transforms:
        rot = {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)} if yaw else \
            {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
        out.append({"header": header(stamp_ns, parent), "child_frame_id": child,
                    "transform": {"translation": {"x": x, "y": y, "z": 0.0}, "rotation": rot}})
    return {"transforms": out}


def write_ros2(path: Path, items: Iterable[tuple[str, str, dict, int]]) -> Path:
    """Write ``(topic, datatype, message, log_time)`` items with ``mcap_ros2.writer``."""
    from mcap_ros2.writer import Writer

    schemas: dict[str, Any] = {}
    with open(path, "wb") as f:
        w = Writer(f)
        for topic, datatype, msg, log_time in items:
            if datatype not in schemas:
                schemas[datatype] = w.register_msgdef(datatype, msgdef(datatype))
            w.write_message(topic, schemas[datatype], msg, log_time=log_time)
        w.finish()
    return path


def ros2_items(frames, topic: str, datatype: str, convert) -> list[tuple[str, str, dict, int]]:
    return [(topic, datatype, convert(f), f.stamp_ns + LOG_DELAY_NS) for f in frames]


def foxglove_pointcloud(frame):
    """A protobuf ``foxglove.PointCloud`` of an xy frame (float64 x, y, z)."""
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    pts = np.zeros((frame.z.shape[0], 3))
    pts[:, :2] = frame.z
    msg = PointCloud(frame_id=frame.sensor, point_stride=24, data=pts.astype("<f8").tobytes())
    msg.timestamp.FromNanoseconds(frame.stamp_ns)
    msg.pose.orientation.w = 1.0
    for i, name in enumerate("xyz"):
        msg.fields.append(PackedElementField(name=name, offset=8 * i, type=PackedElementField.FLOAT64))
    return msg


def write_foxglove_protobuf(path: Path, frames, topic: str = "/lidar/points") -> Path:
    from mcap_protobuf.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        for fr in frames:
            w.write_message(topic, foxglove_pointcloud(fr), log_time=fr.stamp_ns + LOG_DELAY_NS,
                            publish_time=fr.stamp_ns)
        w.finish()
    return path


def write_foxglove_json(path: Path, frames, topic: str = "/lidar/points") -> Path:
    """``foxglove.PointCloud`` in Foxglove's JSON form (data in base64), with ``mcap.writer``."""
    from google.protobuf.json_format import MessageToDict
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foxglove.PointCloud", "jsonschema", json.dumps({"title": "foxglove.PointCloud"}).encode())
        ch = w.register_channel(topic, "json", sid)
        for fr in frames:
            d = MessageToDict(foxglove_pointcloud(fr), preserving_proto_field_name=True)
            d["timestamp"] = {"sec": fr.stamp_ns // 10**9, "nsec": fr.stamp_ns % 10**9}
            d["data"] = base64.b64encode(np.c_[fr.z, np.zeros(len(fr.z))].astype("<f8").tobytes()).decode()
            w.add_message(ch, log_time=fr.stamp_ns + LOG_DELAY_NS, publish_time=fr.stamp_ns,
                          data=json.dumps(d).encode())
        w.finish()
    return path
