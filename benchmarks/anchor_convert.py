"""Pure helpers shared by the Stone Soup anchors of ``benchmarks/vs_stonesoup.py``.

Nothing here imports Stone Soup, so the conventions can be tested without the ``compare``
extra (``tests/benchmarks/test_vs_stonesoup.py``).

Conventions
-----------
* **Bearing.**  bnptrack measures the bearing from the +y axis towards +x,
  :math:`b = \\operatorname{atan2}(p_x, p_y)` (Vo et al. 2017; ``tracker/models/measurement.py``).
  Stone Soup's ``CartesianToBearingRange`` measures it from +x towards +y,
  :math:`\\phi = \\operatorname{atan2}(p_y, p_x)`.  Both describe the same point, so
  :math:`\\phi = \\pi/2 - b` (wrapped to :math:`[-\\pi, \\pi)`); the map is its own inverse.
  Measurements are converted once when fed to Stone Soup; the range is unchanged and the
  bearing noise std is the same (a sign flip does not change a variance).
* **State.**  Both use ``[px, vx, py, vy, omega]`` in the same order and units, so a state
  vector needs no permutation; a position is ``x[[0, 2]]``.
* **Labels.**  A GM-PHD component's ``tag`` and a JPDA track's ``id`` become the estimate's label.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

import msgspec
import numpy as np

from bnptrack.tracker.models.measurement import wrap_angle
from bnptrack.tracker.models.params import ModelParams

__all__ = [
    "JpdaSettings",
    "PhdSettings",
    "adaptive_birth_weights",
    "birth_gaussians",
    "clutter_intensity",
    "extract_phd",
    "from_stonesoup_bearing",
    "position",
    "to_stonesoup_bearing",
    "to_stonesoup_measurements",
]

Pos = Annotated[float, msgspec.Meta(gt=0.0)]
Prob = Annotated[float, msgspec.Meta(gt=0.0, le=1.0)]


class PhdSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """GM-PHD (UKF) anchor settings (tuned on seeds 101-110, docs/vs_stonesoup.md)."""

    birth_rate: Pos = 0.1
    """Expected new objects per scan, spread over the previous scan's measurements
    (Ristic et al. 2012 adaptive birth)."""
    birth_vel_std: Pos = 20.0
    """Velocity std (m/s) of a birth component (mean velocity 0)."""
    birth_turn_std_deg: Pos = 2.0
    """Turn-rate std (deg/s) of a birth component (mean 0)."""
    gate: Pos = 4.0
    """Mahalanobis gate (not squared) in measurement space."""
    prune: Pos = 1e-4
    """Components below this weight are pruned."""
    merge: Pos = 25.0
    """Squared Mahalanobis distance below which components merge."""
    max_components: Annotated[int, msgspec.Meta(ge=1)] = 100
    extract: Prob = 0.5
    """A component with weight above this is reported as an object."""


class JpdaSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """JPDA (UKF) anchor settings (tuned on seeds 101-110, docs/vs_stonesoup.md)."""

    ehm: bool = True
    """Use ``JPDAwithEHM`` (the same exact JPDA marginals by Efficient Hypothesis Management)
    instead of ``JPDA``, which enumerates every joint hypothesis over all tracks."""
    prob_gate: Prob = 0.99
    """PDA gate probability (the gate is the matching chi-square quantile)."""
    init_vel_std: Pos = 10.0
    """Velocity std (m/s) of a tentative track's prior (mean velocity 0)."""
    init_turn_std_deg: Pos = 2.0
    init_gate: Pos = 3.0
    """Mahalanobis gate (not squared) of the initiator's GNN association."""
    min_points: Annotated[int, msgspec.Meta(ge=1)] = 3
    """Updates a tentative track needs before it is confirmed."""
    init_delete_steps: Annotated[int, msgspec.Meta(ge=1)] = 1
    """A tentative track without an update for this many scans is dropped."""
    delete_steps: Annotated[int, msgspec.Meta(ge=1)] = 2
    """A confirmed track without an update for this many scans is deleted."""
    delete_covar_trace: Pos = 1e5
    """A confirmed track whose position covariance trace (m^2) exceeds this is deleted."""


def to_stonesoup_bearing(b: np.ndarray | float) -> np.ndarray:
    """bnptrack bearing (from +y towards +x) -> Stone Soup bearing (from +x towards +y)."""
    return wrap_angle(np.pi / 2 - np.asarray(b, dtype=float))


def from_stonesoup_bearing(phi: np.ndarray | float) -> np.ndarray:
    """Inverse of :func:`to_stonesoup_bearing` (the same map: it is an involution)."""
    return wrap_angle(np.pi / 2 - np.asarray(phi, dtype=float))


def to_stonesoup_measurements(z: np.ndarray) -> np.ndarray:
    """``(M, 2)`` bnptrack ``[bearing, range]`` rows -> Stone Soup ``[bearing, range]`` rows."""
    z = np.asarray(z, dtype=float).reshape(-1, 2)
    return np.column_stack([to_stonesoup_bearing(z[:, 0]), z[:, 1]])


def position(state_vector: np.ndarray) -> np.ndarray:
    """Position ``[px, py]`` of a ``[px, vx, py, vy, omega]`` state (shared order)."""
    x = np.asarray(state_vector, dtype=float).reshape(-1)
    return x[[0, 2]]


def clutter_intensity(params: ModelParams) -> float:
    """Clutter intensity per unit measurement volume (rad * m): rate / (field of view x range)."""
    half = np.deg2rad(params.bearing_half_fov_deg)
    return params.clutter_rate / (2 * half * params.range_max)


def birth_gaussians(
    z: np.ndarray, params: ModelParams, vel_std: float, turn_std_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Birth Gaussians ``(M, 5)``, ``(M, 5, 5)`` at bnptrack measurements ``z`` (M, 2).

    Position and its covariance from the first-order polar-to-Cartesian conversion
    (``BearingRange.to_cartesian``: :math:`P = J R J^T`); velocity 0 with std ``vel_std``;
    turn rate 0 with std ``turn_std_deg``.
    """
    pos, pcov = params.measurement("bearing_range").to_cartesian(np.asarray(z, dtype=float).reshape(-1, 2))
    M = pos.shape[0]
    mean = np.zeros((M, 5))
    mean[:, [0, 2]] = pos
    cov = np.zeros((M, 5, 5))
    ix = np.ix_([0, 2], [0, 2])
    for m in range(M):
        cov[m][ix] = pcov[m]
    cov[:, 1, 1] = cov[:, 3, 3] = vel_std**2
    cov[:, 4, 4] = np.deg2rad(turn_std_deg) ** 2
    return mean, cov


def adaptive_birth_weights(p_assoc: np.ndarray, birth_rate: float) -> np.ndarray:
    """Birth weight of each measurement from its probability of belonging to a known object.

    Ristic, Clark, Vo & Vo (2012), "Adaptive target birth intensity for PHD and CPHD
    filters", eq. (21): :math:`\\nu_b(z) = \\nu_B (1 - P_A(z)) / \\sum_{z'} (1 - P_A(z'))`,
    so the total expected number of births per scan is ``birth_rate``.
    """
    u = np.clip(1.0 - np.asarray(p_assoc, dtype=float), 0.0, 1.0)
    total = u.sum()
    if total <= 0.0:
        return np.zeros_like(u)
    return birth_rate * u / total


def extract_phd(
    components: Sequence[tuple[str, float, np.ndarray]], threshold: float
) -> list[tuple[str, np.ndarray]]:
    """Objects of a GM-PHD mixture: ``(tag, position)`` of each component with weight > threshold.

    ``components`` are ``(tag, weight, state_vector)``; one object per component (the
    weight is not rounded into copies, so a tag is reported at most once).
    """
    return [(str(tag), position(x)) for tag, w, x in components if w > threshold]
