"""Offline building blocks shared by the ``bnptrack`` commands (simulate, track, and later
replay / experiment): resolving model parameters, tracker settings and ``--set`` overrides,
and the offline tracking loop with per-frame metrics.

Everything here is a plain function over plain data; the click commands in
:mod:`pipeline.cli` only parse options, call these and print.  The tracker and the metrics
(which pull in scipy) are imported where they are used, so ``bnptrack --help`` stays quick.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import numpy as np

from sources.mcap_log import McapLogError, McapLogWriter, iter_frames
from sources.scenarios import get_scenario, is_generated
from sources.synthetic import simulate, simulate_sensors
from tracker.config import ConfigError, apply_overrides, load_toml, split_item
from tracker.models.params import ModelParams, load_params
from tracker.state import run
from tracker.types import Estimate, Frame, FrameBoundError, FrameBounds, bounded_frames

if TYPE_CHECKING:
    from tracker.registry import Tracker

__all__ = [
    "DEFAULT_PARAMS",
    "TRACKERS",
    "OSPA_C",
    "OSPA_P",
    "ParamsChoice",
    "SimulationResult",
    "FrameMetrics",
    "TrackResult",
    "format_overrides",
    "parse_overrides",
    "resolve_simulation_params",
    "resolve_scenario",
    "split_scene_overrides",
    "simulation_metadata",
    "format_crossings",
    "parse_crossings",
    "resolve_params",
    "resolve_config",
    "split_overrides",
    "apply_split_overrides",
    "build_tracker",
    "simulate_to_log",
    "frame_metrics",
    "track_frames",
    "score_crossings",
    "track_log",
    "default_tracks_path",
    "check_output_path",
]

#: Parameter set used when neither ``--params`` nor the log says which one.
DEFAULT_PARAMS = "vo2017"
#: Trackers ``bnptrack track`` can run (see :mod:`tracker.registry`).
from tracker.registry import TRACKERS  # noqa: E402
#: OSPA settings of the paper's experiments (cut-off in metres, order): one definition, in
#: :mod:`sinks.scoring`.
from sinks.metrics import CrossingResult, OspaResult  # noqa: E402
from sinks.scoring import OSPA_C, OSPA_P  # noqa: E402

_OVERRIDE_SEP = ";"


# --------------------------------------------------------------------------- overrides


def format_overrides(overrides: Sequence[str]) -> str:
    """Join ``key=value`` overrides for the metadata record (``;``-separated)."""
    return _OVERRIDE_SEP.join(o.strip() for o in overrides)


def parse_overrides(text: str | None) -> tuple[str, ...]:
    """Inverse of :func:`format_overrides` (empty or missing text: no overrides)."""
    if not text:
        return ()
    return tuple(item.strip() for item in text.split(_OVERRIDE_SEP) if item.strip())


def _struct_fields(cls: type[msgspec.Struct]) -> tuple[str, ...]:
    return tuple(cls.__struct_fields__)


def split_overrides(
    overrides: Sequence[str], config_cls: type[msgspec.Struct] | None = None
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Route ``--set`` items to (model parameters, tracker settings).

    ``params.KEY=V`` goes to :class:`ModelParams`, ``tracker.KEY=V`` to the tracker's settings
    (``config_cls``, default :class:`BnpConfig`); a bare ``KEY=V`` goes to whichever has the
    field (``ModelParams`` first).  Raises :class:`ConfigError` naming the key when neither has it.
    """
    if config_cls is None:
        from tracker.bnp_tracker import BnpConfig as config_cls

    p_fields, t_fields = _struct_fields(ModelParams), _struct_fields(config_cls)
    to_params: list[str] = []
    to_tracker: list[str] = []
    for item in overrides:
        key, value = split_item(item)
        head, dot, rest = key.partition(".")
        if dot and head == "params":
            to_params.append(f"{rest}={value}")
        elif dot and head == "tracker":
            to_tracker.append(f"{rest}={value}")
        elif head in p_fields:
            to_params.append(f"{key}={value}")
        elif head in t_fields:
            to_tracker.append(f"{key}={value}")
        else:
            raise ConfigError(
                f"--set {item!r}: unknown key '{key}': not a model parameter "
                f"({', '.join(p_fields)}) nor a tracker setting ({', '.join(t_fields)}); "
                "use params.KEY or tracker.KEY to be explicit"
            )
    return tuple(to_params), tuple(to_tracker)


def apply_split_overrides(
    params: ModelParams, config: msgspec.Struct, overrides: Sequence[str]
) -> tuple[ModelParams, msgspec.Struct]:
    """Apply ``--set`` overrides to both structs (see :func:`split_overrides`)."""
    p_over, t_over = split_overrides(overrides, type(config))
    return apply_overrides(params, p_over), apply_overrides(config, t_over)


# --------------------------------------------------------------------------- params


@dataclass(frozen=True)
class ParamsChoice:
    """The model parameters a command uses, and where they came from.

    ``source`` is the built-in name or file path; ``reason`` a short human explanation
    (e.g. ``"from --params"``, ``"from the log's bnptrack.scenario record"``).
    """

    params: ModelParams
    source: str
    reason: str
    overrides: tuple[str, ...] = ()

    def describe(self, final: ModelParams | None = None, overrides: Sequence[str] = ()) -> str:
        """One line: source, reason, the log's overrides, extra ``--set`` items and the SNR
        of ``final`` (the parameters after those items; default: :attr:`params`)."""
        final = self.params if final is None else final
        extra = []
        if self.overrides:
            extra.append("log overrides " + " ".join(self.overrides))
        if overrides:
            extra.append("--set " + " ".join(overrides))
        set_keys = {o.partition("=")[0].strip() for o in overrides}
        if final.snr_db is not None and "snr_db" not in set_keys:
            extra.append(f"snr_db {final.snr_db:g}")
        tail = f"; {'; '.join(extra)}" if extra else ""
        return f"{self.source} ({self.reason}{tail})"


def _with_snr(params: ModelParams, snr_db: float | None) -> ModelParams:
    if snr_db is None:
        return params
    return msgspec.structs.replace(params, snr_db=float(snr_db))


_SCENE_PREFIX = "scene."


def split_scene_overrides(overrides: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Split ``--set`` items into (``scene.KEY=V`` items without the prefix, the others)."""
    scene, rest = [], []
    for item in overrides:
        item = item.strip()
        if item.startswith(_SCENE_PREFIX):
            scene.append(item[len(_SCENE_PREFIX):])
        else:
            rest.append(item)
    return tuple(scene), tuple(rest)


def resolve_scenario(scenario: str, seed: int, overrides: Sequence[str] = ()):
    """The :class:`~sources.scenarios.Scenario` to simulate: a fixed table, or a generated
    family's scene for the scene seed ``seed`` (the run's seed) and the ``scene.*`` items of
    ``overrides`` (other items are ignored here)."""
    scene, _ = split_scene_overrides(overrides)
    return get_scenario(scenario, seed=seed, scene=scene)


def _adapting_scenario(name: str):
    """The scenario whose ``adapt_params`` applies: the fixed table, or a generated family's
    template (the same for every scene of the family: no birth regions)."""
    if is_generated(name):
        from sources.scene_families import family_template

        return family_template(name)
    return get_scenario(name)


def resolve_simulation_params(
    scenario: str, params: str, overrides: Sequence[str] = (), snr_db: float | None = None
) -> ModelParams:
    """Parameters for simulating ``scenario``: the set, ``--set`` overrides (``scene.*`` items
    are left to :func:`resolve_scenario`), ``--snr``, then the scenario's defaults
    (``Scenario.adapt_params``, e.g. -3 dB for ``snr``, no birth regions for ``random``)."""
    _, model_over = split_scene_overrides(overrides)
    sc = _adapting_scenario(scenario)
    p = _with_snr(load_params(params, model_over), snr_db)
    return sc.adapt_params(p)


def simulation_metadata(
    scenario, params_name: str, seed: int, params: ModelParams, overrides: Sequence[str] = ()
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


def format_crossings(crossings: Sequence[tuple[str, str, int]]) -> str:
    """``(id_a, id_b, scan)`` triples as ``id_a,id_b,scan;...`` (metadata text)."""
    return _OVERRIDE_SEP.join(f"{a},{b},{int(k)}" for a, b, k in crossings)


def parse_crossings(text: str | None) -> tuple[tuple[str, str, int], ...]:
    """Inverse of :func:`format_crossings` (empty or missing text: no pairs)."""
    out = []
    for item in parse_overrides(text):
        a, b, k = (v.strip() for v in item.split(","))
        out.append((a, b, int(k)))
    return tuple(out)


def resolve_params(
    params_arg: str | None, metadata: Mapping[str, str] | None
) -> ParamsChoice:
    """Model parameters for tracking a log.

    1. ``params_arg`` (``--params NAME|FILE.toml``) when given;
    2. else the log's ``bnptrack.scenario`` record: its ``params`` value, its ``overrides``
       (the ``--set`` items used when simulating) and its ``snr_db``;
    3. else the :data:`DEFAULT_PARAMS` set.

    When the record names a known scenario, its defaults are applied as ``simulate`` applied
    them (:meth:`Scenario.adapt_params`: birth regions, none for the generated families, SNR,
    range clutter), in every case.
    """
    meta = dict(metadata or {})
    if params_arg:
        choice = ParamsChoice(load_params(params_arg), params_arg, "from --params")
    elif meta.get("params"):
        choice = _params_from_record(meta)
    else:
        why = (
            "default: the log has no bnptrack.scenario record"
            if metadata is None
            else "default: the log's bnptrack.scenario record names no params"
        )
        choice = ParamsChoice(load_params(DEFAULT_PARAMS), DEFAULT_PARAMS, why)
    return _adapt_to_scenario(choice, meta.get("scenario"))


def _params_from_record(meta: Mapping[str, str]) -> ParamsChoice:
    name = meta["params"]
    overrides = parse_overrides(meta.get("overrides"))
    try:
        p = load_params(name, overrides)
        snr = meta.get("snr_db")
        p = _with_snr(p, float(snr) if snr not in (None, "") else None)
    except (ConfigError, ValueError) as exc:
        raise ConfigError(
            f"params {name!r} named by the log's bnptrack.scenario record: {exc} "
            "(pass --params NAME|FILE.toml)"
        ) from None
    return ParamsChoice(p, name, "from the log's bnptrack.scenario record", overrides)


def _adapt_to_scenario(choice: ParamsChoice, scenario: str | None) -> ParamsChoice:
    """Apply the defaults of the scenario a log's record names (unknown names: unchanged)."""
    if not scenario:
        return choice
    try:
        sc = _adapting_scenario(scenario)
    except ConfigError:
        return choice
    params = sc.adapt_params(choice.params)
    regions = f"{len(params.birth)} birth regions" if params.birth else "no birth regions"
    return ParamsChoice(params, choice.source, f"{choice.reason}; scenario {scenario}: {regions}",
                        choice.overrides)


# --------------------------------------------------------------------------- tracker config


def resolve_config(tracker: str, config_arg: str | None) -> tuple[msgspec.Struct, str]:
    """Tracker settings: a preset name or a TOML file of the tracker's settings fields;
    default: the preset named like the tracker.  Returns ``(config, description)``."""
    from tracker.registry import kind

    try:
        k = kind(tracker)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if not config_arg:
        return k.presets[tracker], f"preset {tracker} (default for --tracker {tracker})"
    if config_arg in k.presets:
        return k.presets[config_arg], f"preset {config_arg}"
    if config_arg.endswith(".toml") or Path(config_arg).exists():
        return load_toml(config_arg, k.config_cls), f"file {config_arg}"
    raise ConfigError(
        f"--config {config_arg!r}: not a preset of {tracker} ({', '.join(k.presets)}) nor a .toml file"
    )


def build_tracker(name: str, params: ModelParams, config: msgspec.Struct):
    """The tracker ``name`` (see :mod:`tracker.registry`) with these parameters and settings."""
    from tracker.registry import build

    try:
        return build(name, params, config)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


# --------------------------------------------------------------------------- simulate


@dataclass(frozen=True)
class SimulationResult:
    """What :func:`simulate_to_log` wrote."""

    path: str
    frames: int
    measurements: int
    target_scans: int
    size_bytes: int

    @property
    def mean_measurements(self) -> float:
        return self.measurements / self.frames if self.frames else 0.0


def simulate_to_log(
    scenario: str,
    params: ModelParams,
    seed: int,
    out: str | os.PathLike,
    metadata: Mapping[str, str],
    overrides: Sequence[str] = (),
) -> SimulationResult:
    """Simulate ``scenario`` with ``params`` (already resolved) and write an MCAP log; a
    generated scenario's scene is drawn from ``seed`` and the ``scene.*`` ``overrides``."""
    sc = resolve_scenario(scenario, seed, overrides)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    n_frames = n_meas = n_targets = 0
    # a parameter set that declares sensors ([sensors.NAME]) is simulated with all of them:
    # one frame per sensor per scan, interleaved (sources.synthetic.simulate_sensors)
    frames = simulate_sensors(sc, params, seed, list(params.sensors)) if params.sensors else simulate(sc, params, seed)
    with McapLogWriter(out, dict(metadata)) as writer:
        for frame in frames:
            writer.write_frame(frame)
            n_frames += 1
            n_meas += frame.n_measurements
            n_targets += len(frame.truth.ids) if frame.truth is not None else 0
    return SimulationResult(str(out), n_frames, n_meas, n_targets, out.stat().st_size)


# --------------------------------------------------------------------------- tracking


@dataclass(frozen=True)
class FrameMetrics:
    """Per-frame result of an offline run.  Truth-based fields are ``None`` without truth."""

    frame: int
    n_measurements: int
    n_tracks: int
    ms: float
    n_true: int | None = None
    ospa: float | None = None
    ospa_localisation: float | None = None
    ospa_cardinality: float | None = None
    cardinality_error: float | None = None

    @property
    def ospa_result(self) -> OspaResult | None:
        """The OSPA of this frame as :class:`sinks.metrics.OspaResult` (``None`` without truth)."""
        if self.ospa is None:
            return None
        return OspaResult(self.ospa, self.ospa_localisation, self.ospa_cardinality)


@dataclass(frozen=True)
class TrackResult:
    """An offline tracking run: per-frame metrics plus the error that ended it early, if any
    (a damaged log, or a frame beyond the :class:`tracker.types.FrameBounds`)."""

    tracker: str
    frames: tuple[FrameMetrics, ...]
    final_tracks: int
    error: McapLogError | FrameBoundError | None = None
    crossings: CrossingResult | None = None
    """Label keeping through the log's crossing pairs (``None``: no pairs or no truth)."""
    warnings: tuple[str, ...] = ()
    """Why the run probably cannot work (:class:`RunHealth`): printed by ``track``."""

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def _truth_values(self, name: str) -> np.ndarray:
        return np.array([getattr(f, name) for f in self.frames if getattr(f, name) is not None], float)

    @property
    def has_truth(self) -> bool:
        return any(f.ospa is not None for f in self.frames)

    @property
    def mean_ospa(self) -> float | None:
        v = self._truth_values("ospa")
        return float(v.mean()) if v.size else None

    @property
    def mean_cardinality_error(self) -> float | None:
        v = self._truth_values("cardinality_error")
        return float(v.mean()) if v.size else None

    @property
    def ms(self) -> np.ndarray:
        return np.array([f.ms for f in self.frames if math.isfinite(f.ms)], float)

    @property
    def ms_median(self) -> float | None:
        v = self.ms
        return float(np.median(v)) if v.size else None

    @property
    def ms_p95(self) -> float | None:
        v = self.ms
        return float(np.percentile(v, 95)) if v.size else None


def frame_metrics(frame: Frame, est: Estimate, c: float = OSPA_C, p: float = OSPA_P) -> FrameMetrics:
    """OSPA (on position) and cardinality error of one estimate against the frame's truth."""
    from sinks.metrics import cardinality_error, ospa

    ms = float(est.diagnostics.get("ms", float("nan")))
    base = dict(frame=frame.frame, n_measurements=frame.n_measurements, n_tracks=len(est.tracks), ms=ms)
    if frame.truth is None:
        return FrameMetrics(**base)
    o = ospa(frame.truth.positions, est.positions, c=c, p=p)
    n_true = len(frame.truth.ids)
    return FrameMetrics(
        **base,
        n_true=n_true,
        ospa=o.total,
        ospa_localisation=o.localisation,
        ospa_cardinality=o.cardinality,
        cardinality_error=cardinality_error(len(est.tracks), n_true),
    )


def track_frames(
    tracker: Tracker,
    frames: Iterable[Frame],
    seed: int,
    on_estimate: Callable[[Frame, Estimate, FrameMetrics], None] | None = None,
    crossings: Sequence[tuple[str, str, int]] = (),
    bounds: FrameBounds | None = None,
) -> TrackResult:
    """Run ``tracker`` over ``frames`` (``tracker.state.run``), scoring every frame.

    ``on_estimate(frame, estimate, metrics)`` is called after each frame is scored (e.g. to
    write it; a recording reuses ``metrics``' OSPA instead of computing it again).  If the
    frame source raises :class:`McapLogError` (a damaged log), or a frame breaks ``bounds``
    (default :class:`FrameBounds`: at most 1000 frames and 3600 s after the previous one;
    checked before the frame reaches the tracker), the frames before it are kept and the
    error is returned in :attr:`TrackResult.error` instead of being raised.
    ``crossings`` (``(id_a, id_b, scan)``, e.g. a ``random`` log's record) are scored with
    :func:`sinks.metrics.crossing_label_keeping` into :attr:`TrackResult.crossings`.
    """
    rows: list[FrameMetrics] = []
    final = 0
    error: McapLogError | FrameBoundError | None = None
    seen: list[tuple[Frame, Estimate]] = []
    health = RunHealth(getattr(tracker, "params", None))
    try:
        for frame, est, _state in run(tracker, bounded_frames(frames, bounds or FrameBounds()), seed):
            health.add(frame)
            row = frame_metrics(frame, est)
            if on_estimate is not None:
                on_estimate(frame, est, row)
            rows.append(row)
            final = len(est.tracks)
            if crossings:
                seen.append((frame, est))
    except (McapLogError, FrameBoundError) as exc:
        error = exc
    return TrackResult(tracker.name, tuple(rows), final, error, score_crossings(seen, crossings),
                       health.warnings(final))


#: A sensor's measurements are "mostly" outside its field of view above this fraction.
OUTSIDE_FOV_WARN = 0.5


@dataclass
class RunHealth:
    """Counts that tell a run that cannot work (issue 13, item 6): per sensor, the
    measurements outside the sensor's field of view (where the model says only nothing can
    be: the clutter density is 0 there), and the frames with measurements."""

    params: Any
    total: dict[str, int] = field(default_factory=dict)
    outside: dict[str, int] = field(default_factory=dict)
    sensors: dict[str, Any] = field(default_factory=dict)
    nonempty: int = 0

    def add(self, frame: Frame) -> None:
        if frame.n_measurements == 0:
            return
        self.nonempty += 1
        if not isinstance(self.params, ModelParams):
            return
        s = self.params.frame_sensor(frame)
        out = int(np.sum(~np.isfinite(self.params.clutter(frame.kind, s).logpdf(frame.z))))
        self.total[frame.sensor] = self.total.get(frame.sensor, 0) + frame.n_measurements
        self.outside[frame.sensor] = self.outside.get(frame.sensor, 0) + out
        self.sensors[frame.sensor] = s

    def warnings(self, final_tracks: int) -> tuple[str, ...]:
        out = []
        for name, n in self.total.items():
            frac = self.outside[name] / n
            if n >= 10 and frac > OUTSIDE_FOV_WARN:
                s = self.sensors[name]
                out.append(
                    f"{100 * frac:.0f}% of the {n} measurements of sensor {name!r} ({s.kind}) fall outside "
                    f"its field of view (at ({s.x:g}, {s.y:g}) m, heading {np.rad2deg(s.heading):g} deg, "
                    f"+-{np.rad2deg(s.half_fov):g} deg, range {s.range_min:g}-{s.range_max:g} m), so the "
                    f"trackers treat them as impossible. Check the sensor pose (a [sensors.{name}] table "
                    f"in --params FILE.toml, or per-frame 'pose'), its field of view (half_fov_deg, "
                    f"range_max) and the kind (docs/models.md, 'Sensors').")
        if final_tracks == 0 and self.nonempty >= 5:
            out.append(
                f"the run ended with 0 tracks from {self.nonempty} frames with measurements. Likely "
                f"causes: the sensor pose or field of view (the default sensor sits at the origin "
                f"facing +y; declare yours in a [sensors.NAME] table or send 'pose'), parameters "
                f"that do not match the data (p_detect, clutter_rate, sigma_*: --params FILE.toml "
                f"or --set KEY=VALUE), or no births (birth_rate = 0 without birth regions).")
        return tuple(out)


def score_crossings(
    seen: Sequence[tuple[Frame, Estimate]], crossings: Sequence[tuple[str, str, int]]
) -> CrossingResult | None:
    """Label keeping through ``crossings`` over consecutive frames with truth; pairs whose
    crossing scan is not among the frames are left out (``None`` when none is left)."""
    from sinks.metrics import crossing_label_keeping

    if not seen or any(f.truth is None for f, _ in seen):
        return None
    scans = [f.frame for f, _ in seen]
    if scans != list(range(scans[0], scans[0] + len(scans))):
        return None
    pairs = [c for c in crossings if scans[0] <= int(c[2]) <= scans[-1]]
    if not pairs:
        return None
    true = [dict(zip(f.truth.ids, f.truth.positions)) for f, _ in seen]
    est = [{t.label: t.position for t in e.tracks} for _, e in seen]
    return crossing_label_keeping(true, est, pairs, first_scan=scans[0])


def default_tracks_path(log: str | os.PathLike, tracker: str) -> Path:
    """``<LOG stem>-<tracker>.tracks.mcap`` next to the log."""
    log = Path(log)
    return log.with_name(f"{log.stem}-{tracker}.tracks.mcap")


def check_output_path(log: str | os.PathLike, out: str | os.PathLike) -> None:
    """Refuse an output path that is the input log itself."""
    if Path(out).resolve() == Path(log).resolve():
        raise ConfigError(f"--out {out}: the output would overwrite the input log {log}")


def track_log(
    log: str | os.PathLike,
    out: str | os.PathLike,
    tracker: Tracker,
    seed: int,
    metadata: Mapping[str, str] | None,
    on_estimate: Callable[[Frame, Estimate, FrameMetrics], None] | None = None,
    bounds: FrameBounds | None = None,
    topic_map: Mapping[str, str] | None = None,
) -> TrackResult:
    """Track the frames of an MCAP log and write ``out``: the input frames (with truth) and
    ``/tracks``, with ``metadata`` as its ``bnptrack.scenario`` record.  ``on_estimate`` is
    called after each frame is written (e.g. a Rerun sink).  The record's ``crossings``
    (a generated ``random`` scene) are scored (:attr:`TrackResult.crossings`).

    A damaged input is processed up to its readable end (a frame beyond ``bounds`` ends it
    too); the output then holds that prefix and :attr:`TrackResult.error` holds the error.
    """
    log, out = Path(log), Path(out)
    check_output_path(log, out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with McapLogWriter(out, dict(metadata) if metadata is not None else None) as writer:

        def write(frame: Frame, est: Estimate, metrics: FrameMetrics) -> None:
            writer.write_frame(frame)
            writer.write_tracks(est)
            if on_estimate is not None:
                on_estimate(frame, est, metrics)

        crossings = parse_crossings((metadata or {}).get("crossings"))
        return track_frames(tracker, iter_frames(log, dict(topic_map or {})), seed, write, crossings, bounds)

