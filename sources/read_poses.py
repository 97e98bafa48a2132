"""Object positions -> ``xy`` (readers of :data:`sources.readers.READERS`):
``vision_msgs/msg/Detection3DArray`` (each detection's box centre,
``detections[i].bbox.center.position``) and ``geometry_msgs/msg/PoseArray``
(``poses[i].position``).  One row ``[x, y]`` per object in the message's ``header.frame_id``
frame; ``z``, the orientation, sizes and class hypotheses are not used."""

from __future__ import annotations

from typing import Any

import numpy as np

from bnptrack.sources.scan import Scan, finite_rows, stamp_ns_of

__all__ = ["Detection3DArrayReader", "PoseArrayReader"]


def _rows(points: list[Any], header: Any) -> Scan:
    z = np.array([(p.x, p.y) for p in points], dtype=np.float64).reshape(-1, 2)
    return Scan(stamp_ns_of(header.stamp.sec, header.stamp.nanosec), header.frame_id, finite_rows(z))


class Detection3DArrayReader:
    """Read a decoded ``Detection3DArray``: one row per detection (its box centre)."""

    kind = "xy"

    def scan(self, msg: Any) -> Scan:
        return _rows([d.bbox.center.position for d in msg.detections], msg.header)


class PoseArrayReader:
    """Read a decoded ``PoseArray``: one row per pose (its position)."""

    kind = "xy"

    def scan(self, msg: Any) -> Scan:
        return _rows([p.position for p in msg.poses], msg.header)
