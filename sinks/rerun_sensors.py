"""The sensors of a recording, as the tracker sees them: each frame's resolved sensor and
measurement model, their colours, field-of-view outlines and the scene extent they cover.

A frame's sensor is resolved by :meth:`tracker.models.params.ModelParams.frame_sensor` (the
parameter set's defaults, then the ``[sensors.NAME]`` table, then the frame's own ``pose`` and
``R``) and its model by :meth:`~tracker.models.params.ModelParams.measurement`: the very calls
the trackers make, so a measurement drawn through the model's ``to_cartesian`` lies where the
tracker put it.  Does not import rerun.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from bnptrack.sinks.rerun_style import SENSOR_COLOR
from bnptrack.tracker.models.measurement import DEFAULT_KIND, measurement_kind
from bnptrack.tracker.models.sensors import Sensor
from bnptrack.tracker.types import Frame

__all__ = ["SensorBook", "fov_outline", "box_of", "grown", "scene_extent", "sensor_title", "SENSOR_COLOURS"]

#: Colours of the sensors (marker, name, field of view), in order of first appearance; none
#: is a track colour (:data:`sinks.rerun_style.PALETTE`).
SENSOR_COLOURS: tuple[tuple[int, int, int, int], ...] = (
    SENSOR_COLOR, (205, 150, 105, 255), (170, 170, 70, 255), (250, 235, 160, 255), (150, 110, 70, 255),
)

_OUTLINE_POINTS = 91


def sensor_title(sensor: Sensor) -> str:
    """The name a sensor is drawn with (``sensor`` when the frames give none)."""
    return sensor.name or "sensor"


def fov_outline(sensor: Sensor) -> np.ndarray:
    """``(K, 2)`` closed outline of the sensor's field of view in world coordinates: the wedge
    ``range_min .. range_max`` over ``heading +- half_fov`` (bearings from +y towards +x), or
    the ring at ``range_max`` for a kind whose detection ignores bearings (range-only)."""
    x, y = sensor.x, sensor.y
    if measurement_kind(sensor.kind).range_only:
        a = np.linspace(0.0, 2.0 * np.pi, _OUTLINE_POINTS)
        return np.stack([x + sensor.range_max * np.sin(a), y + sensor.range_max * np.cos(a)], -1)
    a = sensor.heading + np.linspace(-sensor.half_fov, sensor.half_fov, _OUTLINE_POINTS)
    outer = np.stack([x + sensor.range_max * np.sin(a), y + sensor.range_max * np.cos(a)], -1)
    if sensor.range_min > 0.0:
        inner = np.stack([x + sensor.range_min * np.sin(a), y + sensor.range_min * np.cos(a)], -1)[::-1]
        return np.concatenate([outer, inner, outer[:1]])
    apex = np.array([[x, y]])
    return np.concatenate([apex, outer, apex])


def box_of(points: np.ndarray, margin: float = 0.05) -> tuple[float, float, float, float]:
    """``(x0, x1, y0, y1)`` around ``(n, 2)`` points, widened by ``margin`` of the larger side."""
    lo, hi = np.nanmin(points, axis=0), np.nanmax(points, axis=0)
    m = margin * max(float(hi[0] - lo[0]), float(hi[1] - lo[1]), 1.0)
    return float(lo[0] - m), float(hi[0] + m), float(lo[1] - m), float(hi[1] + m)


def grown(bounds: tuple[float, float, float, float], points: np.ndarray,
          margin: float = 0.1) -> tuple[float, float, float, float] | None:
    """The box ``bounds`` grown to hold ``points`` (with ``margin`` of the new size), or ``None``
    when it holds them already."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not pts.shape[0]:
        return None
    x0, x1, y0, y1 = bounds
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if lo[0] >= x0 and hi[0] <= x1 and lo[1] >= y0 and hi[1] <= y1:
        return None
    corners = np.array([[x0, y0], [x1, y1], lo, hi])
    return box_of(corners, margin)


class SensorBook:
    """The sensors of one recording.

    :meth:`resolve` gives a frame's :class:`~tracker.models.sensors.Sensor` and measurement
    model (cached per name, kind, pose and ``R``); :meth:`to_draw` the sensors whose pose or
    field of view changed since they were last drawn; :meth:`colour` each sensor's colour.
    """

    def __init__(self, params: Any) -> None:
        if params is None:
            from bnptrack.tracker.models.params import load_params

            params = load_params()
        self.params = params
        self._cache: dict[tuple, tuple[Sensor, Any]] = {}
        self._drawn: dict[str, Sensor] = {}
        self._colours: dict[str, tuple[int, int, int, int]] = {}

    def declared(self) -> list[Sensor]:
        """The sensors of the parameter set's ``[sensors.NAME]`` tables, resolved as for a
        frame of their kind without a pose (none without tables)."""
        return [self.params.sensor(name, spec.kind or DEFAULT_KIND) for name, spec in self.params.sensors.items()]

    def default(self) -> Sensor:
        """The parameter set's default sensor (origin, boresight +y)."""
        return self.params.sensor("", DEFAULT_KIND)

    def resolve(self, frame: Frame) -> tuple[Sensor, Any]:
        """The frame's sensor and measurement model, as the tracker resolves them."""
        R = frame.R
        key = (frame.sensor, frame.kind, frame.pose, None if R is None else np.asarray(R, dtype=float).tobytes())
        hit = self._cache.get(key)
        if hit is None:
            sensor = self.params.frame_sensor(frame)
            hit = self._cache[key] = (sensor, self.params.measurement(frame.kind, sensor))
        return hit

    def to_draw(self, sensors: Iterable[Sensor]) -> list[Sensor]:
        """Those of ``sensors`` not drawn yet at their present pose and field of view (and
        remember them as drawn)."""
        out = []
        for s in sensors:
            title = sensor_title(s)
            last = self._drawn.get(title)
            if last is None or _geometry(last) != _geometry(s):
                self._drawn[title] = s
                out.append(s)
        return out

    def colour(self, sensor: Sensor) -> tuple[int, int, int, int]:
        """The sensor's colour (by name, in order of first appearance)."""
        title = sensor_title(sensor)
        c = self._colours.get(title)
        if c is None:
            c = self._colours[title] = SENSOR_COLOURS[len(self._colours) % len(SENSOR_COLOURS)]
        return c

    @property
    def drawn(self) -> list[Sensor]:
        """The sensors drawn so far, their latest pose each."""
        return list(self._drawn.values())


def _geometry(s: Sensor) -> tuple[Any, ...]:
    return (s.x, s.y, s.heading, s.range_min, s.range_max, s.half_fov, s.kind)


def scene_extent(sensors: Iterable[Sensor]) -> tuple[float, float, float, float]:
    """The box around the sensors' fields of view (5 % margin)."""
    pts = np.concatenate([fov_outline(s) for s in sensors])
    return box_of(pts)
