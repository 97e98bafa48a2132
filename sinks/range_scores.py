r"""What one static range sensor can observe, scored (the ``snr`` experiment).

A range-only sensor at :math:`s` measures :math:`r = \lVert p - s \rVert`.  For straight-line
motion :math:`p(t) = p_0 + v t` (sensor at the origin),
:math:`r(t)^2 = \lVert p_0\rVert^2 + 2\,p_0 \cdot v\,t + \lVert v\rVert^2 t^2`: the track
fixes only :math:`\lVert p_0\rVert`, :math:`p_0 \cdot v` and :math:`\lVert v\rVert`, so the
position is known only up to a rotation about the sensor.  Position OSPA then scores the
tracker on what it cannot know; the observable measures are the cardinality and a 1-D OSPA on
range (:func:`range_ospa`).  :func:`within_gate` counts the true objects that have an estimate
within ``gate`` metres in position (one-to-one, optimal assignment): the fraction of
object-frames tracked in the plane.

Both return ``(numerator, denominator)`` per frame; a run's value is the ratio of the sums (the
experiments' extra metrics, ``pipeline.experiments.FrameMetric``).
"""

from __future__ import annotations

import numpy as np

from bnptrack.sinks.metric_checks import optimal_assignment
from bnptrack.sinks.metrics import OSPA_C, OSPA_P, ospa

__all__ = ["ranges", "range_ospa", "within_gate"]


def ranges(positions: np.ndarray, sensor: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """``(n, 1)`` ranges of ``(n, 2)`` positions from ``sensor``."""
    P = np.asarray(positions, dtype=float).reshape(-1, 2)
    return np.linalg.norm(P - np.asarray(sensor, dtype=float), axis=1)[:, None]


def range_ospa(truth: np.ndarray, est: np.ndarray, c: float = OSPA_C, p: float = OSPA_P) -> tuple[float, float]:
    """1-D OSPA (cut-off ``c``, order ``p``) between the true and estimated ranges; ``(value, 1)``."""
    return ospa(ranges(truth), ranges(est), c=c, p=p).total, 1.0


def within_gate(truth: np.ndarray, est: np.ndarray, gate: float = 100.0) -> tuple[float, float]:
    """``(objects with an estimate within gate m, objects)`` under the optimal one-to-one assignment."""
    T = np.asarray(truth, dtype=float).reshape(-1, 2)
    E = np.asarray(est, dtype=float).reshape(-1, 2)
    if T.shape[0] == 0 or E.shape[0] == 0:
        return 0.0, float(T.shape[0])
    D = np.linalg.norm(T[:, None] - E[None], axis=2)
    rows, cols = optimal_assignment(np.minimum(D, gate))
    return float(np.sum(D[rows, cols] < gate)), float(T.shape[0])
