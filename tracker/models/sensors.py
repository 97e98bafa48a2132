r"""Sensor geometry as data: kind, pose, field of view and noise of each sensor.

A sensor is declared in a parameter file as a ``[sensors.NAME]`` table (:class:`SensorSpec`),
keyed by ``Frame.sensor``; a frame may also carry its own ``pose`` and ``R``.  Resolution
(:meth:`tracker.models.params.ModelParams.sensor`), later wins:

1. the parameter set's defaults: the origin, boresight :math:`+y`, ``range_max``,
   ``bearing_half_fov_deg``, the sigmas, ``p_detect``, ``clutter_rate`` (the default sensor);
2. the ``[sensors.NAME]`` table of the frame's sensor;
3. the frame's ``pose = (x, y, heading)`` and ``R``.

The result, :class:`Sensor`, is a small frozen (hashable) dataclass from which the parameter
set builds the measurement, clutter and detection models.  The heading is measured like
bearings, from :math:`+y` towards :math:`+x`, in radians here and in degrees in the TOML.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgspec

from bnptrack.tracker.config import ClutterRate, HalfFovDeg, NonNeg, Positive, Prob


class SensorSpec(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One ``[sensors.NAME]`` table of a parameter file (every field optional)."""

    kind: str | None = None
    """A kind of the registry (:data:`~tracker.models.measurement.KINDS`: ``bearing_range``,
    ``range``, ``xy``, ...): frames of this sensor must have this kind.  Checked when the
    parameter file loads (:class:`~tracker.models.params.ModelParams`)."""
    x: float = 0.0
    y: float = 0.0
    heading_deg: float = 0.0
    """Boresight direction, degrees from +y towards +x."""
    range_min: NonNeg = 0.0
    range_max: Positive | None = None
    half_fov_deg: HalfFovDeg | None = None
    sigma_bearing_deg: Positive | None = None
    sigma_range: Positive | None = None
    sigma_xy: Positive | None = None
    p_detect: Prob | None = None
    clutter_rate: ClutterRate | None = None


@dataclass(frozen=True)
class Sensor:
    """A resolved sensor (SI units, radians; noise sigmas already SNR-scaled).

    ``noise``: the frame's ``R`` as nested tuples (replaces the sigmas), or ``None``.
    """

    name: str
    kind: str
    x: float
    y: float
    heading: float
    range_min: float
    range_max: float
    half_fov: float
    sigma_bearing: float
    sigma_range: float
    sigma_xy: float
    p_detect: float
    clutter_rate: float
    noise: tuple[tuple[float, ...], ...] | None = None

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.heading)
