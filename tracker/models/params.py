"""Model parameter sets: sensor noise, P_D, clutter, P_S, process noise, field of view, birth.

A parameter set is a named, typed, frozen struct.  The built-in sets ``vo2017`` (Vo, Vo & Hoang
2017's demo) and ``paper`` (Moraffah & Papandreou-Suppappola) ship as TOML files in
``tracker/params/``; every command accepts ``--params NAME|FILE.toml`` plus ``--set key=value``.
See ``docs/models.md`` for the table of values and the choices made where the sources are silent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

from bnptrack.tracker.config import (CLI_NAMES, ArgNames, ClutterRate, ConfigError, HalfFovDeg, NonNeg, Positive, Prob, StateList, apply_overrides, convert, did_you_mean,
                            load_toml, read_toml)
from bnptrack.tracker.input_checks import check_sensor_spec
from bnptrack.tracker.models.clutter import ClutterModel, Detection
from bnptrack.tracker.models.measurement import DEFAULT_KIND, KINDS, MeasurementModel, measurement_kind
from bnptrack.tracker.models.motion import CoordinatedTurn
from bnptrack.tracker.models.sensors import Sensor, SensorSpec


#: Expected new objects per scan appearing anywhere, when neither the parameter set nor the
#: scenario states it (docs/models.md).
DEFAULT_BIRTH_RATE = 0.1


class BirthComponent(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One labeled-multi-Bernoulli birth component: existence ``r`` and a Gaussian."""

    r: Prob
    mean: StateList
    std: StateList


class ModelParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Physical model parameters shared by the simulator and every tracker.

    Angles in the TOML files are in degrees where the field name says so.
    """

    name: str
    T: Positive = 1.0
    sigma_accel: NonNeg = 5.0
    """Process noise std of acceleration, m/s^2 (``s`` of the CT model)."""
    sigma_turn_deg: NonNeg = 1.0
    """Process noise std of the turn rate, deg/s."""
    process_noise_dt: Literal["composed", "dwna"] = "composed"
    """Process noise over an interval ``dt != T`` (dropped frames, irregular stamps; identical at
    ``dt == T``): ``composed`` the per-scan noise accumulated over ``dt``
    (:func:`~tracker.models.motion.process_noise_block`), ``dwna`` the per-scan formula with
    ``T`` replaced by ``dt`` (the ablation; it over-states the noise of a gap)."""
    survival_dt: Literal["path", "end"] = "path"
    """Survival over an interval ``dt > T`` (a gap): ``path`` the per-scan ``P_S`` at each of the
    ``ceil(dt/T)`` scan instants of the gap, along the noise-free path back from the predicted
    mean (an object that leaves the field of view in the middle of a gap is "outside" only for
    the scans after it left); ``end`` ``P_S`` at the predicted mean for the whole gap (the
    ablation).  Identical at ``dt <= T``."""
    p_survival: Prob = 0.99
    p_survival_outside: Prob = 0.7
    """Survival probability per scan of an object predicted outside the field of view
    (trackers only; the surveillance region is the sensor's field of view)."""
    p_detect: Prob = 0.98
    clutter_rate: ClutterRate = 15.0
    """Mean number of clutter measurements per scan (at most 1e6)."""
    range_clutter_rate: ClutterRate | None = None
    """Mean clutter per scan of the range-only sensor (``None``: ``clutter_rate``).  The
    ``snr`` scenario sets 2 (``docs/models.md``: range space is one-dimensional)."""
    sigma_bearing_deg: Positive = 2.0
    sigma_range: Positive = 10.0
    sigma_xy: Positive = 10.0
    """Position noise std (m) per axis of ``xy`` detections (``R = sigma_xy^2 I``)."""
    range_max: Positive = 2000.0
    bearing_half_fov_deg: HalfFovDeg = 90.0
    snr_db: float | None = None
    """If set, measurement noise variance is scaled by ``10**(-snr_db/10)``."""
    snr_pd_reference_db: float | None = None
    """If set (with ``snr_db``), P_D follows the Swerling-I relation (see ``Detection``)."""
    birth_rate: NonNeg | None = None
    """Expected number of new objects per scan appearing *anywhere* in the field of view, in
    addition to the birth regions of ``birth`` (whose ``r`` are their own expected births per
    scan); ``None``: :data:`DEFAULT_BIRTH_RATE`, or the scenario's (``anywhere_birth_rate``).
    The uninformative part of the birth model: the BNP trackers' base distribution H weighs
    its uniform part by ``rate / (rate + sum r)`` (1 without regions); the DP's alpha then
    learns the actual rate.  (The GLMB's adaptive birth has its own ``lambda_B``,
    ``GlmbConfig.adaptive_birth_rate``.)  0 allows births only at the birth regions."""
    birth: list[BirthComponent] = msgspec.field(default_factory=list)
    sensors: dict[str, SensorSpec] = msgspec.field(default_factory=dict)
    """``[sensors.NAME]`` tables: pose, field of view and noise of the sensor whose frames
    carry ``sensor = NAME`` (:mod:`tracker.models.sensors`).  A sensor without a table is
    the default one: at the origin, boresight +y, the set's field of view and noise."""

    def __post_init__(self) -> None:
        for name, spec in self.sensors.items():  # at load, not at the sensor's first frame
            if spec.kind is not None and spec.kind not in KINDS:
                raise ValueError(f"[sensors.{name}] kind = {spec.kind!r} is not a measurement kind"
                                 f"{did_you_mean(spec.kind, list(KINDS))} (known: {', '.join(KINDS)})")
            check_sensor_spec(name, spec.heading_deg)

    # --- model factories -------------------------------------------------------------
    @property
    def anywhere_birth_rate(self) -> float:
        """``birth_rate``, or :data:`DEFAULT_BIRTH_RATE` when unset."""
        return DEFAULT_BIRTH_RATE if self.birth_rate is None else float(self.birth_rate)

    @property
    def noise_scale(self) -> float:
        """Variance multiplier from SNR: ``10**(-snr_db/10)`` (1 when no SNR is set)."""
        return 1.0 if self.snr_db is None else 10.0 ** (-self.snr_db / 10.0)

    def motion(self, dt: float | None = None) -> CoordinatedTurn:
        """The CT model over ``dt`` seconds (default ``T``): process noise ``Q(dt)`` of
        :func:`~tracker.models.motion.process_noise_block` (stated per scan period ``T``), or
        with ``process_noise_dt = "dwna"`` the paper's formula evaluated at ``dt``."""
        period = self.T if self.process_noise_dt == "composed" else None
        return CoordinatedTurn(self.T if dt is None else float(dt), self.sigma_accel,
                               np.deg2rad(self.sigma_turn_deg), period)

    # --- sensors -----------------------------------------------------------------------
    def sensor(self, name: str = "", kind: str = DEFAULT_KIND,
               pose: tuple[float, float, float] | None = None, R: np.ndarray | None = None) -> Sensor:
        """The resolved sensor ``name`` for frames of ``kind``: defaults, then its
        ``[sensors.NAME]`` table, then the frame's ``pose`` / ``R`` (``tracker.models.sensors``)."""
        entry = measurement_kind(kind)
        spec = self.sensors.get(name) or SensorSpec()
        if spec.kind is not None and spec.kind != kind:
            raise ValueError(f"sensor {name!r} is declared kind {spec.kind!r} but its frame has kind {kind!r}")
        k = np.sqrt(self.noise_scale)
        x, y, heading = spec.x, spec.y, float(np.deg2rad(spec.heading_deg))
        if pose is not None:
            x, y, heading = (float(v) for v in pose)
        rate = self.clutter_rate
        if entry.clutter_rate_field is not None and getattr(self, entry.clutter_rate_field) is not None:
            rate = getattr(self, entry.clutter_rate_field)
        noise = None if R is None else tuple(tuple(float(v) for v in row) for row in np.asarray(R, dtype=float))
        return Sensor(
            name, kind, float(x), float(y), heading, float(spec.range_min),
            float(self.range_max if spec.range_max is None else spec.range_max),
            float(np.deg2rad(self.bearing_half_fov_deg if spec.half_fov_deg is None else spec.half_fov_deg)),
            float(np.deg2rad(self.sigma_bearing_deg if spec.sigma_bearing_deg is None else spec.sigma_bearing_deg) * k),
            float((self.sigma_range if spec.sigma_range is None else spec.sigma_range) * k),
            float((self.sigma_xy if spec.sigma_xy is None else spec.sigma_xy) * k),
            float(self.p_detect if spec.p_detect is None else spec.p_detect),
            float(rate if spec.clutter_rate is None else spec.clutter_rate),
            noise,
        )

    def frame_sensor(self, frame) -> Sensor:
        """The resolved sensor of a :class:`~tracker.types.Frame` (its name, kind, pose, R)."""
        return self.sensor(frame.sensor, frame.kind, frame.pose, frame.R)

    def measurement(self, kind: str = DEFAULT_KIND, sensor: Sensor | None = None
                    ) -> MeasurementModel:
        """The measurement model of ``kind`` for ``sensor`` (default: the default sensor),
        built by the kind's model class (:data:`~tracker.models.measurement.KINDS`)."""
        s = self.sensor(kind=kind) if sensor is None else sensor
        return measurement_kind(kind).measurement(s)

    def clutter(self, kind: str = DEFAULT_KIND, sensor: Sensor | None = None) -> ClutterModel:
        """Clutter uniform over the sensor's field of view, in its measurement space (the
        kind's registry entry builds it)."""
        s = self.sensor(kind=kind) if sensor is None else sensor
        return measurement_kind(kind).clutter(s)

    def detection(self, kind: str = DEFAULT_KIND, sensor: Sensor | None = None) -> Detection:
        s = self.sensor(kind=kind) if sensor is None else sensor
        return Detection(
            s.p_detect,
            s.range_max,
            -s.half_fov,
            s.half_fov,
            snr_db=self.snr_db,
            snr_reference_db=self.snr_pd_reference_db,
            sensor_x=s.x,
            sensor_y=s.y,
            range_only=measurement_kind(kind).range_only,
            heading=s.heading,
            range_min=s.range_min,
        )

    def survival(self, x: np.ndarray, kind: str = DEFAULT_KIND, sensor: Sensor | None = None,
                 visible: np.ndarray | None = None) -> np.ndarray:
        """``(N,)`` P_S(x): ``p_survival`` inside the surveillance region, ``p_survival_outside``
        beyond.  The region is the field of view of the frame's sensor united with those of the
        declared ``[sensors.*]`` (several sensors share one tracker state).  ``visible``: the
        frame's sensor's field-of-view test of ``x`` (``detection(kind, sensor).visible(x)``)
        when the caller has made it (a tracker, for its P_D too): then the only test made here
        is that of the declared sensors, none when there are none."""
        inside = self.detection(kind, sensor).visible(x) if visible is None else visible
        for name, spec in self.sensors.items():
            if sensor is None or name != sensor.name:
                k = spec.kind or kind
                inside = inside | self.detection(k, self.sensor(name, k)).visible(x)
        return np.where(inside, self.p_survival, self.p_survival_outside)

    def survival_over(self, x: np.ndarray, dt: float, kind: str = DEFAULT_KIND,
                      sensor: Sensor | None = None, visible: np.ndarray | None = None) -> np.ndarray:
        r"""``(N,)`` survival over the ``dt`` seconds that end at the states ``x`` (predicted means).

        One scan's ``P_S`` per ``T``: exactly :meth:`survival` at ``dt == T`` and
        :math:`P_S(x)^{\Delta t / T}` for ``dt < T``.  Over a gap ``dt > T`` (``survival_dt =
        "path"``) the gap is cut into :math:`n = \lceil \Delta t / T \rceil` equal parts of
        :math:`h = \Delta t / n` and

        .. math:: \bar P_S = \prod_{i=0}^{n-1} P_S(x_i)^{h/T}, \qquad x_i = F_{-i h}(x)

        (:math:`F_{-ih}` the noise-free CT flow back by :math:`ih`, the exact inverse): at
        ``dt = n T`` the product of the ``n`` per-scan survivals at the scan instants, as if
        the sensor had scanned and seen nothing (docs/models.md); at most
        ``_MAX_SURVIVAL_STEPS`` parts (a longer gap's parts span several scans).  ``"end"``:
        :math:`P_S(x)^{\Delta t / T}`.  ``visible``: as for :meth:`survival` (of ``x`` only)."""
        ps = self.survival(x, kind, sensor, visible)
        if dt == self.T:
            return ps
        n = min(math.ceil(dt / self.T - 1e-9), _MAX_SURVIVAL_STEPS)
        if self.survival_dt == "end" or n <= 1 or not len(ps):
            return ps ** (dt / self.T)
        h = dt / n
        back = self.motion(-h)
        with np.errstate(divide="ignore"):  # P_S = 0 is allowed
            log_ps, xi = np.log(ps), np.asarray(x, dtype=float)
            for _ in range(n - 1):
                xi = back.f(xi)
                log_ps = log_ps + np.log(self.survival(xi, kind, sensor))
        return np.exp(log_ps * (h / self.T))


_MAX_SURVIVAL_STEPS = 50
"""Parts of a gap :meth:`ModelParams.survival_over` evaluates at most (a bound on its cost)."""

BUILTIN_PARAMS = ("vo2017", "paper")


def builtin_params_path(name: str) -> Path:
    return Path(str(resources.files("bnptrack.tracker") / "params" / f"{name}.toml"))


def load_params(source: str | Path = "vo2017", overrides: Sequence[str] = (),
                names: ArgNames = CLI_NAMES) -> ModelParams:
    """Load a parameter set by built-in name or TOML path, then apply ``key=value`` overrides.

    A file names only what it changes: ``extends = "vo2017"`` (a built-in name or another
    file, relative to this one) starts from that set, and without ``extends`` from the
    defaults of :class:`ModelParams`; ``name`` defaults to the file's stem.  Top-level keys
    replace the base's (``birth`` regions are inherited unless the file gives ``birth``), and
    ``[sensors.NAME]`` tables are merged per sensor.  An unknown key fails with a
    "did you mean".  Errors name ``source`` and the overrides as ``names`` say (the command
    line's ``--params`` / ``--set``, or a Python call's arguments).
    """
    text = str(source)
    if text in BUILTIN_PARAMS:
        params = load_toml(builtin_params_path(text), ModelParams)
    elif text.endswith(".toml") or Path(text).exists():
        params = convert(_file_data(Path(text), ()), ModelParams, text)
    else:
        raise ConfigError(
            f"{names.params.format(text)}: not a built-in set ({', '.join(BUILTIN_PARAMS)}) nor a .toml file"
        )
    return apply_overrides(params, overrides, names=names)


def _file_data(path: Path, seen: tuple[Path, ...]) -> dict:
    """The plain data of a params file with its ``extends`` chain resolved (see :func:`load_params`)."""
    data = read_toml(path)
    check_keys(data, str(path))
    base_name = data.pop("extends", None)
    data.setdefault("name", path.stem)
    if base_name is None:
        return data
    if not isinstance(base_name, str):
        raise ConfigError(f"{path}: extends must be a parameter set name or a .toml path")
    if base_name in BUILTIN_PARAMS:
        base = msgspec.to_builtins(load_toml(builtin_params_path(base_name), ModelParams))
    else:
        base_path = (path.parent / base_name).resolve()
        if base_path in seen:
            raise ConfigError(f"{path}: extends cycle through {base_path}")
        if not base_path.exists():
            raise ConfigError(f"{path}: extends {base_name!r}: not a built-in set "
                              f"({', '.join(BUILTIN_PARAMS)}) nor an existing file")
        base = _file_data(base_path, seen + (path.resolve(),))
    sensors = {**base.get("sensors", {})}
    for name, table in data.get("sensors", {}).items():
        sensors[name] = {**sensors.get(name, {}), **table}
    merged = {**base, **data}
    if sensors:
        merged["sensors"] = sensors
    return merged


_PARAM_KEYS = tuple(ModelParams.__struct_fields__) + ("extends",)
_SENSOR_KEYS = tuple(SensorSpec.__struct_fields__)


def check_keys(data: dict, origin: str) -> None:
    """Reject unknown keys of a params file with the closest known one (difflib)."""
    for key in data:
        if key not in _PARAM_KEYS:
            raise ConfigError(f"{origin}: unknown key '{key}'{did_you_mean(key, _PARAM_KEYS)} "
                              f"(docs/models.md lists the keys)")
    sensors = data.get("sensors", {})
    if not isinstance(sensors, dict):
        raise ConfigError(f"{origin}: sensors must be tables [sensors.NAME]")
    for name, table in sensors.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{origin}: sensors.{name} must be a table [sensors.{name}]")
        for key in table:
            if key not in _SENSOR_KEYS:
                raise ConfigError(f"{origin}: unknown key 'sensors.{name}.{key}'{did_you_mean(key, _SENSOR_KEYS)} "
                                  f"(known: {', '.join(_SENSOR_KEYS)})")
