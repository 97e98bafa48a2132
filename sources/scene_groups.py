"""Groups of the generated scenes (:mod:`sources.scene_families`): group sizes (a Pitman-Yor
partition or drawn sizes), formations, passing pairs, and the shared anchor of ``groups-py``.
``fam`` is a :class:`~sources.scene_families.SceneFamily`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bnptrack.sources.scene_geometry import (
    _MAX_TRIES,
    CROSSING_MIN_SIDE,
    _birth_scan,
    _crossing_side,
    _inside_run,
    _Object,
    _position,
    _propagate,
    _state,
    _velocity,
)
from bnptrack.tracker.bnp.urn import sample_crp_partition
from bnptrack.tracker.config import ConfigError


def pitman_yor_sizes(rng: np.random.Generator, n: int, alpha: float, d: float) -> list[int]:
    """Table sizes, in order of opening, of ``n`` customers seated by the Pitman-Yor Chinese
    restaurant: table ``j`` with weight ``n_j - d``, a new one with ``alpha + d K`` (the urn
    of :func:`tracker.bnp.urn.sample_crp_partition`, whose labels number the tables in order
    of opening)."""
    return np.bincount(sample_crp_partition(rng, n, alpha, d)).tolist() if n else []


def _group_sizes(rng: np.random.Generator, fam) -> list[int]:
    if fam.group_partition == "pitman-yor" and not fam.group_sizes:
        n = int(rng.integers(fam.py_objects, fam.py_objects_max + 1)) if fam.py_objects_max else fam.py_objects
        for _ in range(_MAX_TRIES):
            sizes = pitman_yor_sizes(rng, n, fam.py_alpha, fam.py_discount)
            if max(sizes) <= fam.group_size_max and len(sizes) >= 2 * fam.passing_pairs:
                return sizes
        raise ConfigError("scene: no Pitman-Yor partition within group_size_max; relax the scene.* settings")
    if fam.group_sizes:
        return list(fam.group_sizes)
    sizes = np.arange(fam.group_size_min, fam.group_size_max + 1)
    p = sizes.astype(float) ** -fam.group_size_power
    return [int(x) for x in rng.choice(sizes, size=fam.n_groups, p=p / p.sum())]


def _offsets(rng: np.random.Generator, size: int, radius: float) -> np.ndarray:
    """``(size, 2)`` member offsets uniform in a disc (the first member at the centre)."""
    r = radius * np.sqrt(rng.uniform(size=size))
    phi = rng.uniform(-np.pi, np.pi, size=size)
    out = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    out[0] = 0.0
    return out


@dataclass(frozen=True)
class _Anchor:
    """The scene's shared point and velocity (``group_region`` / ``group_velocity_std``)."""

    pos: np.ndarray  # at scan 1
    vel: np.ndarray  # [vx, vy, omega]


def _anchor(rng: np.random.Generator, fam) -> _Anchor:
    """A point and a velocity (a free object's, turn rate 0) that keep the point in the box for all K scans."""
    for _ in range(_MAX_TRIES):
        pos = _position(rng, fam)
        vel = _velocity(rng, fam, rng.uniform(-np.pi, np.pi))
        vel[2] = 0.0
        if _inside_run(_propagate(_state(pos, vel), fam.K - 1, 1.0), fam) == fam.K:
            return _Anchor(pos, vel)
    raise ConfigError("scene: could not place the group anchor inside the field; relax the scene.* settings")


def _group_motion(rng: np.random.Generator, fam, b: int, anchor: _Anchor | None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A group's ``(velocity, centre at scan b)``: free (anchor None, the ``groups`` draws) or about the anchor."""
    if anchor is None:
        vel = _velocity(rng, fam, rng.uniform(-np.pi, np.pi))
        return vel, _position(rng, fam)
    vel = _velocity(rng, fam, rng.uniform(-np.pi, np.pi))
    if fam.group_velocity_std > 0:
        vel = anchor.vel + np.append(rng.normal(0.0, fam.group_velocity_std, 2), 0.0)
    if fam.group_region <= 0:
        return vel, _position(rng, fam)
    centre = anchor.pos + (b - 1) * anchor.vel[:2] + _offsets(rng, 2, fam.group_region)[1]
    return vel, centre


def _group(rng: np.random.Generator, fam, size: int, anchor: _Anchor | None = None) -> list[_Object]:
    """A formation born in the box: members share velocity and turn rate, offset positions."""
    radius = fam.member_spacing * np.sqrt(size) if fam.member_spacing > 0 else fam.group_spacing
    for _ in range(_MAX_TRIES):
        b = _birth_scan(rng, fam, np.zeros(0, dtype=int))
        life = int(rng.integers(fam.life_min, fam.life_max + 1))
        d = min(b + life - 1, fam.K)
        vel, centre = _group_motion(rng, fam, b, anchor)
        objs = []
        for off in _offsets(rng, size, radius):
            x = _state(centre + off, vel)
            kept = _inside_run(_propagate(x, d - b, 1.0), fam)
            if kept < fam.life_min:
                break
            objs.append(_Object(x, b, b + kept - 1))
        if len(objs) == size:
            return objs
    raise ConfigError("scene: could not place a group inside the field; relax the scene.* settings")


def _passing_groups(rng: np.random.Generator, fam, sizes: tuple[int, int]) -> list[list[_Object]]:
    """Two formations whose centres meet at a random scan, headings 30-150 deg apart."""
    m = CROSSING_MIN_SIDE
    for _ in range(_MAX_TRIES):
        c = int(rng.integers(m + 1, fam.K - m + 1))
        p = _position(rng, fam)
        h_a = rng.uniform(-np.pi, np.pi)
        h_b = h_a + rng.choice([-1.0, 1.0]) * np.deg2rad(rng.uniform(30.0, 150.0))
        groups = []
        for size, heading in zip(sizes, (h_a, h_b)):
            vel = _velocity(rng, fam, heading)
            before = int(rng.integers(m, 40))
            after = int(rng.integers(m, 40))
            objs = []
            for off in _offsets(rng, size, fam.group_spacing):
                x_c = _state(p + off, vel)
                back, n_back = _crossing_side(x_c, min(before, c - 1), -1.0, fam)
                _, n_fwd = _crossing_side(x_c, min(after, fam.K - c), 1.0, fam)
                if n_back < m or n_fwd < m:
                    break
                objs.append(_Object(back[n_back], c - n_back, c + n_fwd))
            if len(objs) < size:
                break
            groups.append(objs)
        if len(groups) == 2:
            return groups
    raise ConfigError("scene: could not place passing groups inside the field; relax the scene.* settings")


def _all_groups(rng: np.random.Generator, fam) -> list[list[_Object]]:
    sizes = _group_sizes(rng, fam)
    out: list[list[_Object]] = []
    for i in range(fam.passing_pairs):
        out += _passing_groups(rng, fam, (sizes[2 * i], sizes[2 * i + 1]))
    shared = fam.group_region > 0 or fam.group_velocity_std > 0
    anchor = _anchor(rng, fam) if shared else None
    out += [_group(rng, fam, s, anchor) for s in sizes[2 * fam.passing_pairs:]]
    return out
