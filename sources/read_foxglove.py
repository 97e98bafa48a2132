"""``foxglove.PointCloud`` (protobuf or JSON) -> ``xy`` (a reader of
:data:`sources.readers.READERS`).

Every point gives one row ``[x, y]`` from its ``x`` and ``y`` fields (``z`` and the other
fields dropped), placed by the cloud's ``pose`` (the points' origin in ``frame_id``; projected
to the ground plane as :mod:`sources.tf_static` does), in the ``frame_id`` frame.  The time is
``timestamp``.  A JSON message has Foxglove's JSON form: ``data`` in base64, ``timestamp``
as ``{"sec", "nsec"}``, a field's ``type`` as its number or name.
"""

from __future__ import annotations

import base64
from types import SimpleNamespace
from typing import Any

from bnptrack.sources.read_pointcloud2 import xy_columns
from bnptrack.sources.readers import Scan, stamp_ns_of
from bnptrack.sources.tf_static import IDENTITY, pose_of_transform

__all__ = ["FoxglovePointCloudReader", "NUMERIC_TYPES"]

#: ``foxglove.PackedElementField.NumericType`` (UINT8 = 1 ... FLOAT64 = 8) as numpy types.
NUMERIC_TYPES = {1: "u1", 2: "i1", 3: "u2", 4: "i2", 5: "u4", 6: "i4", 7: "f4", 8: "f8"}
_TYPE_NAMES = {"UINT8": 1, "INT8": 2, "UINT16": 3, "INT16": 4, "UINT32": 5, "INT32": 6, "FLOAT32": 7, "FLOAT64": 8}


def _ns(obj: Any) -> SimpleNamespace:
    """A JSON object as attributes (recursively)."""
    if isinstance(obj, dict):
        return SimpleNamespace(**{k: _ns(v) for k, v in obj.items()})
    if isinstance(obj, list):
        return [_ns(v) for v in obj]  # type: ignore[return-value]
    return obj


def _field(fields: Any, name: str) -> tuple[int, str]:
    for f in fields:
        if f.name == name:
            t = _TYPE_NAMES.get(f.type, f.type) if isinstance(f.type, str) else int(f.type)
            dtype = NUMERIC_TYPES.get(t)
            if dtype is None:
                raise ValueError(f"field {name!r} has an unknown type {f.type!r}")
            return int(f.offset), dtype
    raise ValueError(f"the cloud has no {name!r} field (fields: {', '.join(f.name for f in fields) or 'none'})")


class FoxglovePointCloudReader:
    """Read a decoded ``foxglove.PointCloud`` (protobuf message or JSON object)."""

    kind = "xy"

    def scan(self, msg: Any) -> Scan:
        if isinstance(msg, dict):
            msg = _ns(msg)
            data = base64.b64decode(msg.data) if getattr(msg, "data", "") else b""
            ts = getattr(msg, "timestamp", None)
            stamp = stamp_ns_of(ts.sec, ts.nsec) if ts is not None else None
        else:
            data = bytes(msg.data)
            stamp = stamp_ns_of(msg.timestamp.seconds, msg.timestamp.nanos) if msg.HasField("timestamp") else None
        fields = list(getattr(msg, "fields", []))
        (ox, tx), (oy, ty) = _field(fields, "x"), _field(fields, "y")
        stride = int(msg.point_stride)
        if stride <= 0:
            raise ValueError(f"point_stride must be > 0, got {stride}")
        z = xy_columns(data, (ox, oy), (tx, ty), len(data) // stride, stride)
        pose = getattr(msg, "pose", None)
        place = IDENTITY
        if pose is not None and getattr(pose, "orientation", None) is not None:
            q = pose.orientation
            if (q.x, q.y, q.z, q.w) != (0, 0, 0, 0):  # an unset orientation is no rotation
                place = pose_of_transform(pose.position, q)
            elif (pose.position.x, pose.position.y) != (0, 0):
                place = pose_of_transform(pose.position, SimpleNamespace(x=0.0, y=0.0, z=0.0, w=1.0))
        return Scan(stamp, str(getattr(msg, "frame_id", "")), place.place(z))
