"""Rerun (``.rrd``) recordings of a tracking run, to inspect it offline in the Rerun viewer.

:class:`RerunSink` writes one frame at a time (``log(frame, estimate, ospa=..., ...)``) to an
``.rrd`` file with a default blueprint, so that ``rerun FILE.rrd`` (or ``bnptrack view FILE.rrd``)
opens ready to read: the 2-D scene large on the left, the time series on the right.
:func:`write_recording` records a whole run and scores it (OSPA, OSPA(2)) on the way.
See ``docs/rerun.md`` for the entity tree, the timelines and how to open or repair a file.

The entity tree is described in :mod:`sinks.rerun_style`.

Timelines: ``frame`` (sequence: the frame number) and ``stamp`` (timestamp: the sensor time
stamp), plus Rerun's own ``log_time``.

Cost: ``log`` keeps the frame's arrays (positions, covariances, measurements, assignment indices)
in memory; every ``flush_interval`` seconds (and on ``close``) the kept frames are turned into
geometry with numpy over all of them at once (no per-point Python loops) and sent as one
columnar chunk per entity (``RecordingStream.send_columns``).  Rare things (births, ends,
annotation context) are logged at once.  ``benchmarks/rerun_overhead.py`` measures the cost
against the tracker's own; see docs/rerun.md.

The class's two halves: :mod:`sinks.rerun_rows` (what is logged at once: births, ends, events,
the annotation context) and :mod:`sinks.rerun_chunks` (the kept frames sent as columns).
The parts: :mod:`sinks.rerun_style` (entity paths, colours, sizes), :mod:`sinks.rerun_geometry`
(ellipses, trails, crosses, rings: numpy), :mod:`sinks.rerun_columns` (ready Arrow columns),
:mod:`sinks.rerun_clusters` (colours by motion cluster, cluster links, the structure series),
:mod:`sinks.rerun_sensors` (each frame's sensor and measurement model, resolved as the tracker
resolves them; fields of view; the scene's extent), :mod:`sinks.rerun_measurements` (the
measurement columns, in the world frame through that model),
:mod:`sinks.rerun_scene` (static content, the sensors), :mod:`sinks.rerun_blueprint` (the layout),
:mod:`sinks.rerun_tools` (the ``rerun`` CLI: verify, repair; analytics off) and
:mod:`sinks.rerun_process` (the recording in a child process).
"""

from __future__ import annotations

import logging
import os
import threading
import time
import uuid
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import rerun as rr

from bnptrack.sinks.metrics import OSPA2_WINDOW, OSPA_C, OSPA_P
from bnptrack.sinks.run_scorer import RunScorer
from bnptrack.sinks.close_on_signal import CloseOnSignal
from bnptrack.sinks.rerun_blueprint import default_blueprint
from bnptrack.sinks.rerun_chunks import ChunkSender, KeptFrame
from bnptrack.sinks.rerun_clusters import ClusterColours, track_clusters
from bnptrack.sinks.rerun_columns import Schema, entity_part, log_arrays
from bnptrack.sinks.rerun_geometry import EMPTY2, EMPTY22, EMPTY_U16, EMPTY_U32, SceneGeometry, assignment_index, labels_shown
from bnptrack.sinks.rerun_live import open_file_and_live
from bnptrack.sinks.rerun_rows import RowLogger
from bnptrack.sinks.rerun_scene import log_grid, log_legend, log_sensor, view_bounds, write_static
from bnptrack.sinks.rerun_sensors import SensorBook, box_of, fov_outline, grown, scene_extent
from bnptrack.sinks.rerun_style import DIAG_NAMES, DIAGNOSTICS, FIRST_LABEL_CLASS, SERIES, TRACKS, unpack_rgba
from bnptrack.tracker.types import Estimate, Frame

if TYPE_CHECKING:
    from bnptrack.sinks.metrics import OspaResult
    from bnptrack.tracker.models.params import ModelParams

__all__ = ["RerunSink", "write_recording"]

_log = logging.getLogger("bnptrack.rerun")


class RerunSink(RowLogger, ChunkSender):
    """Write a tracking run to a Rerun ``.rrd`` recording, frame by frame.

    Args:
        path: output ``.rrd`` file (parent directories are created; an existing file is replaced).
        recording_id: Rerun recording id (default: a fresh UUID).  Processes contributing to one
            recording write separate files with the same id.
        application_id: Rerun application id (the viewer keys blueprints by it).
        metadata: run description (scenario, params, tracker, settings, seed, ...): stored as the
            ``metadata`` text document and as the recording property ``bnptrack``;
            ``bnptrack_version`` and ``rerun_version`` are added.
        trail: number of positions (the current one included) in the trail drawn behind each
            track and each true object.
        params: the model parameters of the run (:class:`tracker.models.params.ModelParams`):
            each frame's sensor (pose, field of view) and measurement model are resolved from
            them and the frame as the tracker resolves them (:class:`sinks.rerun_sensors.SensorBook`);
            default: the built-in ``vo2017`` set.
        handle_signals: install SIGTERM/SIGINT handlers (main thread only) that finalise the
            file (footer written) before the signal's previous disposition runs.
        live: a Rerun gRPC URL (``rerun+http://HOST:PORT/proxy``: a viewer, e.g. one started by
            ``rerun`` or ``bnptrack launch --view``): the recording is streamed there too, as it
            is written to ``path`` (the same rows, on a second stream:
            :mod:`sinks.rerun_live`).  A viewer that goes away or stops reading does not hold
            the file back: :meth:`close` finishes the file first, then gives the viewer a few
            seconds and leaves it behind with a warning.
        flush_interval: ``log`` keeps each frame's data in memory; at most this many seconds
            apart (checked at each ``log``), the frames kept are sent to the file as columns,
            one Arrow chunk per entity.  ``0`` sends every frame at once.  A writer killed by
            SIGKILL loses at most the last interval (plus Rerun's own 200 ms batching);
            :meth:`close` and the signal handlers send everything and write the footer.

    Use as a context manager, or call :meth:`close` (idempotent).  After ``close`` the file has
    its footer and ``rerun rrd verify`` accepts it.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        recording_id: str | None = None,
        application_id: str = "bnptrack",
        metadata: Mapping[str, str] | None = None,
        trail: int = 20,
        params: ModelParams | None = None,
        handle_signals: bool = True,
        flush_interval: float = 1.0,
        live: str | None = None,
    ) -> None:
        if trail < 1:
            raise ValueError(f"trail must be >= 1, got {trail}")
        if not flush_interval >= 0.0:
            raise ValueError(f"flush_interval must be >= 0, got {flush_interval}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.recording_id = str(recording_id) if recording_id is not None else str(uuid.uuid4())
        self.trail = int(trail)
        self.flush_interval = float(flush_interval)
        self._params = params
        self._closed = False
        self._lock = threading.RLock()
        self._prev_frame: int | None = None
        self._time: tuple[int, int] | None = None  # (frame, stamp) last set on the stream
        self._last_flush = time.monotonic()

        self._sensors = SensorBook(params)
        self._geo = SceneGeometry.of(scene_extent(self._sensors.declared() or [self._sensors.default()]))
        self.live = live or None
        self._rec = self._open_stream(application_id)
        self._s = Schema()
        self._init_state()
        self._write_static(dict(metadata or {}))
        self._signals = CloseOnSignal(self.close)
        if handle_signals:
            self._signals.install()

    def _open_stream(self, application_id: str) -> rr.RecordingStream:
        """The recording stream, saving to :attr:`path` (and streaming to :attr:`live`)."""
        self._truth_layout = True  # the blueprint's; switched off at a first frame without truth
        blueprint = default_blueprint(scene_bounds=view_bounds(self._geo.bounds))
        if self.live:  # two streams: a frozen viewer must not hold the file back
            return open_file_and_live(application_id, self.recording_id, str(self.path), self.live, blueprint)
        rec = rr.RecordingStream(application_id, recording_id=self.recording_id)
        rec.save(self.path, default_blueprint=blueprint)
        return rec

    def _init_state(self) -> None:
        # kept until the next flush
        self._frames: list[KeptFrame] = []
        self._scalars: dict[str, list[tuple[int, int, list[float]]]] = {}
        self._clears: list[tuple[str, int, int]] = []
        # label state
        self._class: dict[str, int] = {}
        self._next_class = FIRST_LABEL_CLASS
        self._live: set[str] = set()
        self._history: dict[str, np.ndarray] = {}  # last trail-1 positions before the kept frames
        self._truth_history: dict[str, np.ndarray] = {}
        self._paths: dict[Any, str] = {}
        self._styled: set[str] = set()
        self._colors: dict[str, int] = {}
        self._truth_live: set[str] = set()
        self._legend_track: tuple[tuple[int, int, int], str] | None = None  # an example colour, its meaning
        self._context_logged = False
        self._cc = ClusterColours()

    # -- public ------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def log(
        self,
        frame: Frame,
        estimate: Estimate,
        *,
        ospa: OspaResult | None = None,
        ospa2: float | None = None,
        health: Mapping[str, float] | None = None,
    ) -> None:
        """Record one frame: measurements, assignments, tracks, truth and the time series.

        ``ospa`` / ``ospa2`` are this frame's scores (see :class:`RunScorer`), ``health`` any
        pipeline counters (frames received, rejected, gaps, latency, ...), each a time series
        under ``health/<key>``.  Frames are expected in increasing frame order.
        """
        with self._lock:
            if self._closed:
                raise RuntimeError(f"RerunSink({self.path}) is closed")
            k, t = int(frame.frame), int(frame.stamp_ns)
            if self._prev_frame is None and frame.truth is None and self._truth_layout:
                self._truth_layout = False  # a log without truth: no (empty) OSPA panel
                self._rec.send_blueprint(default_blueprint(scene_bounds=view_bounds(self._geo.bounds), truth=False),
                                         make_active=True, make_default=True)
                self._log_legend()
            sensor, model = self._sensors.resolve(frame)
            self._draw_sensors(k, t, sensor)
            tracks = estimate.tracks
            labels = tuple(tr.label for tr in tracks)
            if set(labels) != self._live:
                self._labels_changed(k, t, labels)
            elif not self._context_logged:  # the context is temporal (static would shadow it)
                self._at(k, t)
                self._log_context()
            pos, cov, tcls, tcol, ccl = self._track_arrays(tracks, labels)
            x0, x1, y0, y1 = self._geo.bounds  # a name (under its dot): about 1/10 of the width, 1/16 of the height
            shown = labels_shown(pos, np.argsort(tcls, kind="stable"), (0.1 * (x1 - x0), 0.06 * (y1 - y0)))
            if labels and (self._legend_track is None or (self._legend_track[1] == "its label" and (ccl >= 0).any())):
                # the legend says what a track's colour means (a motion cluster's, once one appears)
                meaning = "its motion cluster" if (ccl >= 0).any() else "its label"
                self._legend_track = (unpack_rgba(int(tcol[int(np.argmax(ccl >= 0))]))[:3], meaning)
                self._log_legend()
            idx = assignment_index(frame.n_measurements, estimate.assignments, labels)
            truth = frame.truth
            if truth is not None:
                if set(truth.ids) != self._truth_live:
                    self._truth_changed(k, t, truth.ids)
                tids, tpos = truth.ids, truth.positions
            else:
                tids = tpos = None
            self._grow(pos)
            self._frames.append(KeptFrame(k, t, labels, pos, cov, tcls, tcol, ccl, shown, model, frame.z, idx,
                                     tids, tpos))
            self._log_scalars(k, t, frame, estimate, ospa, ospa2, health)
            self._prev_frame = k
            if time.monotonic() - self._last_flush >= self.flush_interval:
                self.flush(wait=False)

    def _draw_sensors(self, k: int, t: int, sensor: Any) -> None:
        """Draw the frame's sensor (and, at the first frame, the declared ones) where it is not
        drawn yet at its present pose; grow the scene to its field of view (at the first frame
        of a run without declared sensors: set the scene to it)."""
        first = self._prev_frame is None
        todo = self._sensors.to_draw([*(self._sensors.declared() if first else ()), sensor])
        if not todo:
            return
        self._at(k, t)
        for s in todo:
            log_sensor(self._rec, s, self._sensors.colour(s))
        outlines = np.concatenate([fov_outline(s) for s in todo])
        if not self._grow(outlines, reset=first and not self._sensors.params.sensors):
            self._log_legend()

    def _grow(self, points: np.ndarray, reset: bool = False) -> bool:
        """Grow the scene (view bounds, grid, legend) to hold ``points`` (``reset``: set it to
        them); whether it changed."""
        if not points.shape[0]:
            return False
        new = box_of(points) if reset else grown(self._geo.bounds, points)
        if new is None or new == self._geo.bounds:
            return False
        self._geo = self._geo.with_bounds(new)
        self._rec.send_blueprint(default_blueprint(scene_bounds=view_bounds(new), truth=self._truth_layout),
                                 make_active=True, make_default=True)
        log_grid(self._rec, new)
        self._log_legend()
        return True

    def _log_legend(self) -> None:
        log_legend(self._rec, self._geo, [(s, self._sensors.colour(s)) for s in self._sensors.drawn],
                   self._legend_track, truth=self._truth_layout)

    def _track_arrays(self, tracks: Any, labels: tuple[str, ...]) -> tuple[np.ndarray, ...]:
        """Positions ``(n, 2)``, position covariances ``(n, 2, 2)``, class ids, packed colours
        (:mod:`sinks.rerun_clusters`) and motion clusters of the frame's tracks."""
        if not labels:
            return EMPTY2, EMPTY22, EMPTY_U16, EMPTY_U32, track_clusters(())
        states = np.stack([tr.state for tr in tracks])
        pos = states[:, 0:3:2]
        cov = np.stack([tr.covariance for tr in tracks])[:, 0:3:2, 0:3:2]
        cls_of, col_of = self._class, self._colors
        tcls = np.array([cls_of[lab] for lab in labels], dtype=np.uint16)
        ccl = track_clusters(tracks)
        tcol = self._cc.frame_colours(ccl, np.array([col_of[lab] for lab in labels], dtype=np.uint32))
        return pos, cov, tcls, tcol, ccl

    def flush(self, *, wait: bool = False) -> None:
        """Send the kept frames to the file now (``wait``: until they are written)."""
        with self._lock:
            if self._closed:
                return
            self._send_kept()
            try:
                self._rec.flush(timeout_sec=30.0 if wait else 0.0)
            except RuntimeError as exc:  # a live viewer that went away must not stop the run
                if not self.live:
                    raise
                _log.warning("live view %s: %s", self.live, exc)
            self._last_flush = time.monotonic()

    def close(self) -> None:
        """Send everything, write the footer and close the file (idempotent)."""
        with self._lock:
            if self._closed:
                return
            try:
                self._send_kept()
                try:
                    self._rec.flush(timeout_sec=30.0)
                except RuntimeError as exc:  # the live viewer is gone; the file is not
                    if not self.live:
                        raise
                    _log.warning("live view %s: %s (the file %s is complete)", self.live, exc, self.path)
            finally:
                self._closed = True
                self._rec.disconnect()
                self._signals.restore()

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- static and rare content (sent at once, row by row) -------------------------------
    def _at(self, k: int, t: int) -> None:
        if self._time != (k, t):
            self._rec.set_time("frame", sequence=k)
            self._rec.set_time("stamp", timestamp=np.datetime64(t, "ns"))
            self._time = (k, t)

    def _write_static(self, metadata: dict[str, str]) -> None:
        write_static(self._rec, self._geo, metadata, self.trail)
        for entity, (names, colors) in SERIES.items():
            self._series_style(entity, names, colors)
        for key in DIAG_NAMES:
            self._series_style(f"{DIAGNOSTICS}/{key}", [DIAG_NAMES[key]], [(120, 190, 255)])

    def _log_arrays(self, path: str, comps: dict[str, pa.Array], static: bool = False) -> None:
        log_arrays(self._rec, self._s, path, comps, static)

    def _track_path(self, label: str) -> str:
        path = self._paths.get(label)
        if path is None:
            path = self._paths[label] = f"{TRACKS}/{entity_part(label)}"
        return path


def write_recording(
    path: str | os.PathLike,
    frames: Iterable[Frame],
    estimates: Iterable[Estimate],
    metadata: Mapping[str, str] | None = None,
    *,
    params: ModelParams | None = None,
    c: float = OSPA_C,
    p: float = OSPA_P,
    window: int = OSPA2_WINDOW,
    **sink_kwargs: Any,
) -> None:
    """Record a whole run (frames and the tracker's estimates, paired in order) to ``path``.

    Frames with truth are scored with :class:`RunScorer` (OSPA with cut-off ``c`` and order
    ``p`` on position; OSPA(2) over ``window`` frames); ``sink_kwargs`` go to
    :class:`RerunSink`.  The file is complete (footer written) when this returns.
    """
    scorer = RunScorer(c=c, p=p, window=window)
    with RerunSink(path, metadata=metadata, params=params, **sink_kwargs) as sink:
        for frame, est in zip(frames, estimates, strict=True):
            sink.log(frame, est, **scorer.update(frame, est))
