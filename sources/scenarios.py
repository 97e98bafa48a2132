r"""Ground-truth scenarios of the simulation study (``/work/shared/spec/scenarios.md``).

A :class:`Scenario` is a frozen description of noiseless target trajectories: each
:class:`TargetSpec` holds the state ``xstart`` one step *before* its birth scan, the state at
scan ``birth`` is :math:`f(x_{start})` and every later scan applies the coordinated-turn
transition :math:`f` again (no process noise).  A target is present at scans
``birth..death`` inclusive.  Scans are numbered ``k = 1..K``.

Registered scenarios (:data:`SCENARIOS`, :func:`get_scenario`):

``vo2017``
    The 10-target nonlinear example of Vo, Vo & Hoang (2017), Sec. IV.B, exactly as in their
    MATLAB demo (``gen_truth.m``), ``wturn = 2 pi / 180``.  Targets 8, 9 and 10 leave the
    2000 m sensor range near the end; they are then not detected (``P_D = 0``) but still count
    in the truth (decided here).  Experiments 1 and 5.
``dpy5``
    Targets 1-5 of ``vo2017`` (same specs, same ids): experiment 4 (at most 5 targets).
``proximity``
    Experiment 2 (close proximity).  Five targets follow the *same* path, entering at
    ``k = 0, 5, 20, 30, 40`` and leaving at ``k = 70, 100, 100, 45, 80``; ``k = 0`` is mapped
    to scan 1 (present from the first scan), so the birth scans are 1, 5, 20, 30, 40 and the
    last scans 70, 100, 100, 45, 80.  Target ``j`` at scan ``k`` is at the path state
    :math:`s(k - b_j)` with :math:`s(0) = s_0` and :math:`s(t+1) = f(s(t))`, so all targets
    pass the same points at different times.  Decided here: the path is a gentle
    constant-turn arc inside the sensor field,

    .. math:: s_0 = [-900,\ 18,\ 600,\ 6,\ -\pi/720]

    (speed 19 m/s, turn rate -0.25 deg/s, clockwise).  Over 100 scans it runs from
    (-900, 600) to about (953, 797); its range stays within 791-1243 m and ``p_y >= 600`` m
    (bearing within (-56, 51) deg), well inside the 2000 m / +-90 deg field of view.  The
    common ``xstart`` is :math:`f^{-1}(s_0)` (the transition run with period ``-T``), computed
    for ``T = 1``.
``snr``
    Experiment 3 (varying SNR): 11 targets on straight lines (``omega = 0``) seen by a
    range-only sensor; ``default_snr_db = -3`` (the paper's default; see
    :meth:`Scenario.adapt_params`).  Decided here (state at the birth scan; ``xstart`` is
    one step earlier, ``[px - vx T, vx, py - vy T, vy, 0]``):

    ===  =======  =======  ======  ======  =====  =====  ============  ===========  ==============
    id   px (m)   py (m)   vx      vy      birth  death  range0 (m)    speed (m/s)  range in life
    ===  =======  =======  ======  ======  =====  =====  ============  ===========  ==============
    T1   -1200    1200     10      -5      1      100    1697          11.2         736-1697
    T2   300      400      8       6       1      90     500           10.0         500-1377
    T3   1000     1200     -5      -12     1      80     1562          13.0         655-1562
    T4   -400     300      -12     10      10     100    500           15.6         500-1905
    T5   1500     600      -20     5       10     75     1616          20.6         946-1616
    T6   0        1800     5       -20     20     100    1800          20.6         447-1800
    T7   -800     600      25      0       20     85     1000          25.0         600-1020
    T8   600      1500     -15     -5      30     95     1616          15.8         1233-1616
    T9   200      900      6       2       40     100    922           6.3          922-1164
    T10  -1000    1400     10      -20     50     90     1720          22.4         849-1720
    T11  1200     300      -5      15      60     100    1237          15.8         1233-1345
    ===  =======  =======  ======  ======  =====  =====  ============  ===========  ==============

    Starting bearings spread over -53..76 deg; every target keeps ``p_y > 0`` (so it stays in
    the +-90 deg field the detection model also applies to the range-only sensor) and a range
    in (0, 2000) m while present.  Cardinality: 3 (k=1-9), 5 (10-19), 7 (20-29), 8 (30-39),
    9 (40-49), 10 (50-59), 11 (60-75), 10 (76-80), 9 (81-85), 8 (86-90), 6 (91-95),
    5 (96-100).

Generated families (:mod:`sources.scene_families`; :func:`get_scenario` with a scene ``seed``
and ``scene`` settings):

``random``
    20-30 coordinated-turn objects born anywhere in the field (range 150-1900 m, bearing
    within +-85 deg while present; a trajectory leaving that box is truncated) at random
    scans, lifetimes 15-100 scans, speeds 5-40 m/s, turn rates up to 3 deg/s (a quarter
    straight), plus 3 crossing pairs within 20 m of each other at a recorded scan
    (:attr:`Scenario.crossings`).  No birth regions (``birth = ()``: ``adapt_params`` sets
    ``birth = []``).  Experiment ``random``.
``random-cv``
    Held-out family: 8-15 straight constant-velocity objects, 2-25 m/s, births in 3 bursts,
    no crossing pairs, no birth regions.
``groups``, ``groups-pl``
    Convoys/formations sharing velocity and turn rate (offsets within 40 m), born anywhere,
    one pair of groups passing each other, plus independent objects; ``groups-pl``'s groups
    are a Pitman-Yor partition (d 0.6) of 24 objects: power-law sizes, many singletons.  True
    membership in :attr:`Scenario.groups`.
``groups-py``
    A Pitman-Yor partition (alpha 1, d 0.6; ``scene.py_discount``) of 100-300 objects whose
    groups overlap in space and velocity (one frame does not decide a membership), 50 scans.

The trajectories depend only on the sampling period ``T`` (:meth:`Scenario.truth` takes it
from the parameter set); the scenario tables are defined for ``T = 1`` s.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import msgspec
import numpy as np

from bnptrack.sources.scene import Scenario, TargetSpec
from bnptrack.tracker.config import CLI_NAMES, ArgNames, ConfigError, did_you_mean
from bnptrack.tracker.models.motion import CoordinatedTurn
from bnptrack.tracker.models.params import ModelParams

__all__ = [
    "TargetSpec",
    "Scenario",
    "SCENARIOS",
    "get_scenario",
    "scenario_names",
    "is_generated",
    "WTURN",
    "PROXIMITY_PATH_START",
    "OpenScenario",
    "open_scenario",
    "scene_of",
    "scenario_params",
    "scenario_metadata",
    "adapting_scenario",
    "with_snr",
    "split_scene_overrides",
    "format_overrides",
    "parse_overrides",
    "format_crossings",
    "parse_crossings",
]

#: Turn-rate unit of Vo et al.'s scenario, rad/s.
WTURN = 2.0 * np.pi / 180.0

#: State of the close-proximity path at each target's first present scan.
PROXIMITY_PATH_START = (-900.0, 18.0, 600.0, 6.0, -np.pi / 720.0)




# ----------------------------------------------------------------------------------
# Scenario tables
# ----------------------------------------------------------------------------------
_VO2017_TABLE = [
    ((1003.8676, -10.0, 1488.2543, -10.0, WTURN / 8), 1, 100),
    ((-255.8857, 20.0, 1011.4102, 3.0, -WTURN / 3), 10, 100),
    ((-1507.3806, 11.0, 256.7993, 10.0, -WTURN / 2), 10, 100),
    ((-1500.0, 43.0, 250.0, 0.0, 0.0), 10, 66),
    ((246.1324, 11.0, 738.9253, 5.0, WTURN / 4), 20, 80),
    ((-242.6194, -12.0, 993.2007, -12.0, WTURN / 2), 40, 100),
    ((1000.0, 0.0, 1500.0, -10.0, WTURN / 4), 40, 100),
    ((250.0, -50.0, 750.0, 0.0, -WTURN / 4), 40, 80),
    ((1000.0, -50.0, 1500.0, 0.0, -WTURN / 4), 60, 100),
    ((250.0, -40.0, 750.0, 25.0, WTURN / 4), 60, 100),
]

_VO2017_TARGETS = tuple(
    TargetSpec(f"T{i + 1}", xs, b, d) for i, (xs, b, d) in enumerate(_VO2017_TABLE)
)

# proximity: births/deaths of the paper (k = 0 mapped to scan 1)
_PROX_BIRTHS = (1, 5, 20, 30, 40)
_PROX_DEATHS = (70, 100, 100, 45, 80)
# f^{-1}(s0): the CT transition over -T is its exact inverse (T = 1).
_PROX_XSTART = tuple(
    float(v) for v in CoordinatedTurn(T=-1.0).f(np.asarray(PROXIMITY_PATH_START, dtype=float))
)
_PROXIMITY_TARGETS = tuple(
    TargetSpec(f"T{i + 1}", _PROX_XSTART, b, d)
    for i, (b, d) in enumerate(zip(_PROX_BIRTHS, _PROX_DEATHS, strict=True))
)

# snr: state at the birth scan [px, vx, py, vy] (omega = 0), birth, death
_SNR_TABLE = [
    ((-1200.0, 10.0, 1200.0, -5.0), 1, 100),
    ((300.0, 8.0, 400.0, 6.0), 1, 90),
    ((1000.0, -5.0, 1200.0, -12.0), 1, 80),
    ((-400.0, -12.0, 300.0, 10.0), 10, 100),
    ((1500.0, -20.0, 600.0, 5.0), 10, 75),
    ((0.0, 5.0, 1800.0, -20.0), 20, 100),
    ((-800.0, 25.0, 600.0, 0.0), 20, 85),
    ((600.0, -15.0, 1500.0, -5.0), 30, 95),
    ((200.0, 6.0, 900.0, 2.0), 40, 100),
    ((-1000.0, 10.0, 1400.0, -20.0), 50, 90),
    ((1200.0, -5.0, 300.0, 15.0), 60, 100),
]
_SNR_TARGETS = tuple(
    TargetSpec(f"T{i + 1}", (px - vx, vx, py - vy, vy, 0.0), b, d)
    for i, ((px, vx, py, vy), b, d) in enumerate(_SNR_TABLE)
)

# Birth regions: Vo's convention (zero velocity mean, std [50, 50, 50, 50, 6 deg/s]).
#: Vo, Vo & Hoang's four labeled multi-Bernoulli birth components (gen_model.m), the prior
#: knowledge of where vo2017's (and dpy5's) objects appear.
_TABLE_BIRTH_RATE = 0.01  # the fixed tables: every birth is at a region; a floor elsewhere
_VO_BIRTH = ((0.02, (-1500.0, 0.0, 250.0, 0.0, 0.0)), (0.02, (-250.0, 0.0, 1000.0, 0.0, 0.0)),
             (0.03, (250.0, 0.0, 750.0, 0.0, 0.0)), (0.03, (1000.0, 0.0, 1500.0, 0.0, 0.0)))
_PROX_BIRTH = ((0.05, (PROXIMITY_PATH_START[0], 0.0, PROXIMITY_PATH_START[2], 0.0, 0.0)),)
_SNR_BIRTH = tuple((0.03, (px, 0.0, py, 0.0, 0.0)) for (px, _vx, py, _vy), _b, _d in _SNR_TABLE)

SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            "vo2017",
            "Vo, Vo & Hoang (2017) Sec. IV.B: 10 coordinated-turn targets, bearing-range "
            "sensor (experiments 1 and 5)",
            targets=_VO2017_TARGETS,
            birth=_VO_BIRTH,
            default_birth_rate=_TABLE_BIRTH_RATE,
        ),
        Scenario(
            "dpy5",
            "Targets 1-5 of vo2017 (experiment 4: DPY-STP vs GLMB, at most 5 targets)",
            targets=_VO2017_TARGETS[:5],
            birth=_VO_BIRTH,
            default_birth_rate=_TABLE_BIRTH_RATE,
        ),
        Scenario(
            "proximity",
            "Close proximity: 5 targets on the same constant-turn arc, entering at scans "
            "1, 5, 20, 30, 40 and leaving at 70, 100, 100, 45, 80 (experiment 2)",
            targets=_PROXIMITY_TARGETS,
            birth=_PROX_BIRTH,
            default_birth_rate=_TABLE_BIRTH_RATE,
        ),
        Scenario(
            "snr",
            "Varying SNR: 11 straight-line targets, range-only sensor, default SNR -3 dB "
            "(experiment 3)",
            targets=_SNR_TARGETS,
            kind="range",
            default_snr_db=-3.0,
            default_range_clutter_rate=2.0,
            birth=_SNR_BIRTH,
            # range-only: tracks drift (position is unobservable) and the uniform part of H
            # re-opens them.  DDP-EMM's mean cardinality error, seeds 4-9: 1.10 at the default
            # 0.1 and 1.04 at 0.2 (2.0 at 0.01 on seeds 1-3); docs/trackers.md, "Births".
            default_birth_rate=0.2,
        ),
    )
}


def scenario_names() -> tuple[str, ...]:
    """The fixed scenarios, then the generated families."""
    from bnptrack.sources.scene_families import family_names

    return tuple(SCENARIOS) + family_names()


def is_generated(name: str) -> bool:
    """Whether ``name`` is a generated family (its scene depends on a seed)."""
    from bnptrack.sources.scene_families import FAMILIES

    return name in FAMILIES


def get_scenario(name: str, seed: int | None = None, scene: Sequence[str] = (),
                 names: ArgNames = CLI_NAMES) -> Scenario:
    """Look a scenario up by name; raises :class:`ConfigError` listing the valid names.

    A generated family (``random``, ``random-cv``; :mod:`sources.scene_families`) is built
    from the scene ``seed`` (required) and ``scene`` overrides (``KEY=VALUE``, no ``scene.``
    prefix); the fixed scenarios ignore ``seed`` and reject ``scene`` overrides.
    """
    if name in SCENARIOS:
        if scene:
            raise ConfigError(
                f"scene.* settings ({'; '.join(scene)}) apply only to the generated scenarios "
                f"({', '.join(scenario_names()[len(SCENARIOS):])}), not to {name!r}")
        return SCENARIOS[name]
    if not is_generated(name):
        raise ConfigError(
            f"unknown scenario {name!r}{did_you_mean(name, scenario_names())}; valid scenarios: "
            f"{', '.join(scenario_names())}"
        )
    if seed is None:
        raise ConfigError(f"scenario {name!r} is generated: it needs a scene seed")
    return _generated(name, int(seed), tuple(scene), names)


@functools.lru_cache(maxsize=32)
def _generated(name: str, seed: int, scene: tuple[str, ...], names: ArgNames) -> Scenario:
    from bnptrack.sources.scene_families import generate_scene

    return generate_scene(name, seed, scene, names)


# --------------------------------------------------------------------------- opening a scenario
# (the one place that applies ``--set`` overrides, ``--snr`` and the scenario's defaults, and
# writes / reads the ``bnptrack.scenario`` record of a simulated log)

OVERRIDE_SEP = ";"
SCENE_PREFIX = "scene."


def format_overrides(overrides: Sequence[str]) -> str:
    """Join ``key=value`` overrides for the metadata record (``;``-separated)."""
    return OVERRIDE_SEP.join(o.strip() for o in overrides)


def parse_overrides(text: str | None) -> tuple[str, ...]:
    """Inverse of :func:`format_overrides` (empty or missing text: no overrides)."""
    if not text:
        return ()
    return tuple(item.strip() for item in text.split(OVERRIDE_SEP) if item.strip())


def format_crossings(crossings: Sequence[tuple[str, str, int]]) -> str:
    """``(id_a, id_b, scan)`` triples as ``id_a,id_b,scan;...`` (metadata text)."""
    return OVERRIDE_SEP.join(f"{a},{b},{int(k)}" for a, b, k in crossings)


def parse_crossings(text: str | None) -> tuple[tuple[str, str, int], ...]:
    """Inverse of :func:`format_crossings` (empty or missing text: no pairs)."""
    out = []
    for item in parse_overrides(text):
        a, b, k = (v.strip() for v in item.split(","))
        out.append((a, b, int(k)))
    return tuple(out)


def split_scene_overrides(overrides: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Split ``--set`` items into (``scene.KEY=V`` items without the prefix, the others)."""
    scene, rest = [], []
    for item in overrides:
        item = item.strip()
        if item.startswith(SCENE_PREFIX):
            scene.append(item[len(SCENE_PREFIX):])
        else:
            rest.append(item)
    return tuple(scene), tuple(rest)


def with_snr(params: ModelParams, snr_db: float | None) -> ModelParams:
    """``params`` with ``snr_db`` set (``None``: unchanged)."""
    if snr_db is None:
        return params
    return msgspec.structs.replace(params, snr_db=float(snr_db))


def adapting_scenario(name: str) -> Scenario:
    """The scenario whose ``adapt_params`` applies: the fixed table, or a generated family's
    template (the same for every scene of the family: no birth regions)."""
    if is_generated(name):
        from bnptrack.sources.scene_families import family_template

        return family_template(name)
    return get_scenario(name)


@dataclass(frozen=True)
class OpenScenario:
    """A scenario ready to simulate: the scene, the final model parameters and the
    ``bnptrack.scenario`` record of its log."""

    scenario: Scenario
    params: ModelParams
    metadata: dict[str, str]


def open_scenario(
    name: str, params: str, seed: int, overrides: Sequence[str] = (), snr_db: float | None = None,
    names: ArgNames = CLI_NAMES,
) -> OpenScenario:
    """Scenario ``name`` with model parameter set ``params`` (a built-in name or TOML file):
    the scene (:func:`scene_of`), the parameters (:func:`scenario_params`) and the record
    (:func:`scenario_metadata`).  Raises :class:`ConfigError` for an unknown name or key,
    naming ``params`` and ``overrides`` as ``names`` say."""
    scenario = scene_of(name, seed, overrides, names)
    p = scenario_params(name, params, overrides, snr_db, names)
    return OpenScenario(scenario, p, scenario_metadata(scenario, params, seed, p, overrides))


def scene_of(name: str, seed: int, overrides: Sequence[str] = (), names: ArgNames = CLI_NAMES) -> Scenario:
    """The scenario to simulate: a fixed table, or a generated family's scene for the scene
    seed ``seed`` and the ``scene.*`` items of ``overrides`` (other items are ignored here)."""
    scene, _ = split_scene_overrides(overrides)
    return get_scenario(name, seed=seed, scene=scene, names=names)


def scenario_params(
    name: str, params: str, overrides: Sequence[str] = (), snr_db: float | None = None,
    names: ArgNames = CLI_NAMES,
) -> ModelParams:
    """Parameters for simulating scenario ``name``: the set ``params``, the ``--set`` items of
    ``overrides`` (``scene.*`` items are left to :func:`scene_of`), ``snr_db`` (``--snr``),
    then the scenario's defaults (:meth:`Scenario.adapt_params`, e.g. -3 dB for ``snr``, no
    birth regions for ``random``)."""
    from bnptrack.tracker.models.params import load_params

    _, model_over = split_scene_overrides(overrides)
    adapting = adapting_scenario(name)
    return adapting.adapt_params(with_snr(load_params(params, model_over, names), snr_db))


def scenario_metadata(
    scenario: Scenario, params_name: str, seed: int, params: ModelParams, overrides: Sequence[str] = ()
) -> dict[str, str]:
    """The ``bnptrack.scenario`` record of a simulated log: scenario, params, seed, plus
    snr_db and the model ``overrides`` when used; for a generated scene also ``scene_seed``,
    its ``scene`` overrides (``;``-separated, without ``scene.``) and its ``crossings``
    (``id_a,id_b,scan`` items, ``;``-separated)."""
    scene, model_over = split_scene_overrides(overrides)
    meta = {"scenario": scenario.name, "params": params_name, "seed": str(seed)}
    if params.snr_db is not None:
        meta["snr_db"] = repr(float(params.snr_db))
    if model_over:
        meta["overrides"] = format_overrides(model_over)
    if scenario.seed is not None:
        meta["scene_seed"] = str(scenario.seed)
        if scene:
            meta["scene"] = format_overrides(scene)
        meta["crossings"] = format_crossings(scenario.crossings)
    return meta
