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
from bnptrack.sources.scan import Scan, stamp_ns_of
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
    for f in fields:  # a JSON field may omit what is at its default (offset 0)
        if getattr(f, "name", "") == name:
            ftype = getattr(f, "type", 0)
            t = _TYPE_NAMES.get(ftype, 0) if isinstance(ftype, str) else int(ftype)
            dtype = NUMERIC_TYPES.get(t)
            if dtype is None:
                raise ValueError(f"field {name!r} has an unknown type {ftype!r}")
            return int(getattr(f, "offset", 0)), dtype
    names = ", ".join(getattr(f, "name", "?") for f in fields) or "none"
    raise ValueError(f"the cloud has no {name!r} field (fields: {names})")


def _xyzw(d: Any, keys: str) -> SimpleNamespace:
    """A JSON vector / quaternion with its omitted (default) components as 0."""
    d = d if isinstance(d, dict) else {}
    return SimpleNamespace(**{k: float(d.get(k, 0.0)) for k in keys})


def _place(position: Any, q: Any) -> Any:
    """The cloud's pose as a ground-plane transform (an all-zero quaternion: no rotation)."""
    if (q.x, q.y, q.z, q.w) == (0, 0, 0, 0):
        q = SimpleNamespace(x=0.0, y=0.0, z=0.0, w=1.0)
    if (position.x, position.y, q.x, q.y, q.z, q.w) == (0, 0, 0, 0, 0, 1):
        return IDENTITY
    return pose_of_transform(position, q)


class FoxglovePointCloudReader:
    """Read a decoded ``foxglove.PointCloud`` (protobuf message or JSON object)."""

    kind = "xy"

    def scan(self, msg: Any) -> Scan:
        if isinstance(msg, dict):
            data = base64.b64decode(msg.get("data", ""))
            ts = msg.get("timestamp") or {}
            stamp = stamp_ns_of(ts.get("sec", 0), ts.get("nsec", 0))
            fields = [_ns(f) for f in msg.get("fields", [])]
            stride, frame_id = int(msg.get("point_stride", 0)), str(msg.get("frame_id", ""))
            pose = msg.get("pose") or {}
            place = _place(_xyzw(pose.get("position"), "xyz"), _xyzw(pose.get("orientation"), "xyzw"))
        else:
            data, fields, stride, frame_id = bytes(msg.data), list(msg.fields), int(msg.point_stride), msg.frame_id
            stamp = stamp_ns_of(msg.timestamp.seconds, msg.timestamp.nanos)
            place = _place(msg.pose.position, msg.pose.orientation)
        (ox, tx), (oy, ty) = _field(fields, "x"), _field(fields, "y")
        if stride <= 0:
            raise ValueError(f"point_stride must be > 0, got {stride}")
        z = xy_columns(data, (ox, oy), (tx, ty), len(data) // stride, stride)
        return Scan(stamp, frame_id, place.place(z))
