"""``radar_msgs/msg/RadarScan`` -> ``bearing_range`` (a reader of :data:`sources.readers.READERS`).

Azimuth convention.  A ``RadarReturn``'s ``azimuth`` follows REP 103: radians in the radar's
frame (x forward, y left), **positive anticlockwise** from the radar's boresight (+x).
bnptrack's bearing is measured from the boresight **towards the sensor's right**, i.e.
positive clockwise seen from above (docs/formats.md, "Conventions and units").  So::

    bearing = -azimuth            (wrapped to [-pi, pi] when |azimuth| > pi)
    range   = range

``elevation``, ``doppler_velocity`` and ``amplitude`` are not used (a 2-D tracker; the
range is taken as the ground range).  The fields are ``float32`` in the message, so the
values are those ``float32`` numbers exactly.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bnptrack.sources.scan import Scan, finite_rows, stamp_ns_of

__all__ = ["RadarScanReader", "bearing_of_azimuth"]

_PI = float(np.pi)
_INF = float("inf")


def bearing_of_azimuth(azimuth: np.ndarray) -> np.ndarray:
    """bnptrack bearings of REP 103 azimuths (exact negation; wrapped only outside [-pi, pi])."""
    b = -np.asarray(azimuth, dtype=np.float64)
    if b.size and np.abs(b).max() > np.pi:
        out = np.abs(b) > np.pi
        b[out] = (b[out] + np.pi) % (2.0 * np.pi) - np.pi
    return b


def _checked(z: np.ndarray) -> np.ndarray:
    """Rows ``[bearing, range]`` without non-finite rows, bearings wrapped to [-pi, pi];
    :class:`ValueError` for a negative range."""
    negative = z[:, 1] < 0
    if negative.any():
        i = int(np.argmax(negative))
        raise ValueError(f"return {i} has a negative range {float(z[i, 1])!r}")
    z = finite_rows(z)
    z[:, 0] = bearing_of_azimuth(-z[:, 0])  # the columns hold -azimuth
    return z


class RadarScanReader:
    """Read a decoded ``RadarScan``: one row ``[bearing, range]`` per return."""

    kind = "bearing_range"

    def scan(self, msg: Any) -> Scan:
        z = np.array([(-r.azimuth, r.range) for r in msg.returns], dtype=np.float64).reshape(-1, 2)
        if z.shape[0]:
            lo, hi = z.min(axis=0), z.max(axis=0)
            # one test for the usual scan (NaN fails every comparison): else the slow path
            if not (lo[1] >= 0.0 and lo[0] >= -_PI and hi[0] <= _PI and hi[1] < _INF):
                z = _checked(z)
        header = msg.header
        return Scan(stamp_ns_of(header.stamp.sec, header.stamp.nanosec), header.frame_id, z)
