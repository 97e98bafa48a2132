r"""Seeded generated scenario families: ``random``, the held-out ``random-cv`` and the ``groups`` families.

A family is a pure function ``(family name, scene seed, family parameters) -> Scenario``
(:func:`generate_scene`).  The parameters are a :class:`SceneFamily` (``--set scene.KEY=VALUE``
on the command line, see :func:`scene_config`); the scene's random stream is
:func:`scene_rng`, ``SeedSequence(seed, spawn_key=(0, crc32(name)))``, disjoint from the
measurement streams of :func:`sources.synthetic.measurement_frame_rng` (``spawn_key=(k,)``), so one seed
drives both the scene and its measurements without the two sharing draws.

The field (decided here): the ``vo2017`` sensor (bearing-range at the origin, bearing in
(-90, 90) deg from +y, range 0-2000 m).  Every object stays *inside* the box
``range_min <= r <= range_max`` (default 150-1900 m) and ``|bearing| <= bearing_max_deg``
(default 85 deg) at every scan it is present, so it is always observable (``P_D`` applies).
An object whose trajectory would leave the box is **truncated**: its life ends at the last
scan inside (crossing-pair objects: also its life begins at the first scan inside); a draw
that keeps fewer than ``life_min`` scans (crossing objects: fewer than 7 scans on either
side of the crossing) is redrawn.

``random`` (defaults of :class:`SceneFamily`)
    ``N`` objects, uniform in 20-30 (``n_objects`` fixes it).  Each free object: birth scan
    uniform in ``1..K - life_min + 1``, planned lifetime uniform in 15-100 scans (clipped to
    ``K = 100``), position uniform over the area of the box, heading uniform, speed uniform
    in 5-40 m/s, turn rate 0 with probability ``straight_fraction`` (0.25), else uniform in
    +-3 deg/s (coordinated-turn model, noiseless).  Plus ``crossing_pairs`` (3) pairs: a
    crossing scan ``c`` uniform in ``8..K-7``, a crossing point in the box, the two objects
    placed ``sep`` apart around it (``sep`` uniform in ``0..crossing_sep``, default 10 m, so
    within 20 m) with headings 30-150 deg apart, and each propagated backwards (the
    coordinated turn with period ``-T`` is the exact inverse) and forwards from ``c``.  The
    pairs are recorded in :attr:`Scenario.crossings` as ``(id_a, id_b, c)``.  No birth
    regions: :meth:`Scenario.adapt_params` sets ``birth = []``.
``random-cv`` (held-out family, different defaults)
    8-15 straight-line constant-velocity objects (``turn_max_deg = 0``), speeds 2-25 m/s,
    lifetimes 20-100, births in ``bursts = 3`` bursts: each object is born at a burst scan
    (uniform in ``1..K - life_min + 1``) plus 0-2 scans; no crossing pairs; no birth regions.

``groups`` (the two-level model's scene, ``docs/trackers.md``)
    3-6 free objects as in ``random`` (speeds 5-30 m/s, |turn| <= 2 deg/s, lifetimes 20-100,
    no crossing pairs) plus ``n_groups`` (5) groups of ``group_size_min..group_size_max``
    (2-5) objects (``group_sizes = [..]`` fixes them): one birth scan, lifetime, velocity and
    turn rate per group, members at offsets uniform in a disc of radius ``group_spacing``
    (40 m; the first at the centre), each truncated when it leaves the box (the group is
    redrawn if a member keeps fewer than ``life_min`` scans).  ``passing_pairs`` (1) pairs of
    groups have centres that meet at a scan in ``8..K-7``, headings 30-150 deg apart, 7-39
    scans on each side.  The groups (2+ members) are recorded in :attr:`Scenario.groups`.
``groups-pl``
    As ``groups`` but the partition of the group objects is a **Pitman-Yor partition**
    (``group_partition = "pitman-yor"``): ``py_objects`` (24) objects seated by the
    Pitman-Yor Chinese restaurant with discount ``py_discount`` (0.6) and concentration
    ``py_alpha`` (1), redrawn until no group exceeds ``group_size_max`` (10): many singletons
    (about 9 of about 13 groups) and a few big groups, the power-law sizes DPY-STP models
    (``Pr(s) ~ s^-(1+d)``); plus one free object.  ``group_partition = "sizes"`` is the first
    version (8 groups with i.i.d. sizes ``Pr(s) ~ s^-group_size_power`` on 1-10, not a PY
    partition: its EPPF barely tells ``d`` from 0, ``docs/trackers.md``).
``groups-py`` (where a discount can matter)
    A Pitman-Yor partition (``py_alpha`` 1, ``py_discount`` 0.6; 0 and 0.3 by ``scene.py_discount``)
    of ``py_objects..py_objects_max`` (100-300) objects, no size cap, no passing pairs: every
    group's centre is uniform in a disc of ``group_region`` (400 m) about one anchor point that
    moves with the scene velocity (speed 2-8 m/s, straight), its velocity that velocity plus
    N(0, ``group_velocity_std``^2 I) (5 m/s), its members within ``member_spacing * sqrt(size)``
    (15 m) of its centre; plus one free object; ``K`` = 50 scans.  Groups overlap in space and
    velocity, so a membership is ambiguous from one frame.

Objects are named ``T1..TN`` in order of birth scan (ties: generation order).  The tables
are defined for ``T = 1`` s (the crossing distance holds for that period).
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence

import msgspec
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
    in_field,
)
from bnptrack.sources.scene_groups import _all_groups, pitman_yor_sizes
from bnptrack.tracker.config import CLI_NAMES, ArgNames, ConfigError, apply_overrides
from bnptrack.tracker.messages import MAX_OBJECTS
from bnptrack.tracker.models.motion import CoordinatedTurn

__all__ = [
    "SceneFamily",
    "FAMILIES",
    "family_names",
    "scene_rng",
    "scene_config",
    "generate_scene",
    "family_template",
    "in_field",
    "CROSSING_MIN_SIDE",
    "pitman_yor_sizes",
]

#: ``groups-py``'s scene settings (chosen on scene seeds 101-110, which no reported figure uses).
GROUPS_PY_REGION = 400.0
GROUPS_PY_VEL_STD = 5.0
GROUPS_PY_SPACING = 15.0


class SceneFamily(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Parameters of a generated family (``--set scene.KEY=VALUE``).  Angles in degrees."""

    n_objects: int = 0
    """Number of objects; 0 = uniform in ``n_min..n_max``."""
    n_min: int = 20
    n_max: int = 30
    crossing_pairs: int = 3
    crossing_sep: float = 10.0
    """Largest separation (m) of a crossing pair at its crossing scan (at most 20)."""
    life_min: int = 15
    life_max: int = 100
    speed_min: float = 5.0
    speed_max: float = 40.0
    turn_max_deg: float = 3.0
    """Largest |turn rate| in deg/s (0 = straight lines only)."""
    straight_fraction: float = 0.25
    bursts: int = 0
    """0: birth scans uniform; else births at this many burst scans (+0..burst_spread)."""
    burst_spread: int = 2
    range_min: float = 150.0
    range_max: float = 1900.0
    bearing_max_deg: float = 85.0
    K: int = 100
    n_groups: int = 0
    """Motion groups (``groups`` families): 0 = none."""
    group_sizes: tuple[int, ...] = ()
    """Explicit group sizes (overrides ``n_groups`` and the size draw)."""
    group_size_min: int = 2
    group_size_max: int = 5
    group_size_power: float = 0.0
    """0: sizes uniform in min..max; > 0: Pr(size s) proportional to s^-power (power law)."""
    group_spacing: float = 40.0
    """Members sit at offsets uniform in a disc of this radius (m) about the group's centre."""
    passing_pairs: int = 0
    """Pairs of groups whose centres meet (heading 30-150 deg apart) at a random scan."""
    group_partition: str = "sizes"
    """"sizes": ``n_groups`` sizes drawn as above; "pitman-yor": the group sizes are a
    Pitman-Yor partition of ``py_objects`` objects (``py_alpha``, ``py_discount``), sizes <=
    ``group_size_max`` (redrawn), singletons included (size-1 groups)."""
    py_objects: int = 24
    py_objects_max: int = 0
    """0: the partition has exactly ``py_objects`` objects; else uniform in ``py_objects..py_objects_max``."""
    py_alpha: float = 1.0
    py_discount: float = 0.6
    group_region: float = 0.0
    """0: a group's centre anywhere in the box; > 0: uniform in a disc of this radius (m) about
    the scene's anchor, one point that moves with the scene velocity (groups overlap in space)."""
    group_velocity_std: float = 0.0
    """0: each group's velocity drawn as a free object's; > 0: the scene velocity (drawn once, as
    a free object's) plus N(0, std^2 I) per group, turn rate 0 (groups overlap in velocity)."""
    member_spacing: float = 0.0
    """0: members within ``group_spacing`` of the centre; > 0: within ``member_spacing * sqrt(size)``
    (the same density for every size)."""

    def __post_init__(self) -> None:
        checks = [
            (0 <= self.n_objects <= MAX_OBJECTS, f"n_objects must be in [0, {MAX_OBJECTS}] (a /truth message "
             f"holds at most {MAX_OBJECTS} objects)"),
            (1 <= self.n_min <= self.n_max, "need 1 <= n_min <= n_max"),
            (self.crossing_pairs >= 0, "crossing_pairs must be >= 0"),
            (0.0 <= self.crossing_sep <= 20.0, "crossing_sep must be in [0, 20] m"),
            (self.K >= 2 * CROSSING_MIN_SIDE + 1, f"K must be >= {2 * CROSSING_MIN_SIDE + 1}"),
            (1 <= self.life_min <= self.life_max, "need 1 <= life_min <= life_max"),
            (self.life_min <= self.K, "life_min must be <= K"),
            (0.0 < self.speed_min <= self.speed_max, "need 0 < speed_min <= speed_max"),
            (0.0 <= self.turn_max_deg <= 30.0, "turn_max_deg must be in [0, 30]"),
            (0.0 <= self.straight_fraction <= 1.0, "straight_fraction must be in [0, 1]"),
            (self.bursts >= 0 and self.burst_spread >= 0, "bursts, burst_spread must be >= 0"),
            (0.0 <= self.range_min < self.range_max <= 2000.0,
             "need 0 <= range_min < range_max <= 2000"),
            (0.0 < self.bearing_max_deg < 90.0, "bearing_max_deg must be in (0, 90)"),
        ]
        checks += [
            (self.n_groups >= 0 and all(g >= 1 for g in self.group_sizes), "group sizes must be >= 1"),
            (1 <= self.group_size_min <= self.group_size_max, "need 1 <= group_size_min <= group_size_max"),
            (self.group_size_power >= 0.0, "group_size_power must be >= 0"),
            (0.0 <= self.group_spacing <= 200.0, "group_spacing must be in [0, 200] m"),
            (self.group_partition == "pitman-yor"
             or 0 <= 2 * self.passing_pairs <= max(self.n_groups, len(self.group_sizes)),
             "2 * passing_pairs must not exceed the number of groups"),
            (self.group_partition in ("sizes", "pitman-yor"), 'group_partition must be "sizes" or "pitman-yor"'),
            (self.py_objects >= 2 * self.passing_pairs and 0.0 <= self.py_discount < 1.0
             and self.py_alpha > -self.py_discount, "need py_objects >= 2 passing_pairs, 0 <= py_discount < 1, "
             "py_alpha > -py_discount"),
            (self.py_objects_max == 0 or self.py_objects_max >= self.py_objects, "need py_objects_max >= py_objects (or 0)"),
            (0.0 <= self.group_region <= 1000.0 and 0.0 <= self.group_velocity_std <= 20.0
             and 0.0 <= self.member_spacing <= 50.0,
             "need group_region in [0, 1000] m, group_velocity_std in [0, 20] m/s, member_spacing in [0, 50] m"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ValueError(msg)
        if 2 * self.crossing_pairs > (self.n_objects or self.n_min) and self.crossing_pairs:
            raise ValueError("2 * crossing_pairs must not exceed the number of objects")


#: The registered families and their default parameters.
FAMILIES: dict[str, SceneFamily] = {
    "random": SceneFamily(),
    "random-cv": SceneFamily(
        n_min=8, n_max=15, crossing_pairs=0, life_min=20, speed_min=2.0, speed_max=25.0,
        turn_max_deg=0.0, straight_fraction=1.0, bursts=3,
    ),
    "groups": SceneFamily(
        n_min=3, n_max=6, crossing_pairs=0, n_groups=5, passing_pairs=1, life_min=20, speed_min=5.0,
        speed_max=30.0, turn_max_deg=2.0,
    ),
    "groups-pl": SceneFamily(
        n_min=1, n_max=1, crossing_pairs=0, n_groups=8, passing_pairs=1, group_size_min=1,
        group_size_max=10, group_size_power=1.5, life_min=20, speed_min=5.0, speed_max=30.0,
        turn_max_deg=2.0, group_partition="pitman-yor",
    ),
    "groups-py": SceneFamily(
        n_min=1, n_max=1, crossing_pairs=0, life_min=20, speed_min=2.0, speed_max=8.0, turn_max_deg=0.0,
        straight_fraction=1.0, group_size_min=1, group_size_max=300, group_partition="pitman-yor",
        py_objects=100, py_objects_max=300, group_region=GROUPS_PY_REGION, group_velocity_std=GROUPS_PY_VEL_STD,
        member_spacing=GROUPS_PY_SPACING, K=50,
    ),
}

_DESCRIPTIONS = {
    "random": "Generated: 20-30 coordinated-turn objects born anywhere at random scans, "
              "5-40 m/s, |turn| <= 3 deg/s, 3 crossing pairs (within 20 m); no birth regions",
    "random-cv": "Generated (held-out): 8-15 straight constant-velocity objects, 2-25 m/s, "
                 "births in 3 bursts; no birth regions",
    "groups": "Generated: 5 convoys of 2-5 objects sharing velocity and turn rate (offsets within "
              "40 m), born anywhere, one pair of groups passing each other, plus 3-6 independent objects",
    "groups-pl": "Generated: groups that are a Pitman-Yor partition (d 0.6, alpha 1) of 24 objects, sizes <= 10 "
                 "(many singletons, a few big groups), one passing pair, "
                 "plus 1 independent object",
    "groups-py": "Generated: groups that are a Pitman-Yor partition (d 0.6, alpha 1) of 100-300 objects, "
                 "overlapping in space and velocity (ambiguous memberships), plus 1 independent object",
}


def family_names() -> tuple[str, ...]:
    return tuple(FAMILIES)


def scene_rng(name: str, seed: int) -> np.random.Generator:
    """The scene's random stream: ``SeedSequence(seed, spawn_key=(0, crc32(name)))``."""
    key = (0, zlib.crc32(name.encode()))
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=key))


def scene_config(name: str, overrides: Sequence[str] = (), names: ArgNames = CLI_NAMES) -> SceneFamily:
    """The family's parameters with ``KEY=VALUE`` overrides (keys without ``scene.``).

    Raises :class:`ConfigError` naming a bad key or value (as ``names`` say).
    """
    try:
        base = FAMILIES[name]
    except KeyError:
        raise ConfigError(
            f"scenario {name!r} is not generated; scene.* settings apply only to "
            f"{', '.join(FAMILIES)}"
        ) from None
    wrapped = apply_overrides(_Wrapped(base), [f"scene.{o.strip()}" for o in overrides], names=names)
    return wrapped.scene


class _Wrapped(msgspec.Struct, frozen=True):
    """``scene.KEY`` overrides resolve against this, so errors name the full key."""

    scene: SceneFamily


# ----------------------------------------------------------------------------------
# Objects
# ----------------------------------------------------------------------------------
def _free_object(rng: np.random.Generator, fam: SceneFamily, bursts: np.ndarray) -> _Object:
    """One object born in the box, truncated when it leaves (redrawn if too short)."""
    for _ in range(_MAX_TRIES):
        b = _birth_scan(rng, fam, bursts)
        life = int(rng.integers(fam.life_min, fam.life_max + 1))
        d = min(b + life - 1, fam.K)
        x = _state(_position(rng, fam), _velocity(rng, fam, rng.uniform(-np.pi, np.pi)))
        kept = _inside_run(_propagate(x, d - b, 1.0), fam)
        if kept >= fam.life_min:
            return _Object(x, b, b + kept - 1)
    raise ConfigError("scene: could not place an object inside the field; relax the scene.* settings")


def _crossing_pair(rng: np.random.Generator, fam: SceneFamily) -> tuple[_Object, _Object, int]:
    """Two objects within ``crossing_sep`` m of each other at a random crossing scan."""
    m = CROSSING_MIN_SIDE
    for _ in range(_MAX_TRIES):
        c = int(rng.integers(m + 1, fam.K - m + 1))
        p = _position(rng, fam)
        sep = rng.uniform(0.0, fam.crossing_sep)
        phi = rng.uniform(-np.pi, np.pi)
        off = 0.5 * sep * np.array([np.cos(phi), np.sin(phi)])
        h_a = rng.uniform(-np.pi, np.pi)
        h_b = h_a + rng.choice([-1.0, 1.0]) * np.deg2rad(rng.uniform(30.0, 150.0))
        objs = []
        for pos, heading in ((p + off, h_a), (p - off, h_b)):
            x_c = _state(pos, _velocity(rng, fam, heading))
            life = int(rng.integers(max(fam.life_min, 2 * m + 1), max(fam.life_max, 2 * m + 1) + 1))
            before = int(rng.integers(m, life - m))  # scans before c, then after = life-1-before
            back, n_back = _crossing_side(x_c, min(before, c - 1), -1.0, fam)
            _, n_fwd = _crossing_side(x_c, min(life - 1 - before, fam.K - c), 1.0, fam)
            if n_back < m or n_fwd < m:
                break
            objs.append(_Object(back[n_back], c - n_back, c + n_fwd))
        if len(objs) == 2:
            return objs[0], objs[1], c
    raise ConfigError("scene: could not place a crossing pair inside the field; relax the scene.* settings")


def family_template(name: str):
    """A target-less :class:`Scenario` of family ``name``: what every scene of the family
    shares (sensor kind, ``K``, no birth regions), for :meth:`Scenario.adapt_params` without
    drawing a scene."""
    from bnptrack.sources.scene import Scenario

    scene_config(name)  # validates the name
    return Scenario(name, _DESCRIPTIONS[name], K=FAMILIES[name].K, birth=())


def generate_scene(name: str, seed: int, overrides: Sequence[str] = (), names: ArgNames = CLI_NAMES):
    """The scene of family ``name`` for ``seed`` and ``scene.*`` ``overrides`` (a :class:`Scenario`)."""
    from bnptrack.sources.scene import Scenario, TargetSpec

    fam = scene_config(name, overrides, names)
    rng = scene_rng(name, seed)
    n = fam.n_objects or int(rng.integers(fam.n_min, fam.n_max + 1))
    bursts = np.sort(rng.integers(1, fam.K - fam.life_min + 2, size=fam.bursts))
    objs: list[_Object] = []
    pairs: list[tuple[int, int, int]] = []
    for _ in range(fam.crossing_pairs):
        a, b, c = _crossing_pair(rng, fam)
        pairs.append((len(objs), len(objs) + 1, c))
        objs += [a, b]
    objs += [_free_object(rng, fam, bursts) for _ in range(n - len(objs))]
    member_of: list[list[int]] = []
    for g in _all_groups(rng, fam) if fam.n_groups or fam.group_sizes or fam.group_partition == "pitman-yor" else []:
        member_of.append(list(range(len(objs), len(objs) + len(g))))
        objs += g
    n = len(objs)
    order = sorted(range(n), key=lambda j: (objs[j].birth, j))
    ident = {j: f"T{rank + 1}" for rank, j in enumerate(order)}
    inv = CoordinatedTurn(T=-1.0)
    targets = tuple(
        TargetSpec(ident[j], tuple(inv.f(objs[j].x_birth)), objs[j].birth, objs[j].death)
        for j in order
    )
    crossings = tuple((ident[a], ident[b], c) for a, b, c in pairs)
    return Scenario(
        name, _DESCRIPTIONS[name], K=fam.K, targets=targets, birth=(), crossings=crossings,
        groups=tuple(tuple(ident[j] for j in g) for g in member_of if len(g) > 1), seed=int(seed), scene=tuple(overrides),
    )
