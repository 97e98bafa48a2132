"""The tracks as a Foxglove scene (the ``foxglove`` entry of :data:`sinks.sink.SINKS`).

:class:`FoxgloveSceneSink` writes, beside ``/tracks``, the channel :data:`TOPIC_SCENE`
(``/tracks/scene``) of ``foxglove.SceneUpdate`` messages in Foxglove's JSON encoding, one per
frame, so the same ``tracks.mcap`` opens in Foxglove's 3D panel as well as in Rerun.  Each
update first deletes every entity (type ``ALL``), then adds one entity per reported track,
``id`` = its label, in the frame ``world`` (bnptrack's world x, y; z = 0):

* a sphere at the position (1 m);
* an arrow along the velocity, as long as the distance covered in one second;
* a flat ellipsoid: the 2-sigma ellipse of the position covariance (principal axes);
* a text with the track's display name (:func:`track_display_name`);
* metadata: ``existence`` and, for two-level trackers, ``cluster``.

When the run writes the MCAP log (the ``mcap`` sink on the same file) the channel goes into
that file; alone, the sink writes a file of its own.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sinks.records import SinkOptions, SinkRecord
from bnptrack.tracker.types import display_name

__all__ = ["FoxgloveSceneSink", "TOPIC_SCENE", "SCENE_SCHEMA", "scene_update", "track_display_name"]

TOPIC_SCENE = "/tracks/scene"
FRAME_ID = "world"
_COLOR = {"r": 0.1, "g": 0.6, "b": 1.0, "a": 1.0}
_ELLIPSE = {"r": 0.1, "g": 0.6, "b": 1.0, "a": 0.25}

#: The JSON Schema stored with the channel (its title names the Foxglove schema).
SCENE_SCHEMA = json.dumps({
    "title": "foxglove.SceneUpdate",
    "description": "An update to the entities displayed in a 3D scene",
    "type": "object",
    "properties": {"deletions": {"type": "array", "items": {"type": "object"}},
                   "entities": {"type": "array", "items": {"type": "object"}}},
}, separators=(",", ":")).encode()


def track_display_name(track: Any) -> str:
    """The name shown beside a track: :func:`tracker.types.display_name` of its label (the
    same name as in the Rerun recording, the summary and the export)."""
    return display_name(str(track.label))


def _time(stamp_ns: int) -> dict[str, int]:
    return {"sec": int(stamp_ns) // 1_000_000_000, "nsec": int(stamp_ns) % 1_000_000_000}


def _yaw_quaternion(yaw: float) -> dict[str, float]:
    """The rotation by ``yaw`` (anticlockwise from +x) about +z."""
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def _pose(x: float, y: float, yaw: float = 0.0) -> dict[str, Any]:
    return {"position": {"x": x, "y": y, "z": 0.0}, "orientation": _yaw_quaternion(yaw)}


def _ellipse(x: float, y: float, cov: np.ndarray) -> dict[str, Any]:
    """The 2-sigma ellipse of a 2x2 position covariance as a flat ellipsoid."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    vals = np.clip(vals, 0.0, None)
    yaw = math.atan2(vecs[1, 1], vecs[0, 1])  # the major axis (largest eigenvalue last)
    size = {"x": 4.0 * math.sqrt(vals[1]), "y": 4.0 * math.sqrt(vals[0]), "z": 0.05}
    return {"pose": _pose(x, y, yaw), "size": size, "color": _ELLIPSE}


def _entity(track: Any, stamp_ns: int) -> dict[str, Any]:
    px, vx, py, vy = (float(v) for v in track.state[:4])
    cov = np.asarray(track.covariance, dtype=float)[np.ix_([0, 2], [0, 2])]
    speed = math.hypot(vx, vy)
    arrows = []
    if speed > 0.0:
        head = min(0.3 * speed, 5.0)
        arrows.append({"pose": _pose(px, py, math.atan2(vy, vx)), "shaft_length": max(speed - head, 0.0),
                       "shaft_diameter": 0.4, "head_length": head, "head_diameter": 1.2, "color": _COLOR})
    metadata = [{"key": "existence", "value": f"{float(track.existence):.6g}"}]
    if track.cluster is not None:
        metadata.append({"key": "cluster", "value": str(track.cluster)})
    return {
        "timestamp": _time(stamp_ns), "frame_id": FRAME_ID, "id": str(track.label),
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": metadata,
        "arrows": arrows,
        "spheres": [{"pose": _pose(px, py), "size": {"x": 1.0, "y": 1.0, "z": 1.0}, "color": _COLOR},
                    _ellipse(px, py, cov)],
        "texts": [{"pose": _pose(px, py), "billboard": True, "font_size": 14.0, "scale_invariant": True,
                   "color": _COLOR, "text": track_display_name(track)}],
    }


def scene_update(estimate: Any) -> dict[str, Any]:
    """The ``foxglove.SceneUpdate`` (JSON form) of one frame's estimate."""
    return {"deletions": [{"timestamp": _time(estimate.stamp_ns), "type": 1, "id": ""}],
            "entities": [_entity(t, estimate.stamp_ns) for t in estimate.tracks]}


class FoxgloveSceneSink:
    """Write one ``foxglove.SceneUpdate`` per frame with an estimate to ``options.path``:
    into the MCAP log open at that path in this process (the ``mcap`` sink), else into a
    file of its own."""

    def __init__(self, options: SinkOptions) -> None:
        self.options = options
        self.writer: McapLogWriter | None = None
        self.owned = False

    def open(self, metadata: Mapping[str, str] | None) -> None:
        shared = McapLogWriter.open_at(self.options.path)
        if shared is None:
            self.options.path.parent.mkdir(parents=True, exist_ok=True)
            shared, self.owned = McapLogWriter(self.options.path, dict(metadata) if metadata is not None else None), True
        self.writer = shared

    def write(self, record: SinkRecord) -> None:
        if self.writer is None:
            raise RuntimeError(f"FoxgloveSceneSink({self.options.path}) is not open")
        est = record.estimate
        if est is None:
            return
        data = json.dumps(scene_update(est), separators=(",", ":")).encode()
        self.writer.write_message(TOPIC_SCENE, ("foxglove.SceneUpdate", "jsonschema", SCENE_SCHEMA), "json", data,
                                  est.stamp_ns, est.frame)

    def close(self) -> None:
        if self.writer is not None and self.owned:
            self.writer.close()
        self.writer = None
