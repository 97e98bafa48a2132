"""Geometry of the generated scenes (:mod:`sources.scene_families`): the field's box, noiseless
propagation, random positions and velocities, objects and their birth scans.  ``fam`` is a
:class:`~sources.scene_families.SceneFamily`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bnptrack.tracker.models.motion import CoordinatedTurn

#: Scans a crossing-pair object is present on each side of its crossing scan (at least).
CROSSING_MIN_SIDE = 7
_MAX_TRIES = 2000


# ----------------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------------
def in_field(states: np.ndarray, fam) -> np.ndarray:
    """``(...)`` bool: position of ``(..., 5)`` states inside the family's box."""
    px, py = states[..., 0], states[..., 2]
    r = np.hypot(px, py)
    bearing = np.arctan2(px, py)
    return ((r >= fam.range_min) & (r <= fam.range_max)
            & (np.abs(bearing) <= np.deg2rad(fam.bearing_max_deg)))


def _propagate(x: np.ndarray, steps: int, T: float) -> np.ndarray:
    """``(steps + 1, 5)``: ``x`` and ``steps`` noiseless transitions with period ``T``."""
    return CoordinatedTurn(T=T).path(x, steps)


def _inside_run(traj: np.ndarray, fam) -> int:
    """Length of the leading run of ``traj`` inside the box."""
    inside = in_field(traj, fam)
    return int(inside.size if inside.all() else np.argmin(inside))


def _position(rng: np.random.Generator, fam) -> np.ndarray:
    """A position uniform over the area of the box."""
    r = np.sqrt(rng.uniform(fam.range_min**2, fam.range_max**2))
    b = np.deg2rad(rng.uniform(-fam.bearing_max_deg, fam.bearing_max_deg))
    return np.array([r * np.sin(b), r * np.cos(b)])


def _velocity(rng: np.random.Generator, fam, heading: float) -> np.ndarray:
    """``[vx, vy, omega]``: random speed along ``heading`` (rad from +x), random turn rate."""
    speed = rng.uniform(fam.speed_min, fam.speed_max)
    straight = fam.turn_max_deg == 0.0 or rng.uniform() < fam.straight_fraction
    omega = 0.0 if straight else np.deg2rad(rng.uniform(-fam.turn_max_deg, fam.turn_max_deg))
    return np.array([speed * np.cos(heading), speed * np.sin(heading), omega])


def _state(pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
    return np.array([pos[0], vel[0], pos[1], vel[1], vel[2]])


# ----------------------------------------------------------------------------------
# Objects
# ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Object:
    x_birth: np.ndarray  # state at the birth scan
    birth: int
    death: int


def _birth_scan(rng: np.random.Generator, fam, bursts: np.ndarray) -> int:
    last = fam.K - fam.life_min + 1
    if bursts.size:
        b = int(rng.choice(bursts)) + int(rng.integers(0, fam.burst_spread + 1))
        return min(b, last)
    return int(rng.integers(1, last + 1))


def _crossing_side(x_c: np.ndarray, steps: int, T: float, fam) -> tuple[np.ndarray, int]:
    """Trajectory from the crossing state over ``steps`` scans (``T = -1``: backwards),
    truncated at leaving the box; returns it and the scans kept beyond ``c``."""
    traj = _propagate(x_c, steps, T)
    kept = _inside_run(traj, fam)
    return traj, kept - 1
