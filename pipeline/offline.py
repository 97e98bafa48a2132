"""Offline runs of the ``bnptrack`` commands: simulate a scenario into a log
(:func:`simulate_to_log`) and track a log with per-frame scores (:func:`track_log`).

What a run uses (parameters, settings, the tracker) is resolved by :mod:`pipeline.resolve`,
the scenario by :func:`sources.scenarios.open_scenario`; frames are scored by
:class:`sinks.run_scorer.RunScorer`, as the pipeline's sink and the experiments score them.
The tracker and the metrics (which pull in scipy) are imported where they are used, so
``bnptrack --help`` stays quick.
"""

from __future__ import annotations

import math
import os
import statistics
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bnptrack.sinks.crossings import CrossingResult
from bnptrack.sinks.metrics import OSPA_C, OSPA_P, OspaResult
from bnptrack.sinks.run_scorer import RunScorer
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sinks.sink import SinkSet, make_sink
from bnptrack.sinks.records import Sink, SinkOptions, SinkRecord
from bnptrack.pipeline.output_paths import check_output_path
from bnptrack.pipeline.stop_request import StopOnSignal
from bnptrack.sources.frame_window import FrameWindow
from bnptrack.sources.mcap_log import McapLogError, first_frames, iter_frames
from bnptrack.sources.scenarios import OpenScenario, parse_crossings
from bnptrack.sources.synthetic import simulate, simulate_sensors
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.input_checks import SCAN_FRAMES, warn
from bnptrack.tracker.messages import MSG_TYPES, TOPIC_MEASUREMENTS
from bnptrack.tracker.models.measurement import measurement_kind
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.lag import FixedLag, run_lagged
from bnptrack.tracker.state import run
from bnptrack.tracker.types import Estimate, Frame, FrameBoundError, FrameBounds, FrameGate, gated_segments

if TYPE_CHECKING:
    from bnptrack.tracker.registry import Tracker

__all__ = [
    "OSPA_C",
    "OSPA_P",
    "SimulationResult",
    "FrameMetrics",
    "TrackResult",
    "RunHealth",
    "read_log_start",
    "simulate_to_log",
    "frame_metrics",
    "track_frames",
    "score_crossings",
    "track_log",
    "track_to_sinks",
    "open_sinks",
    "default_tracks_path",
]


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


def simulate_to_log(opened: OpenScenario, seed: int, out: str | os.PathLike) -> SimulationResult:
    """Simulate an opened scenario (:func:`sources.scenarios.open_scenario`: its scene and
    final parameters) with ``seed`` and write an MCAP log with its record.  The log is written
    beside ``out`` under a temporary name and renamed at the end: a failure leaves no partial
    log (and an existing ``out`` as it was)."""
    sc, params = opened.scenario, opened.params
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    n_frames = n_meas = n_targets = 0
    # a parameter set that declares sensors ([sensors.NAME]) is simulated with all of them:
    # one frame per sensor per scan, interleaved (sources.synthetic.simulate_sensors)
    frames = simulate_sensors(sc, params, seed, list(params.sensors)) if params.sensors else simulate(sc, params, seed)
    part = out.with_name(f".{out.name}.part")
    try:
        with McapLogWriter(part, dict(opened.metadata)) as writer:
            for frame in frames:
                writer.write_frame(frame)
                n_frames += 1
                n_meas += frame.n_measurements
                n_targets += len(frame.truth.ids) if frame.truth is not None else 0
        os.replace(part, out)
    finally:
        part.unlink(missing_ok=True)
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
    ospa2: float | None = None
    """OSPA(2) over the window ending at this frame (:class:`sinks.run_scorer.RunScorer`)."""

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
    final_names: tuple[str, ...] = ()
    """Display names (:func:`tracker.types.display_name`) of the last frame's tracks."""
    skipped: tuple[tuple[int, str], ...] = ()
    """Frames beyond the bounds, skipped (:class:`tracker.types.FrameGate`): (frame, why)."""
    labels: int | None = None
    """How many distinct labels the run reported in all."""

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
    def mean_ospa2(self) -> float | None:
        """The mean of the frames' OSPA(2) (each over the window ending at the frame)."""
        v = self._truth_values("ospa2")
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
        """The median (``statistics.median``: the same double as ``np.median``, which imports
        ``numpy.ma``, 0.05-0.1 s, for its NaN check; the times here are finite)."""
        v = self.ms
        return float(statistics.median(v.tolist())) if v.size else None


def frame_metrics(frame: Frame, est: Estimate, c: float = OSPA_C, p: float = OSPA_P,
                  scorer: RunScorer | None = None) -> FrameMetrics:
    """OSPA (on position) and cardinality error of one estimate against the frame's truth,
    scored by ``scorer`` (a run's :class:`sinks.run_scorer.RunScorer`, which then also gives
    the frame's OSPA(2); default: a scorer of this frame alone, cut-off ``c``, order ``p``)."""
    from bnptrack.sinks.metrics import cardinality_error

    if scorer is None:
        scorer = RunScorer(c=c, p=p, window=1)
    ms = float(est.diagnostics.get("ms", float("nan")))
    base = dict(frame=frame.frame, n_measurements=frame.n_measurements, n_tracks=len(est.tracks), ms=ms)
    scores = scorer.update(frame, est)
    if frame.truth is None:
        return FrameMetrics(**base)
    o = scores["ospa"]
    n_true = len(frame.truth.ids)
    return FrameMetrics(
        **base,
        n_true=n_true,
        ospa=o.total,
        ospa_localisation=o.localisation,
        ospa_cardinality=o.cardinality,
        cardinality_error=cardinality_error(len(est.tracks), n_true),
        ospa2=scores["ospa2"],
    )


def track_frames(
    tracker: Tracker,
    frames: Iterable[Frame],
    seed: int,
    on_estimate: Callable[[Frame, Estimate, FrameMetrics], None] | None = None,
    crossings: Sequence[tuple[str, str, int]] = (),
    bounds: FrameBounds | None = None,
    lag: int = 0,
    on_online: Callable[[Frame, Estimate], None] | None = None,
) -> TrackResult:
    """Run ``tracker`` over ``frames`` (``tracker.state.run``), scoring every frame.

    With ``lag`` > 0 the estimates scored and passed on are the fixed-lag output
    (:mod:`tracker.lag`: frame ``k - lag`` published when frame ``k`` arrives, the last
    ``lag`` frames at the end), and ``on_online(frame, estimate)`` sees each online estimate.

    ``on_estimate(frame, estimate, metrics)`` is called after each frame is scored (e.g. to
    write it; a recording reuses ``metrics``' OSPA instead of computing it again).  If the
    frame source raises :class:`McapLogError` (a damaged log), the frames before it are kept
    and the error is returned in :attr:`TrackResult.error` instead of being raised.  A frame
    beyond ``bounds`` (default :class:`FrameBounds`: at most 1000 frames and 3600 s after the
    previous one) is skipped before it reaches the tracker, by the rule of
    :class:`tracker.types.FrameGate` that the pipeline's stages follow, and listed in
    :attr:`TrackResult.skipped`.
    ``crossings`` (``(id_a, id_b, scan)``, e.g. a ``random`` log's record) are scored with
    :func:`sinks.metrics.crossing_label_keeping` into :attr:`TrackResult.crossings`.
    """
    rows: list[FrameMetrics] = []
    final, names = 0, ()
    error: McapLogError | FrameBoundError | None = None
    seen: list[tuple[Frame, Estimate]] = []
    health = RunHealth(getattr(tracker, "params", None))
    scorer = RunScorer()
    skipped: list[tuple[int, str]] = []
    labels: set[str] = set()
    segments = gated_segments(frames, FrameGate(bounds or FrameBounds()), skipped)
    try:
        for frame, est, _state in (x for seg in segments for x in _estimates(tracker, seg, seed, lag, on_online)):
            health.add(frame)
            row = frame_metrics(frame, est, scorer=scorer)
            if on_estimate is not None:
                on_estimate(frame, est, row)
            rows.append(row)
            final, names = len(est.tracks), tuple(t.name for t in est.tracks)
            labels.update(est.labels)
            if crossings:
                seen.append((frame, est))
    except (McapLogError, FrameBoundError) as exc:
        error = exc
    notes = health.warnings(final)
    for note in notes:
        warn(note)
    return TrackResult(tracker.name, tuple(rows), final, error, score_crossings(seen, crossings), notes, names,
                       tuple(skipped), len(labels))


def _estimates(tracker: Tracker, frames: Iterable[Frame], seed: int, lag: int,
               on_online: Callable[[Frame, Estimate], None] | None):
    """The online run (``lag`` 0) or the fixed-lag run of ``tracker`` over ``frames``."""
    if lag <= 0:
        return run(tracker, frames, seed)
    return run_lagged(FixedLag(tracker, tracker.params, lag), frames, seed, on_online)


def read_log_start(log: str | os.PathLike, topics: Mapping[str, str] | None) -> list[Frame]:
    """The first frames of ``log`` (:data:`tracker.input_checks.SCAN_FRAMES`), read while a
    command checks its options (``track``; ``launch`` / ``replay`` in their checks), for
    :func:`tracker.input_checks.check_frames`.  A first ``/measurements`` message that does
    not decode, under its own name or mapped there with ``--topic``, is a
    :class:`ConfigError`: nothing has been started or written yet."""
    mapped = [src for src, dst in (topics or {}).items() if dst == TOPIC_MEASUREMENTS]
    try:
        return first_frames(log, dict(topics or {}) or None, SCAN_FRAMES)
    except McapLogError as exc:
        if mapped and mapped[0] in MSG_TYPES:  # another bnptrack channel: /tracks, /truth
            raise ConfigError(f"{log}: channel {mapped[0]} holds bnptrack {mapped[0]} messages, not measurements: "
                              f"--topic {mapped[0]}=/measurements cannot be tracked") from None
        what = f"channel {mapped[0]} (--topic {mapped[0]}=/measurements)" if mapped else "its /measurements"
        raise ConfigError(f"{log}: {what} does not decode as bnptrack measurements (`bnptrack schema "
                          f"/measurements` gives the contract): {exc.reason}") from None


#: A sensor's measurements are "mostly" outside its field of view above this fraction.
OUTSIDE_FOV_WARN = 0.5


@dataclass
class RunHealth:
    """Counts that tell a run that cannot work: per sensor, the
    measurements outside the sensor's field of view (where the model says only nothing can
    be: the clutter density is 0 there), the sum of their bearings' unit vectors (a boresight
    to suggest), whether any of its frames had a pose, and the frames with measurements."""

    params: Any
    total: dict[str, int] = field(default_factory=dict)
    outside: dict[str, int] = field(default_factory=dict)
    sensors: dict[str, Any] = field(default_factory=dict)
    posed: set[str] = field(default_factory=set)
    bearings: dict[str, complex] = field(default_factory=dict)
    nonempty: int = 0

    def add(self, frame: Frame) -> None:
        if frame.n_measurements == 0:
            return
        self.nonempty += 1
        if not isinstance(self.params, ModelParams):
            return
        s = self.params.frame_sensor(frame)
        lost = ~np.isfinite(self.params.clutter(frame.kind, s).logpdf(frame.z))
        self.total[frame.sensor] = self.total.get(frame.sensor, 0) + frame.n_measurements
        self.outside[frame.sensor] = self.outside.get(frame.sensor, 0) + int(np.sum(lost))
        self.sensors[frame.sensor] = s
        if frame.pose is not None:
            self.posed.add(frame.sensor)
        if 0 in measurement_kind(frame.kind).wrapped:  # a bearing column: where the sensor looks
            b = frame.z[lost, 0] + s.heading
            self.bearings[frame.sensor] = self.bearings.get(frame.sensor, 0j) + complex(
                float(np.sum(np.sin(b))), float(np.sum(np.cos(b))))

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
                    f"trackers treat them as impossible. " + self._fix(name))
        if final_tracks == 0 and self.nonempty >= 5:
            out.append(
                f"the run ended with 0 tracks from {self.nonempty} frames with measurements. Likely "
                f"causes: the sensor pose or field of view (the default sensor sits at the origin "
                f"facing +y; declare yours in a [sensors.NAME] table or send 'pose'), parameters "
                f"that do not match the data (p_detect, clutter_rate, sigma_*: --params FILE.toml "
                f"or --set KEY=VALUE), or no births (birth_rate = 0 without birth regions).")
        return tuple(out)

    def _fix(self, name: str) -> str:
        """What to do about sensor ``name``'s measurements outside its field of view: without
        any pose (no table, no per-frame pose), the ``[sensors.NAME]`` table to add."""
        declared = name in getattr(self.params, "sensors", {})
        if declared or name in self.posed:
            return (f"Check the sensor pose (a [sensors.{name}] table in --params FILE.toml, or "
                    f"per-frame 'pose'), its field of view (half_fov_deg, range_max) and the kind "
                    f"(docs/models.md, 'Sensors').")
        v = self.bearings.get(name)
        heading = f"{np.degrees(np.arctan2(v.real, v.imag)):.0f}" if v else "<boresight, deg from +y>"
        return (f"The sensor has no pose: add to --params FILE.toml the table "
                f"[sensors.{name}] x = <m> y = <m> heading_deg = {heading} (its position and "
                f"boresight; the measurements point to heading_deg = {heading}), or send a "
                f"per-frame 'pose' (docs/models.md, 'Sensors').")


def score_crossings(
    seen: Sequence[tuple[Frame, Estimate]], crossings: Sequence[tuple[str, str, int]]
) -> CrossingResult | None:
    """Label keeping through ``crossings`` over consecutive frames with truth; pairs whose
    crossing scan is not among the frames are left out (``None`` when none is left)."""
    from bnptrack.sinks.crossings import crossing_label_keeping

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


def open_sinks(outputs: Mapping[str, Path], options: SinkOptions) -> SinkSet:
    """The sinks of :data:`sinks.sink.SINKS` named by ``outputs`` (name -> file; see
    :func:`pipeline.config.sink_outputs`), each built with ``options`` for its file (not
    opened yet: a sink may start work at once, e.g. the Rerun sink's child process)."""
    built: list[Sink] = []
    try:
        for name, path in outputs.items():
            built.append(make_sink(name, replace(options, path=Path(path))))
    except BaseException:
        SinkSet(built).close()
        raise
    return SinkSet(built)


def track_to_sinks(
    log: str | os.PathLike,
    sinks: SinkSet,
    tracker: Tracker,
    seed: int,
    metadata: Mapping[str, str] | None,
    bounds: FrameBounds | None = None,
    topic_map: Mapping[str, str] | None = None,
    window: FrameWindow | None = None,
    lag: int = 0,
    stop: StopOnSignal | None = None,
) -> TrackResult:
    """Track the frames of an MCAP log (those of ``window``; default: all; with ``lag`` > 0
    the fixed-lag output of :mod:`tracker.lag`) and record each frame,
    its estimate and its scores (:class:`sinks.run_scorer.RunScorer`, as :attr:`TrackResult.frames`
    holds them) to ``sinks``,
    opened with ``metadata`` and closed here (the files are complete when this returns).
    The record's ``crossings`` (a generated ``random`` scene) are scored
    (:attr:`TrackResult.crossings`).

    A damaged input is processed up to its readable end (a frame beyond ``bounds`` ends it
    too); the outputs then hold that prefix and :attr:`TrackResult.error` holds the error.
    A signal held by ``stop`` ends the input at the next frame, as if the log ended there.
    """

    online: dict[int, Estimate] = {}

    def write(frame: Frame, est: Estimate, metrics: FrameMetrics) -> None:
        sinks.write(SinkRecord(frame, est, {"ospa": metrics.ospa_result, "ospa2": metrics.ospa2},
                               online=online.pop(frame.frame, None)))

    with sinks:
        sinks.open(metadata)
        crossings = parse_crossings((metadata or {}).get("crossings"))
        frames = iter_frames(Path(log), dict(topic_map or {}))
        if window is not None:
            frames = window.cut(frames)
        if stop is not None:
            frames = stop.until_stopped(frames)
        return track_frames(tracker, frames, seed, write, crossings, bounds, lag,
                            lambda frame, est: online.__setitem__(frame.frame, est))


def track_log(
    log: str | os.PathLike,
    out: str | os.PathLike,
    tracker: Tracker,
    seed: int,
    metadata: Mapping[str, str] | None,
    bounds: FrameBounds | None = None,
    topic_map: Mapping[str, str] | None = None,
) -> TrackResult:
    """Track the frames of an MCAP log and write ``out``: the input frames (with truth) and
    ``/tracks``, with ``metadata`` as its ``bnptrack.scenario`` record (the ``mcap`` sink of
    :func:`track_to_sinks`)."""
    check_output_path(log, out)
    return track_to_sinks(log, open_sinks({"mcap": Path(out)}, SinkOptions(Path(out))), tracker, seed,
                          metadata, bounds, topic_map)
