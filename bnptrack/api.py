"""The Python API: simulate a scene, read or write a log, build and run a tracker.

Each function is a thin layer over the library the command line uses (the same resolution of
parameter sets, presets and ``--set`` items, the same seeds), so a notebook and ``bnptrack
track`` give the same tracks for the same inputs.  Errors in what the caller passes raise
:class:`bnptrack.tracker.config.ConfigError` (a ``ValueError``) with a one-line message.
Walk-through: docs/python.md.
"""

from __future__ import annotations

import os
from numbers import Integral
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from bnptrack.pipeline.offline import TrackResult, read_log_start, track_frames
from bnptrack.pipeline.resolve import tracker_setup
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.mcap_log import LogContents, iter_frames, read_metadata
from bnptrack.sources.mcap_log import read_log as _read_log
from bnptrack.sources.scenarios import open_scenario, scenario_names
from bnptrack.sources.synthetic import simulate as _simulate_frames
from bnptrack.sources.synthetic import simulate_sensors
from bnptrack.tracker.config import PYTHON_NAMES, ConfigError, did_you_mean
from bnptrack.tracker.input_checks import SCAN_FRAMES, check_frames
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.models.params import load_params as _load_params
from bnptrack.tracker.registry import Tracker
from bnptrack.tracker.types import Estimate, Frame

__all__ = ["simulate", "track", "make_tracker", "load_params", "read_log", "write_log", "TrackRun", "LogContents"]

PathLike = str | os.PathLike


def simulate(
    scenario: str = "vo2017", seed: int = 1, *, params: str = "vo2017", overrides: Sequence[str] = (),
    out: PathLike | None = None, overwrite: bool = False,
) -> list[Frame]:
    """The frames of scenario ``scenario`` simulated with ``seed`` (as ``bnptrack simulate``).

    ``params`` is a built-in parameter set or a TOML file; ``overrides`` are ``--set`` items
    (``"p_detect=0.9"``, ``"scene.n_objects=12"``).  With ``out``, the frames are also written
    to that MCAP log with its scenario record, ready for ``bnptrack track`` or ``replay``
    (an existing file is replaced only with ``overwrite=True``).
    Frames do not carry their parameter set: pass the same ``params`` (and ``scenario``) to
    :func:`track`, or track the log written with ``out``, whose record names them.
    """
    _check_scenario("simulate", scenario)
    _check_count("simulate", "seed", seed)
    _check_items("simulate", "overrides", overrides)
    if out is not None:
        _refuse_existing("simulate(out=...)", out, overwrite)
    opened = open_scenario(scenario, params, seed, tuple(overrides), names=PYTHON_NAMES)
    sc, p = opened.scenario, opened.params
    frames = list(simulate_sensors(sc, p, seed, list(p.sensors)) if p.sensors else _simulate_frames(sc, p, seed))
    if out is not None:
        write_log(out, frames, opened.metadata, overwrite=overwrite)
    return frames


def write_log(path: PathLike, frames: Iterable[Frame], metadata: dict[str, str] | None = None, *,
              overwrite: bool = False) -> Path:
    """Write ``frames`` (measurements, and truth where a frame has it) to an MCAP log.  An
    existing file is replaced only with ``overwrite=True`` (as the command line's ``--overwrite``)."""
    _refuse_existing("write_log", path, overwrite)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with McapLogWriter(path, dict(metadata or {})) as writer:
        for frame in frames:
            writer.write_frame(frame)
    return path


def make_tracker(
    name: str = "ddp", *, params: str | ModelParams | None = "vo2017", overrides: Sequence[str] = (),
    config: str | None = None, scenario: str | None = None,
) -> Tracker:
    """Tracker ``name`` (``ddp``, ``dpyp``, ``ddp-mb``, ``dpyp-mb``, ``glmb``) built as ``bnptrack
    track`` builds it: parameter set ``params`` (a name, a TOML file or a :class:`ModelParams`),
    settings preset or TOML ``config`` (default: the preset named like the tracker), then the
    ``--set`` items ``overrides``.  ``scenario`` adds that scenario's prior knowledge (its birth
    regions), as a log's record does; without it new objects are expected anywhere in the
    field of view.  Run it with ``state = tracker.initial_state()`` and
    ``state, estimate = tracker.step(state, frame, rng)``, or with :func:`track`."""
    _check_scenario("make_tracker", scenario)
    _check_items("make_tracker", "overrides", overrides)
    meta = {"scenario": scenario} if scenario else None
    return tracker_setup(name, params=params, config=config, overrides=tuple(overrides), metadata=meta,
                         names=PYTHON_NAMES).tracker


def load_params(source: str | os.PathLike = "vo2017", overrides: Sequence[str] = ()) -> ModelParams:
    """Parameter set ``source`` (a built-in name or a TOML file; docs/models.md) with the
    ``--set`` items ``overrides`` (``["clutter_rate=20"]``) applied."""
    _check_items("load_params", "overrides", overrides)
    return _load_params(source, tuple(overrides), names=PYTHON_NAMES)


def read_log(path: PathLike, strict: bool = True) -> LogContents:
    """Read a whole log (metadata, frames with truth, tracks) in one pass.

    A truncated or damaged file raises :class:`bnptrack.sources.log_errors.McapLogError`; with
    ``strict=False`` it returns what was readable, with the error in ``.error``.  A missing
    path is a :class:`ConfigError` (``no such file``)."""
    _check_log_path("read_log", path)
    return _read_log(path, strict)


@dataclass(frozen=True)
class TrackRun:
    """What :func:`track` returns: one estimate per frame, plus the run's scores."""

    estimates: list[Estimate] = field(repr=False)
    result: TrackResult = field(repr=False)
    online: list[Estimate] = field(default_factory=list, repr=False)
    """With ``lag`` > 0: the online estimates the lagged ones were re-decided from (else empty)."""
    input_warnings: tuple[str, ...] = ()
    """The warnings about the inputs raised before tracking (:func:`tracker.input_checks.check_frames`)."""

    @property
    def mean_ospa(self) -> float | None:
        """Mean OSPA (p = 1, c = 100 m) over the frames with truth; ``None`` without truth."""
        return self.result.mean_ospa

    @property
    def mean_cardinality_error(self) -> float | None:
        return self.result.mean_cardinality_error

    @property
    def warnings(self) -> tuple[str, ...]:
        """Why the run probably gives a wrong result: the inputs' warnings raised before
        tracking (stamps in another unit, a sensor with no pose), then the run's own (e.g.
        measurements outside the field of view); each was also raised with ``warnings.warn``
        (:class:`bnptrack.tracker.input_checks.InputWarning`)."""
        return self.input_warnings + self.result.warnings


def track(
    frames: PathLike | Iterable[Frame], tracker: str = "ddp", *, params: str | ModelParams | None = None,
    overrides: Sequence[str] = (), config: str | None = None, seed: int = 0, scenario: str | None = None,
    topics: Sequence[str] = (), lag: int = 0,
) -> TrackRun:
    """Run tracker ``tracker`` over ``frames`` (a list of :class:`Frame` or an MCAP log's path)
    with tracker seed ``seed``, scoring each frame that carries truth.

    Parameters as :func:`make_tracker`; for a log, ``params=None`` takes the set named in the
    log's scenario record (as ``bnptrack track`` does), for frames it means ``vo2017``.
    ``scenario`` (for frames; a log's record names its own) adds that scenario's birth regions.
    ``topics`` (for a log) are ``--topic`` items: ``["/radar/scan"]`` reads a ROS 2 / Foxglove
    channel (several: several sensors), ``["/radar/detections=/measurements"]`` maps a
    bnptrack JSON channel.
    ``lag`` > 0 gives the fixed-lag output (as ``bnptrack track --lag``; docs/trackers.md,
    "Fixed-lag output"), with the online estimates in :attr:`TrackRun.online`.
    """
    _check_count("track", "lag", lag, " (scans)")
    lag = int(lag)
    is_log = isinstance(frames, (str, os.PathLike))
    if is_log and scenario:
        raise ConfigError(f"track({os.fspath(frames)!r}, scenario={scenario!r}): a log's own record names its "
                          "scenario; scenario= is for a list of frames")
    _check_scenario("track", scenario)
    _check_count("track", "seed", seed)
    _check_items("track", "overrides", overrides)
    _check_items("track", "topics", topics)
    if is_log:
        _check_log_path("track", frames)
    else:
        frames = _frames_arg(frames)
    metadata = read_metadata(frames) if is_log else ({"scenario": scenario} if scenario else None)
    if params is None and not is_log:
        params = "vo2017"
    setup = tracker_setup(tracker, params=params, config=config, overrides=tuple(overrides), names=PYTHON_NAMES,
                          metadata=metadata, seed=seed)
    if topics and not is_log:
        raise ConfigError("track(frames, topics=...): topics choose the channels of a log; frames have none")
    mapping = _topic_map(Path(frames), topics) if is_log else None
    noted = check_frames(setup.params, read_log_start(frames, mapping) if is_log else
                         list(frames[:SCAN_FRAMES]) if isinstance(frames, Sequence) else [],
                         None if isinstance(params, ModelParams) else setup.choice.source, setup.set_sensors,
                         "overrides item")
    source = iter_frames(Path(frames), mapping) if is_log else frames
    estimates: list[Estimate] = []
    online: list[Estimate] = []
    result = track_frames(setup.tracker, source, seed, lambda _f, est, _m: estimates.append(est), lag=lag,
                          on_online=lambda _f, est: online.append(est))
    run = TrackRun(estimates, result, online, noted)
    if result.error is not None:
        result.error.run = run  # the readable prefix, as `bnptrack track` writes it before exit 2
        raise result.error
    return run


def _topic_map(log: Path, topics: Sequence[str]) -> dict[str, str]:
    """``topics`` as the channel mapping of :func:`sources.mcap_log.iter_frames`, checked
    against the log (a channel bnptrack cannot read, or no channel read as ``/measurements``,
    is a :class:`ConfigError`)."""
    from bnptrack.pipeline.config import parse_topic_item
    from bnptrack.sources.channels import channel_list
    from bnptrack.sources.mcap_log import missing_measurements_message
    from bnptrack.tracker.messages import TOPIC_MEASUREMENTS
    from bnptrack.sources.robot_log import robot_topics

    try:
        mapping = dict(parse_topic_item(t) for t in topics)
        robot_topics(log, mapping, channels := channel_list(log))
    except ValueError as exc:
        raise ConfigError(f"track(topics=...): {exc}") from None
    if not any(mapping.get(c.topic, c.topic) == TOPIC_MEASUREMENTS for c in channels):
        raise ConfigError(f"track({os.fspath(log)!r}): {missing_measurements_message(log, channels, 'topics=[{!r}]')}")
    return mapping


def _check_scenario(function: str, scenario: str | None) -> None:
    """An unknown ``scenario`` is a :class:`ConfigError` naming the argument (the command line
    only warns about an unknown name in a log's record: the log may come from another version)."""
    if scenario is None:
        return
    known = scenario_names()
    if not isinstance(scenario, str):
        raise ConfigError(f"{function}(scenario={scenario!r}): expected a scenario name (a str), "
                          f"got {type(scenario).__name__}")
    if scenario not in known:
        raise ConfigError(f"{function}(scenario={scenario!r}): unknown scenario{did_you_mean(scenario, known)}; "
                          f"valid scenarios: {', '.join(known)}")


def _check_log_path(function: str, path: PathLike) -> None:
    """A log path that is not a file is a :class:`ConfigError` naming it (not a damaged log)."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{function}({os.fspath(path)!r}): {p} is a folder, not a log")
    if not p.exists():
        raise ConfigError(f"{function}({os.fspath(path)!r}): no such file: {p}")


def _refuse_existing(call: str, path: PathLike, overwrite: bool) -> None:
    """An output path that is a folder, or an existing file without ``overwrite``, is a
    :class:`ConfigError` naming the call."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{call}: {p} is a folder; give a file path")
    if p.exists() and not overwrite:
        raise ConfigError(f"{call}: {p} exists: pass overwrite=True to replace it, or another path")


#: What each sequence-of-str argument holds, for its error.
_ITEMS = {"overrides": "'key=value' strings", "topics": "channel names ('/radar/scan' or 'SRC=/measurements')"}


def _check_items(call: str, arg: str, value: object) -> None:
    """``value`` is a list (any sequence) of str; a bare str, whose characters would be read
    as items, is a :class:`ConfigError` naming the argument."""
    if isinstance(value, (str, bytes)):
        raise ConfigError(f"{call}({arg}={value!r}): expected a list of {_ITEMS[arg]}, got a str "
                          f"(write [{value!r}])")
    if not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{call}({arg}={value!r}): expected a list of {_ITEMS[arg]}")


def _frames_arg(frames: object) -> Iterable[Frame]:
    """``track``'s ``frames`` when not a log's path: a list (checked whole) or an iterable
    (checked item by item as it is read) of :class:`Frame`, else a :class:`ConfigError`."""
    if isinstance(frames, LogContents):
        raise ConfigError("track(frames=<LogContents>): give its .frames, or the log's path")
    if isinstance(frames, (bytes, Frame)) or not isinstance(frames, Iterable):
        raise ConfigError(f"track(frames={frames!r:.60}): expected a log's path or a list of bnptrack Frames "
                          f"(bnptrack.simulate gives one), got {type(frames).__name__}")
    if isinstance(frames, Sequence):
        bad = next((i for i, f in enumerate(frames) if not isinstance(f, Frame)), None)
        if bad is not None:
            raise ConfigError(_not_a_frame(bad, frames[bad]))
        return frames
    return _each_frame(frames)


def _each_frame(frames: Iterable[object]) -> Iterable[Frame]:
    for i, f in enumerate(frames):
        if not isinstance(f, Frame):
            raise ConfigError(_not_a_frame(i, f))
        yield f


def _not_a_frame(i: int, item: object) -> str:
    return (f"track(frames): item {i} ({item!r:.40}, type {type(item).__name__}) is not a bnptrack Frame "
            "(bnptrack.simulate and bnptrack.read_log(...).frames give Frames)")


def _check_count(call: str, name: str, value: object, unit: str = "") -> None:
    """A seed or a lag is an integer >= 0 (a numpy integer too; not a bool or a float)."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < 0:
        raise ConfigError(f"{call}({name}={value!r}): {name} must be an integer >= 0{unit}")
