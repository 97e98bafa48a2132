"""Sensor poses from ``/tf_static`` (``tf2_msgs/msg/TFMessage``), projected to the ground plane.

A ROS frame is x forward, y left, z up (REP 103); the root of the transform tree (``map``,
``odom``, ``world``, ...) is bnptrack's world frame, its x and y the world's x and y.  A
sensor frame's pose in the root is the composition of the static transforms from the root
down to it, each projected to 2-D: its translation's x, y and the rotation's effect on the
frame's +x axis (its boresight).  bnptrack's heading is the boresight's direction measured
from +y towards +x, so a boresight along the root's +x (yaw 0) is heading ``pi/2`` and one
along +y (yaw ``pi/2``) is heading ``0``: ``heading = atan2(c, s)`` for the boresight
``(c, s)``.  Dynamic ``/tf`` is not read (a moving platform's sensor pose per message is not
supported).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Pose2D", "IDENTITY", "pose_of_transform", "StaticTransforms"]


@dataclass(frozen=True)
class Pose2D:
    """A ground-plane transform: translation ``(x, y)`` and the unit direction ``(c, s)``
    of the frame's +x axis in the parent frame."""

    x: float
    y: float
    c: float
    s: float

    def then(self, child: Pose2D) -> Pose2D:
        """The pose of ``child`` (given in this frame) in this frame's parent."""
        c, s = self.c, self.s
        return Pose2D(self.x + c * child.x - s * child.y, self.y + s * child.x + c * child.y,
                      c * child.c - s * child.s, s * child.c + c * child.s)

    @property
    def is_identity(self) -> bool:
        return self == IDENTITY

    def heading(self) -> float:
        """bnptrack's heading of the frame's boresight (+x): from +y towards +x, radians."""
        return math.atan2(self.c, self.s)

    def bnptrack_pose(self) -> tuple[float, float, float]:
        """``(x, y, heading)`` as a frame's ``pose``."""
        return (float(self.x), float(self.y), self.heading())

    def place(self, z: np.ndarray) -> np.ndarray:
        """``(M, 2)`` points of this frame in the parent frame (unchanged for the identity)."""
        if self.is_identity or z.shape[0] == 0:
            return z
        out = np.empty_like(z)
        out[:, 0] = self.x + self.c * z[:, 0] - self.s * z[:, 1]
        out[:, 1] = self.y + self.s * z[:, 0] + self.c * z[:, 1]
        return out


IDENTITY = Pose2D(0.0, 0.0, 1.0, 0.0)


def pose_of_transform(translation: Any, rotation: Any) -> Pose2D:
    """The ground-plane projection of a translation and a unit quaternion (``x, y, z, w``):
    the rotated +x axis ``(1 - 2(y^2 + z^2), 2(xy + wz))``, normalised."""
    qx, qy, qz, qw = float(rotation.x), float(rotation.y), float(rotation.z), float(rotation.w)
    c = 1.0 - 2.0 * (qy * qy + qz * qz)
    s = 2.0 * (qx * qy + qw * qz)
    norm = math.hypot(c, s)
    if not norm > 1e-9:
        raise ValueError("the rotation points the frame's x axis straight up or down (no ground-plane heading)")
    if norm != 1.0:
        c, s = c / norm, s / norm
    # a quaternion of a right angle is not exact in floats (cos 45 deg != sin 45 deg): a
    # component within 1e-12 of 0 is 0, so a yaw of 90 degrees gives heading 0 exactly
    c, s = (0.0 if abs(c) < 1e-12 else c), (0.0 if abs(s) < 1e-12 else s)
    if c == 0.0 or s == 0.0:
        c, s = math.copysign(1.0, c) if c else 0.0, math.copysign(1.0, s) if s else 0.0
    return Pose2D(float(translation.x), float(translation.y), c, s)


class StaticTransforms:
    """The static transform tree of a log: ``add`` each ``TFMessage``, then ``pose(frame)``."""

    def __init__(self) -> None:
        self.parent: dict[str, tuple[str, Pose2D]] = {}

    def add(self, msg: Any) -> None:
        for t in msg.transforms:
            tr = t.transform
            self.parent[t.child_frame_id] = (t.header.frame_id, pose_of_transform(tr.translation, tr.rotation))

    def pose(self, frame_id: str) -> Pose2D | None:
        """The pose of ``frame_id`` in the root of its tree, or ``None`` when no static
        transform has ``frame_id`` as child (the frame is a root or unknown)."""
        if frame_id not in self.parent:
            return None
        chain: list[Pose2D] = []
        seen = {frame_id}
        name = frame_id
        while name in self.parent:
            name, pose = self.parent[name]
            chain.append(pose)
            if name in seen:
                raise ValueError(f"/tf_static has a cycle through frame {name!r}")
            seen.add(name)
        out = chain[-1]
        for pose in reversed(chain[:-1]):
            out = out.then(pose)
        return out
