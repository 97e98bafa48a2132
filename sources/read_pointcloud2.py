"""``sensor_msgs/msg/PointCloud2`` -> ``xy`` (a reader of :data:`sources.readers.READERS`).

Every point gives one row ``[x, y]`` from its ``x`` and ``y`` fields, in the cloud's
``header.frame_id`` frame; ``z`` and every other field (intensity, ring, ...) are dropped: the
tracker is 2-D, so a point is its projection on the ground plane.  Points with a non-finite
``x`` or ``y`` (the NaN of an organised cloud) are dropped.  The fields are read with one
numpy view of the data buffer (any numeric ``datatype``, either byte order, padded rows).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bnptrack.sources.scan import Scan, finite_rows, stamp_ns_of

__all__ = ["PointCloud2Reader", "POINTFIELD_DTYPES", "xy_columns"]

#: ``sensor_msgs/msg/PointField`` datatypes (INT8 = 1 ... FLOAT64 = 8) as numpy types.
POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def xy_columns(data: bytes, offsets: tuple[int, int], types: tuple[str, str], n_points: int,
               point_step: int, big_endian: bool = False) -> np.ndarray:
    """``(n_points, 2)`` float64 rows of the two fields at ``offsets`` (numpy ``types``) of
    ``n_points`` packed points of ``point_step`` bytes each in ``data``."""
    order = ">" if big_endian else "<"
    dtype = np.dtype({"names": ["x", "y"], "formats": [order + types[0], order + types[1]],
                      "offsets": list(offsets), "itemsize": point_step})
    need = n_points * point_step
    if len(data) < need:
        raise ValueError(f"the data holds {len(data)} bytes, {n_points} points of {point_step} bytes need {need}")
    pts = np.frombuffer(data, dtype=dtype, count=n_points)
    z = np.empty((n_points, 2))
    z[:, 0] = pts["x"]
    z[:, 1] = pts["y"]
    return finite_rows(z)


def _field(fields: Any, name: str) -> tuple[int, str]:
    for f in fields:
        if f.name == name:
            dtype = POINTFIELD_DTYPES.get(int(f.datatype))
            if dtype is None:
                raise ValueError(f"field {name!r} has an unknown datatype {f.datatype}")
            return int(f.offset), dtype
    raise ValueError(f"the cloud has no {name!r} field (fields: {', '.join(f.name for f in fields) or 'none'})")


class PointCloud2Reader:
    """Read a decoded ``PointCloud2``: one row ``[x, y]`` per point."""

    kind = "xy"

    def scan(self, msg: Any) -> Scan:
        (ox, tx), (oy, ty) = _field(msg.fields, "x"), _field(msg.fields, "y")
        height, width, step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
        data = bytes(msg.data)
        big = bool(msg.is_bigendian)
        if height <= 1 or row_step == width * step:
            z = xy_columns(data, (ox, oy), (tx, ty), height * width, step, big)
        else:  # padded rows: each row on its own
            rows = [xy_columns(data[r * row_step:(r + 1) * row_step], (ox, oy), (tx, ty), width, step, big)
                    for r in range(height)]
            z = np.concatenate(rows) if rows else np.empty((0, 2))
        header = msg.header
        return Scan(stamp_ns_of(header.stamp.sec, header.stamp.nanosec), header.frame_id, z)
