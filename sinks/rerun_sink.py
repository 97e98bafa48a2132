"""Rerun (``.rrd``) recordings of a tracking run, to inspect it offline in the Rerun viewer.

:class:`RerunSink` writes one frame at a time (``log(frame, estimate, ospa=..., ...)``) to an
``.rrd`` file with a default blueprint, so that ``rerun FILE.rrd`` (or ``bnptrack view FILE.rrd``)
opens ready to read: the 2-D scene large on the left, the time series on the right.
:func:`write_recording` records a whole run and scores it (OSPA, OSPA(2)) on the way.
See ``docs/rerun.md`` for the entity tree, the timelines and how to open or repair a file.

Entity tree (``world`` is drawn with +y up; positions in metres, sensor at the origin)::

    world                      AnnotationContext (class 0 clutter, 1 unassigned, 2.. labels)
    world/sensor               sensor position and field of view (static)
    world/grid                 metric grid (static); world/grid/axes x and y axes, world/grid/ticks
                               tick labels in metres
    world/legend/<what>        legend symbols with their meaning (static, top corners)
    world/measurements         Points2D, coloured by the label they were assigned to
    world/measurements/rings   range-only sensors: one arc per measurement
    world/assignments          LineStrips2D measurement -> assigned track estimate
    world/tracks/<label>       Points2D (position, short name T1, T2, ... in order of
                               confirmation) + LineStrips2D (trail, 2-sigma
                               ellipse); cleared (rr.Clear) when the label ends
    world/truth                LineStrips2D grey crosses (when the source has truth)
    world/truth/trails         LineStrips2D thin grey trails of the true objects
    metrics/cardinality        Scalars [estimated, true]
    metrics/ospa               Scalars [total, localisation, cardinality]
    metrics/ospa2              Scalars [total]
    diagnostics/<key>          Scalars, one per tracker diagnostic (alpha, d, n_clusters, ...)
    health/<key>               Scalars, pipeline health counters when given
    events                     TextLog: track and truth births and ends
    metadata                   TextDocument: scenario, parameters, tracker, seed, versions

Timelines: ``frame`` (sequence: the frame number) and ``stamp`` (timestamp: the sensor time
stamp), plus Rerun's own ``log_time``.

Cost: ``log`` keeps the frame's arrays (positions, covariances, measurements, assignment indices)
in memory; every ``flush_interval`` seconds (and on ``close``) the kept frames are turned into
geometry with numpy over all of them at once (no per-point Python loops) and sent as one
columnar chunk per entity (``RecordingStream.send_columns``).  Rare things (births, ends,
annotation context) are logged at once.  ``benchmarks/rerun_overhead.py`` measures the cost
against the tracker's own; see docs/rerun.md.

Analytics: the Rerun *SDK* used here sends nothing; the ``rerun`` *CLI/viewer* binary would.
Every subprocess started from this module (:func:`verify`, :func:`repair`) runs with
:func:`rerun_env`, which turns the CLI's analytics off (see its docstring).
"""

from __future__ import annotations

import importlib.util
import logging
import math
import os
import shutil
import signal
import subprocess
import threading
import time
import uuid
import zlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from sinks.metrics import OSPA2_WINDOW, OSPA_C, OSPA_P, RunScorer
from tracker.types import Estimate, Frame

if TYPE_CHECKING:
    from sinks.metrics import OspaResult
    from tracker.models.params import ModelParams

__all__ = [
    "RerunSink",
    "RunScorer",
    "RerunToolError",
    "write_recording",
    "default_blueprint",
    "label_color",
    "rerun_cli",
    "rerun_env",
    "verify",
    "repair",
    "OSPA_C",
    "OSPA_P",
    "OSPA2_WINDOW",
]

_log = logging.getLogger("bnptrack.rerun")

# --------------------------------------------------------------------------- entity paths
WORLD = "world"
SENSOR = "world/sensor"
MEASUREMENTS = "world/measurements"
RINGS = "world/measurements/rings"
ASSIGNMENTS = "world/assignments"
TRACKS = "world/tracks"
TRUTH = "world/truth"
TRUTH_TRAILS = "world/truth/trails"
CARDINALITY = "metrics/cardinality"
OSPA = "metrics/ospa"
OSPA2 = "metrics/ospa2"
DIAGNOSTICS = "diagnostics"
HEALTH = "health"
EVENTS = "events"
METADATA = "metadata"
GRID = "world/grid"
GRID_TICKS = "world/grid/ticks"
AXES = "world/grid/axes"
LEGEND = "world/legend"

#: Class ids of the annotation context on ``world`` (labels get ids from FIRST_LABEL_CLASS on).
CLUTTER_CLASS = 0
UNASSIGNED_CLASS = 1
FIRST_LABEL_CLASS = 2
_MAX_CLASS = 65535  # class ids are uint16

# Colours (RGBA) and sizes; negative radii are screen points (zoom independent).
GREY_CLUTTER = (150, 150, 150, 255)
WHITE_UNASSIGNED = (225, 225, 225, 255)
GREY_TRUTH = (175, 175, 175, 255)
GREY_TRUTH_TRAIL = (175, 175, 175, 110)
SENSOR_COLOR = (240, 200, 80, 255)
R_TRACK = -5.0
R_TRAIL = -1.25
R_ELLIPSE = -1.0
R_MEAS_CLUTTER = -2.0
R_MEAS_ASSIGNED = -3.0
R_ASSIGN_LINE = -0.6
R_TRUTH_CROSS = -1.0
R_TRUTH_TRAIL = -0.6
R_RING = -0.6
ELLIPSE_SIGMA = 2.0
ELLIPSE_POINTS = 36

#: Series styles: entity -> (names, colours).
_SERIES: dict[str, tuple[list[str], list[tuple[int, int, int]]]] = {
    CARDINALITY: (["estimated", "true"], [(80, 170, 255), (190, 190, 190)]),
    OSPA: (["total", "localisation", "cardinality"], [(255, 120, 80), (120, 200, 120), (200, 140, 255)]),
    OSPA2: (["OSPA(2)"], [(255, 200, 60)]),
}
_DIAG_NAMES = {
    "alpha": "alpha (concentration)",
    "d": "d (discount)",
    "n_clusters": "clusters",
    "n_tracks": "reported tracks",
    "log_joint": "Gibbs log joint",
    "ms": "tracker ms / frame",
}


class RerunToolError(RuntimeError):
    """The ``rerun`` command-line tool is missing, failed or timed out."""


_EMPTY2 = np.zeros((0, 2))
_EMPTY22 = np.zeros((0, 2, 2))
_EMPTY_U16 = np.zeros(0, dtype=np.uint16)
_EMPTY_U32 = np.zeros(0, dtype=np.uint32)

# --------------------------------------------------------------------------- colours


#: Distinct track colours (RGB, bright on the viewer's dark background): a label takes one at
#: birth and keeps it until it ends.  None is near the colours of the sensor, the truth, clutter
#: or unassigned measurements (RGB distance >= :data:`MIN_COLOR_DISTANCE`: no yellow, cream,
#: pale pink or lavender track that could be read as the sensor or the truth).
PALETTE: tuple[tuple[int, int, int], ...] = (
    (230, 25, 75), (60, 180, 75), (90, 130, 255), (245, 130, 49), (170, 80, 230),
    (66, 212, 244), (240, 50, 230), (70, 200, 180), (255, 120, 120), (120, 220, 60),
    (0, 110, 255),
)
#: Smallest RGB distance between a track colour and the reserved colours (tests check it).
MIN_COLOR_DISTANCE = 75.0


def label_color(label: str, taken: Iterable[tuple[int, ...]] = ()) -> tuple[int, int, int, int]:
    """Colour of a track label: the palette entry picked by the CRC32 of the label, or, when
    that one is ``taken`` by a live label, the next free entry (the least used one if none is).

    Without ``taken`` the result depends on the label alone, in every run and process (no
    ``hash()`` salt); :class:`RerunSink` passes the colours of the live labels at birth, so that
    labels alive together differ, and keeps the colour for the label's whole life.
    """
    n = len(PALETTE)
    start = zlib.crc32(label.encode("utf-8")) % n
    used: dict[tuple[int, int, int], int] = {}
    for rgba in taken:
        key = tuple(rgba[:3])
        used[key] = used.get(key, 0) + 1  # type: ignore[index]
    best = min(range(n), key=lambda i: (used.get(PALETTE[(start + i) % n], 0), i))
    return (*PALETTE[(start + best) % n], 255)


def _pack(rgba: Sequence[int]) -> int:
    r, g, b, a = (list(rgba) + [255])[:4]
    return (int(r) << 24) | (int(g) << 16) | (int(b) << 8) | int(a)


def _unpack(packed: int) -> tuple[int, int, int, int]:
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255, packed & 255


# --------------------------------------------------------------------------- arrow columns


class _Batch:
    """A ready Arrow array with its component descriptor (``rerun.ComponentBatchLike``)."""

    __slots__ = ("_descr", "_array")

    def __init__(self, descr: Any, array: pa.Array) -> None:
        self._descr, self._array = descr, array

    def component_descriptor(self) -> Any:
        return self._descr

    def as_arrow_array(self) -> pa.Array:
        return self._array


class _Schema:
    """Component descriptors and Arrow types of the components this module writes as arrays.

    Taken once from real archetype objects (``rr.Points2D``, ``rr.LineStrips2D``, ``rr.Scalars``,
    ``rr.Clear``, ``rr.TextLog``, ``rr.AnnotationContext``), so the arrays built here from numpy
    carry exactly the descriptors and Arrow types the SDK's constructors would give them, without
    their per-call Python cost.  The tests read every component back and compare the values.
    """

    def __init__(self) -> None:
        protos = {
            "Points2D": rr.Points2D(
                [[0.0, 0.0]], radii=[1.0], colors=[0], labels=["a"], class_ids=[1],
                show_labels=True, draw_order=1.0,
            ),
            "LineStrips2D": rr.LineStrips2D(
                [[[0.0, 0.0], [1.0, 1.0]]], radii=[1.0], colors=[0], labels=["a"],
                class_ids=[1], show_labels=True, draw_order=1.0,
            ),
            "Scalars": rr.Scalars([1.0]),
            "Clear": rr.Clear(recursive=True),
            "TextLog": rr.TextLog("a", level="INFO"),
            "AnnotationContext": rr.AnnotationContext(
                [rr.AnnotationInfo(id=1, label="a", color=(1, 2, 3, 255))]),
        }
        self.d: dict[str, Any] = {}
        self.t: dict[str, pa.DataType] = {}
        for arch, proto in protos.items():
            for batch in proto.as_component_batches():
                descr = batch.component_descriptor()
                key = f"{arch}:{str(descr).split(':', 1)[1]}"
                self.d[key] = descr
                self.t[key] = batch.as_arrow_array().type
        self.vec2 = self.t["Points2D:positions"]
        self.strip = self.t["LineStrips2D:strips"]

    def positions(self, xy: np.ndarray) -> pa.Array:
        flat = np.ascontiguousarray(xy, dtype=np.float32).reshape(-1)
        return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float32()), type=self.vec2)

    def strip_array(self, points: np.ndarray, lengths: np.ndarray) -> pa.Array:
        """LineStrip2D array: strip ``i`` is the next ``lengths[i]`` rows of ``points``."""
        offsets = np.zeros(len(lengths) + 1, dtype=np.int32)
        np.cumsum(lengths, out=offsets[1:])
        return pa.ListArray.from_arrays(pa.array(offsets, type=pa.int32()), self.positions(points),
                                        type=self.strip)


# --------------------------------------------------------------------------- CLI helpers


def rerun_cli() -> list[str]:
    """Command prefix that runs the ``rerun`` CLI shipped with the installed rerun-sdk.

    ``RERUN_CLI_PATH`` overrides it; otherwise the binary inside the ``rerun_cli`` package (the
    same version as the SDK), else ``rerun`` on ``PATH``.  Raises :class:`RerunToolError`.
    """
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return [override]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        exe = Path(spec.origin).with_name("rerun")
        if exe.is_file() and os.access(exe, os.X_OK):
            return [str(exe)]
    found = shutil.which("rerun")
    if found:
        return [found]
    raise RerunToolError(
        "the `rerun` command-line tool was not found: install rerun-sdk "
        "(pip install 'rerun-sdk>=0.41,<0.42'), which ships it"
    )


def rerun_env(*, analytics: bool = False, quiet: bool = True) -> dict[str, str]:
    """Environment for a ``rerun`` subprocess.

    rerun 0.41 has no analytics environment switch of its own (``RERUN_ANALYTICS`` is not read);
    its analytics pipeline is skipped when ``CI`` is set (any value) or after
    ``rerun analytics disable``.  With ``analytics=False`` (the default) ``CI`` is set if absent,
    so the CLI neither phones home nor writes an analytics config.  ``quiet`` sets ``RUST_LOG``
    to ``error`` unless already set (the viewer otherwise shows log toasts over screenshots).
    """
    env = dict(os.environ)
    if not analytics:
        env.setdefault("CI", "1")
    if quiet:
        env.setdefault("RUST_LOG", "error")
    return env


def _run_cli(args: Sequence[str], timeout: float, what: str) -> subprocess.CompletedProcess[str]:
    cmd = [*rerun_cli(), *map(str, args)]
    try:
        return subprocess.run(
            cmd, capture_output=True, text=True, timeout=timeout, env=rerun_env(),
            stdin=subprocess.DEVNULL, check=False,
        )
    except subprocess.TimeoutExpired as exc:
        raise RerunToolError(f"{what}: `{' '.join(cmd)}` timed out after {timeout:g} s") from exc
    except OSError as exc:
        raise RerunToolError(f"{what}: cannot run `{cmd[0]}`: {exc}") from exc


def verify(path: str | os.PathLike, *, timeout: float = 60.0) -> None:
    """``rerun rrd verify PATH`` (footer checked); raises :class:`RerunToolError` on failure."""
    res = _run_cli(["rrd", "verify", os.fspath(path)], timeout, "verify")
    if res.returncode != 0:
        raise RerunToolError(f"rerun rrd verify {path} failed: {(res.stderr or res.stdout).strip()}")


def repair(path: str | os.PathLike, out: str | os.PathLike, *, timeout: float = 120.0) -> Path:
    """Rewrite a damaged recording (e.g. a writer killed before its footer) into ``out``.

    Runs ``rerun rrd merge --continue-on-error -o OUT PATH``: every chunk that can be decoded is
    kept, the rest dropped, and ``out`` gets a proper footer (``rerun rrd verify`` accepts it).
    Raises :class:`RerunToolError` when the tool fails, times out or writes nothing.
    """
    path, out = Path(path), Path(out)
    if out.resolve() == path.resolve():
        raise ValueError(f"repair: the output {out} would overwrite the input")
    if not path.is_file():
        raise FileNotFoundError(2, "No such file", str(path))
    out.parent.mkdir(parents=True, exist_ok=True)
    res = _run_cli(["rrd", "merge", "--continue-on-error", "-o", os.fspath(out), os.fspath(path)],
                   timeout, "repair")
    if res.returncode != 0 or not out.is_file() or out.stat().st_size == 0:
        raise RerunToolError(
            f"rerun rrd merge --continue-on-error failed on {path} (exit {res.returncode}): "
            f"{(res.stderr or res.stdout).strip()}"
        )
    return out


# --------------------------------------------------------------------------- blueprint


def default_blueprint(*, diagnostics: Iterable[str] = tuple(_DIAG_NAMES), health: bool = True,
                      scene_bounds: tuple[float, float, float, float] | None = None,
                      truth: bool = True) -> rrb.Blueprint:
    """The layout a recording opens with: the 2-D scene (3/5 of the width) and, beside it,
    cardinality, OSPA / OSPA(2) and a tab group (tracker diagnostics, pipeline health, events,
    run metadata).  ``scene_bounds`` = ``(x_min, x_max, y_min, y_max)`` in metres.  Without
    ``truth`` (a log without ground truth) there is no OSPA panel (it would stay empty) and the
    cardinality panel shows the number of tracks alone.
    """
    scene_kw: dict[str, Any] = {}
    if scene_bounds is not None:
        x0, x1, y0, y1 = scene_bounds
        # the scene is drawn under a y-flip (see RerunSink): view y = -world y
        scene_kw["visual_bounds"] = rrb.VisualBounds2D(x_range=[x0, x1], y_range=[-y1, -y0])
    diag_views: list[Any] = [
        rrb.TimeSeriesView(origin=f"{DIAGNOSTICS}/{k}", name=_DIAG_NAMES.get(k, k)) for k in diagnostics
    ]
    tabs: list[Any] = [*diag_views]
    if health:
        tabs.append(rrb.TimeSeriesView(origin=HEALTH, name="pipeline health"))
    tabs += [rrb.TextLogView(origin=EVENTS, name="births / ends"),
             rrb.TextDocumentView(origin=METADATA, name="run")]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="/", contents=f"{WORLD}/**", name="scene (x east, y north, m)",
                              **scene_kw),
            rrb.Vertical(*_metric_views(truth), rrb.Tabs(*tabs, active_tab=0),
                         row_shares=[1.0, 1.0, 1.1] if truth else [1.0, 2.1]),
            column_shares=[3.0, 2.0],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline="frame"),
    )


def _metric_views(truth: bool) -> list[Any]:
    if not truth:
        return [rrb.TimeSeriesView(origin=CARDINALITY, name="tracks (the log has no truth: no OSPA)")]
    return [rrb.TimeSeriesView(origin=CARDINALITY, name="cardinality: estimated vs true"),
            rrb.TimeSeriesView(origin="metrics", contents=[OSPA, OSPA2], name="OSPA (c=100 m, p=1) and OSPA(2)")]


def _nice_step(span: float) -> float:
    """The largest round grid step (1, 2 or 5 x 10^n metres) not above ``span``."""
    base = 10.0 ** math.floor(math.log10(max(span, 1e-9)))
    return max(m * base for m in (1.0, 2.0, 5.0) if m * base <= span * (1 + 1e-9))


# --------------------------------------------------------------------------- the sink


class _Rec(NamedTuple):
    """What :meth:`RerunSink.log` keeps of one frame until the next flush."""

    k: int
    t: int
    labels: tuple[str, ...]
    pos: np.ndarray  # (n, 2) track positions
    cov: np.ndarray  # (n, 2, 2) position covariances
    tcls: np.ndarray  # (n,) class ids of the tracks
    tcol: np.ndarray  # (n,) packed colours of the tracks
    kind: str
    z: np.ndarray  # (M, d) measurements
    idx: np.ndarray | None  # (M,) index of the assigned track, -1 clutter; None: no assignments
    truth_ids: tuple[str, ...] | None
    truth_pos: np.ndarray | None


class RerunSink:
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
        params: the model parameters of the run (:class:`tracker.models.params.ModelParams`),
            for the measurement model (sensor position) and the field of view; default: the
            sensor at the origin with a 2000 m / +-90 deg field.
        handle_signals: install SIGTERM/SIGINT handlers (main thread only) that finalise the
            file (footer written) before the signal's previous disposition runs.
        live: a Rerun gRPC URL (``rerun+http://HOST:PORT/proxy``: a viewer, e.g. one started by
            ``rerun`` or ``bnptrack launch --view``): the recording is streamed there too, as it
            is written to ``path`` (the same rows: ``rr.set_sinks(GrpcSink, FileSink)``).  A
            viewer that goes away does not stop the file: :meth:`close` logs the failed
            flush and still finishes the file (Rerun gives up on the stream after about 5 s).
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

        rng = float(getattr(params, "range_max", 2000.0))
        half = math.radians(float(getattr(params, "bearing_half_fov_deg", 90.0)))
        self._range_max, self._half_fov = rng, half
        self._cross = 0.015 * rng  # half-size of a truth cross, m
        circle = np.linspace(0.0, 2.0 * np.pi, ELLIPSE_POINTS + 1)
        self._circle = np.stack([np.cos(circle), np.sin(circle)], axis=-1)  # (K+1, 2)
        self._arc = np.linspace(-half, half, 49)

        self.live = live or None
        self._rec = rr.RecordingStream(application_id, recording_id=self.recording_id)
        self._bounds = _fov_bounds(rng, half)
        self._truth_layout = True  # the blueprint's; switched off at a first frame without truth
        blueprint = default_blueprint(scene_bounds=self._bounds)
        if self.live:
            self._rec.set_sinks(rr.GrpcSink(self.live), rr.FileSink(self.path), default_blueprint=blueprint)
        else:
            self._rec.save(self.path, default_blueprint=blueprint)
        self._s = _Schema()

        # kept until the next flush
        self._frames: list[_Rec] = []
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
        self._meas_models: dict[str, Any] = {}
        self._context_logged = False
        self._names: dict[str, str] = {}  # label -> short name (T1, T2, ... in order of birth)

        self._write_static(dict(metadata or {}))
        self._old_handlers: dict[int, Any] = {}
        if handle_signals:
            self._install_signals()

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
                self._rec.send_blueprint(default_blueprint(scene_bounds=self._bounds, truth=False),
                                         make_active=True, make_default=True)
            tracks = estimate.tracks
            labels = tuple(tr.label for tr in tracks)
            if set(labels) != self._live:
                self._labels_changed(k, t, labels)
            elif not self._context_logged:  # the context is temporal (static would shadow it)
                self._at(k, t)
                self._log_context()
            n = len(labels)
            if n:
                states = np.stack([tr.state for tr in tracks])
                pos = states[:, 0:3:2]
                cov = np.stack([tr.covariance for tr in tracks])[:, 0:3:2, 0:3:2]
                cls_of, col_of = self._class, self._colors
                tcls = np.array([cls_of[lab] for lab in labels], dtype=np.uint16)
                tcol = np.array([col_of[lab] for lab in labels], dtype=np.uint32)
            else:
                pos, cov = _EMPTY2, _EMPTY22
                tcls, tcol = _EMPTY_U16, _EMPTY_U32
            M = frame.n_measurements
            assigned = estimate.assignments
            if len(assigned) == M and M:
                if n:
                    index = {lab: i for i, lab in enumerate(labels)}
                    idx = np.fromiter((-1 if a is None else index.get(a, -1) for a in assigned),
                                      dtype=np.int64, count=M)
                else:
                    idx = np.full(M, -1, dtype=np.int64)
            else:
                idx = None
            truth = frame.truth
            if truth is not None:
                if set(truth.ids) != self._truth_live:
                    self._truth_changed(k, t, truth.ids)
                tids, tpos = truth.ids, truth.positions
            else:
                tids = tpos = None
            self._frames.append(_Rec(k, t, labels, pos, cov, tcls, tcol, frame.kind, frame.z, idx,
                                     tids, tpos))
            self._log_scalars(k, t, frame, estimate, ospa, ospa2, health)
            self._prev_frame = k
            if time.monotonic() - self._last_flush >= self.flush_interval:
                self.flush(wait=False)

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
                self._restore_signals()

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- signals -----------------------------------------------------------------------
    def _install_signals(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                self._old_handlers[sig] = signal.signal(sig, self._on_signal)
            except (ValueError, OSError):  # pragma: no cover - not allowed here
                pass

    def _restore_signals(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig, old in self._old_handlers.items():
            try:
                if signal.getsignal(sig) == self._on_signal:
                    signal.signal(sig, old)
            except (ValueError, OSError, TypeError):  # pragma: no cover
                pass

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        old = self._old_handlers.get(signum, signal.SIG_DFL)
        try:
            self.close()  # also puts the previous handler back
        finally:
            if callable(old):
                old(signum, frame)  # e.g. SIGINT -> KeyboardInterrupt, or another sink's handler
            elif old == signal.SIG_DFL:
                signal.signal(signum, signal.SIG_DFL)
                os.kill(os.getpid(), signum)  # die by the signal, as without the sink
            # SIG_IGN: ignored as before (the sink is closed all the same)

    # -- static and rare content (sent at once, row by row) -------------------------------
    def _at(self, k: int, t: int) -> None:
        if self._time != (k, t):
            self._rec.set_time("frame", sequence=k)
            self._rec.set_time("stamp", timestamp=np.datetime64(t, "ns"))
            self._time = (k, t)

    def _write_static(self, metadata: dict[str, str]) -> None:
        rec = self._rec
        meta = {str(k): str(v) for k, v in metadata.items()}
        meta.setdefault("bnptrack_version", _version("bnptrack"))
        meta.setdefault("rerun_version", rr.__version__)
        name = " ".join(meta[k] for k in ("scenario", "tracker") if k in meta)
        if "seed" in meta:
            name += f" seed {meta['seed']}"
        rec.send_recording_name(name.strip() or "bnptrack run")
        rec.send_property("bnptrack", rr.AnyValues(**{_ident(k): v for k, v in meta.items()}))
        rows = "\n".join(f"| {k} | {_md(v)} |" for k, v in meta.items())
        rec.log(METADATA, rr.TextDocument(
            "# bnptrack run\n\n| key | value |\n| --- | --- |\n" + rows + "\n\n"
            "Scene: x east, y north (m), sensor at the origin, grid lines every "
            f"{_nice_step((self._bounds[1] - self._bounds[0]) / 8):g} m; the legend is in the top "
            "corners. Tracks: dot + short name (T1, T2, ... in order of confirmation; hover a "
            "track for its internal label, in its entity path), trail of the "
            f"last {self.trail} positions, {ELLIPSE_SIGMA:g}-sigma position ellipse. Measurements "
            "take the colour of the track they were assigned to; grey dots are clutter; thin lines "
            "join a measurement to its track. Grey crosses and thin trails: ground truth.",
            media_type=rr.MediaType.MARKDOWN), static=True)
        rec.log(WORLD, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)  # draw +y up
        arc = np.linspace(-self._half_fov, self._half_fov, 91)
        fov = np.concatenate([[[0.0, 0.0]],
                              np.stack([self._range_max * np.sin(arc), self._range_max * np.cos(arc)], -1),
                              [[0.0, 0.0]]])
        rec.log(SENSOR, rr.Points2D([[0.0, 0.0]], radii=-6.0, colors=[SENSOR_COLOR], labels=["sensor"]),
                rr.LineStrips2D([fov], radii=-0.75, colors=[(110, 110, 110, 150)], draw_order=0.1),
                static=True)
        self._log_grid()
        self._log_legend()
        # styles that do not change from frame to frame
        rec.log(MEASUREMENTS, rr.Points2D.from_fields(show_labels=False, draw_order=3.0), static=True)
        rec.log(ASSIGNMENTS, rr.LineStrips2D.from_fields(radii=[R_ASSIGN_LINE], show_labels=False,
                                                         draw_order=2.0), static=True)
        rec.log(TRUTH, rr.LineStrips2D.from_fields(radii=[R_TRUTH_CROSS], colors=[GREY_TRUTH],
                                                   show_labels=False, draw_order=1.0), static=True)
        rec.log(TRUTH_TRAILS, rr.LineStrips2D.from_fields(
            radii=[R_TRUTH_TRAIL], colors=[GREY_TRUTH_TRAIL], show_labels=False, draw_order=0.9),
            static=True)
        for entity, (names, colors) in _SERIES.items():
            self._series_style(entity, names, colors)
        for key in _DIAG_NAMES:
            self._series_style(f"{DIAGNOSTICS}/{key}", [_DIAG_NAMES[key]], [(120, 190, 255)])

    def _log_grid(self) -> None:
        """Static metric grid (round steps, about 8 across the field of view), the x and y axes
        through the sensor, and tick labels in metres along the bottom and left edges."""
        x0, x1, y0, y1 = self._bounds
        step = _nice_step((x1 - x0) / 8)
        xs = np.arange(math.ceil(x0 / step), math.floor(x1 / step) + 1) * step
        ys = np.arange(math.ceil(y0 / step), math.floor(y1 / step) + 1) * step
        lines = [[[x, y0], [x, y1]] for x in xs] + [[[x0, y], [x1, y]] for y in ys]
        rec = self._rec
        rec.log(GRID, rr.LineStrips2D(lines, radii=-0.5, colors=[(70, 70, 70, 110)], draw_order=0.0),
                static=True)
        rec.log(AXES, rr.LineStrips2D([[[x0, 0.0], [x1, 0.0]], [[0.0, y0], [0.0, y1]]], radii=-0.8,
                                      colors=[(135, 135, 135, 200)], show_labels=False, draw_order=0.05),
                rr.Points2D([[x1 - 0.07 * (x1 - x0), y0 - 0.1 * (y1 - y0)], [0.0, y1 + 0.02 * (y1 - y0)]],
                            radii=-1.0,
                            colors=[(135, 135, 135, 255)], labels=["x east (m)", "y north (m)"],
                            show_labels=True, draw_order=0.05), static=True)
        inset = 0.025 * (x1 - x0)  # tick labels are centred on their point: keep them in view
        ticks = [[x, y0] for x in xs] + [[x0 + inset, y] for y in ys if y > y0 + 0.5 * step]
        labels = [f"{x:g}" for x in xs] + [f"{y:g}" for y in ys if y > y0 + 0.5 * step]
        rec.log(GRID_TICKS, rr.Points2D(ticks, radii=-1.0, colors=[(135, 135, 135, 255)], labels=labels,
                                        show_labels=True, draw_order=0.05), static=True)

    def _log_legend(self) -> None:
        """Static legend in the scene's top corners (empty: outside the field of view), one
        entity per symbol: ``world/legend/<what>``, the symbol drawn as in the scene with its
        meaning as label."""
        x0, x1, y0, y1 = self._bounds
        w, h = x1 - x0, y1 - y0
        dy = 0.09 * h
        left, right = x0 + 0.2 * w, x1 - 0.17 * w
        top = y1 - 0.03 * h
        track_rgb = PALETTE[2]
        rec = self._rec

        def at(col: float, row: int) -> np.ndarray:
            return np.array([col, top - row * dy])

        rec.log(f"{LEGEND}/measurement", rr.Points2D([at(left, 0)], radii=R_MEAS_ASSIGNED, colors=[WHITE_UNASSIGNED],
                                                     labels=["measurement"], show_labels=True), static=True)
        rec.log(f"{LEGEND}/clutter", rr.Points2D([at(left, 1)], radii=R_MEAS_CLUTTER, colors=[GREY_CLUTTER],
                                                 labels=["clutter (no track)"], show_labels=True), static=True)
        p, q = at(left, 2), at(left, 2) + (0.04 * w, 0.0)
        rec.log(f"{LEGEND}/assigned", rr.Points2D([p], radii=R_MEAS_ASSIGNED, colors=[track_rgb],
                                                  labels=["assigned measurement (track colour)"], show_labels=True),
                rr.LineStrips2D([[p, q]], radii=R_ASSIGN_LINE, colors=[(*track_rgb, 150)]), static=True)
        c, hx = at(right, 0), self._cross
        rec.log(f"{LEGEND}/truth", rr.LineStrips2D(
            [[c - (hx, hx), c + (hx, hx)], [c + (-hx, hx), c + (hx, -hx)]], radii=R_TRUTH_CROSS,
            colors=[GREY_TRUTH], labels=["truth", ""], show_labels=True), static=True)
        c = at(right, 1)
        trail = c + np.stack([np.linspace(-0.06 * w, 0.0, 6), 0.01 * w * np.sin(np.linspace(0, 3, 6))], -1)
        rec.log(f"{LEGEND}/track", rr.Points2D([c], radii=R_TRACK, colors=[track_rgb], labels=["track T1 + trail"],
                                               show_labels=True),
                rr.LineStrips2D([trail], radii=R_TRAIL, colors=[track_rgb]), static=True)
        c = at(right, 2)
        ell = c + self._circle * (0.03 * w, 0.012 * h)
        rec.log(f"{LEGEND}/ellipse", rr.LineStrips2D([ell], radii=R_ELLIPSE, colors=[(*track_rgb, 170)],
                                                     labels=[f"{ELLIPSE_SIGMA:g}-sigma ellipse"], show_labels=True),
                static=True)

    def _series_style(self, entity: str, names: list[str], colors: list[tuple[int, int, int]]) -> None:
        self._rec.log(entity, rr.SeriesLines(names=names, colors=colors, widths=[1.5] * len(names)),
                      static=True)
        self._styled.add(entity)

    def _log_context(self) -> None:
        """Annotation context of ``world``: clutter, unassigned, and one class per live label
        (its name and colour), so hovering a measurement names the track it went to."""
        classes = [(CLUTTER_CLASS, "clutter", _pack(GREY_CLUTTER)),
                   (UNASSIGNED_CLASS, "measurement", _pack(WHITE_UNASSIGNED))]
        classes += [(self._class[lab], f"{self._names[lab]} (label {lab})", self._colors[lab])
                    for lab in sorted(self._live, key=self._class.__getitem__)]
        rows = [{"class_id": i, "class_description": {
                    "info": {"id": i, "label": name, "color": color},
                    "keypoint_annotations": [], "keypoint_connections": []}}
                for i, name, color in classes]
        self._log_arrays(WORLD, {"AnnotationContext:context": pa.array(
            [rows], type=self._s.t["AnnotationContext:context"])})
        self._context_logged = True

    def _log_arrays(self, path: str, comps: dict[str, pa.Array], static: bool = False) -> None:
        """``rr.log`` of ready Arrow arrays (one row), skipping the archetype constructors."""
        d = self._s.d
        self._rec.log(path, [_Batch(d[k], arr) for k, arr in comps.items()], static=static,
                      strict=True)

    def _event(self, text: str, level: str = "INFO") -> None:
        self._log_arrays(EVENTS, {"TextLog:text": pa.array([text], type=pa.string()),
                                  "TextLog:level": pa.array([level], type=pa.string())})

    def _track_path(self, label: str) -> str:
        path = self._paths.get(label)
        if path is None:
            path = self._paths[label] = f"{TRACKS}/{_escape(label)}"
        return path

    def _labels_changed(self, k: int, t: int, labels: tuple[str, ...]) -> None:
        """Births and ends of labels: styles, clears, events, annotation context."""
        now = set(labels)
        born = [lab for lab in labels if lab not in self._live]
        ended = sorted(self._live - now, key=self._class.__getitem__)
        self._at(k, t)
        for lab in ended:
            self._clears.append((self._track_path(lab), k, t))
            self._event(f"track {self._names[lab]} ended (label {lab}, last seen at frame {self._prev_frame})")
        taken = [_unpack(self._colors[o]) for o in labels if o in self._live]
        for lab in born:
            name = self._names.get(lab)
            if name is None:  # T1, T2, ... in order of confirmation; kept if the label comes back
                name = self._names[lab] = f"T{len(self._names) + 1}"
            self._class[lab] = self._next_class
            self._next_class = (FIRST_LABEL_CLASS if self._next_class >= _MAX_CLASS
                                else self._next_class + 1)
            rgba = label_color(lab, taken)
            taken.append(rgba)
            packed = _pack(rgba)
            if self._colors.get(lab) != packed:  # static style: fixed for the label's life
                self._colors[lab] = packed
                self._log_arrays(self._track_path(lab), {
                    "Points2D:colors": pa.array([packed], type=pa.uint32()),
                    "Points2D:labels": pa.array([name], type=pa.string()),
                    "Points2D:radii": pa.array([R_TRACK], type=pa.float32()),
                    "Points2D:show_labels": pa.array([True], type=pa.bool_()),
                    "Points2D:draw_order": pa.array([5.0], type=pa.float32()),
                    "LineStrips2D:colors": pa.array([packed, (packed & 0xFFFFFF00) | 170], type=pa.uint32()),
                    "LineStrips2D:radii": pa.array([R_TRAIL, R_ELLIPSE], type=pa.float32()),
                    "LineStrips2D:show_labels": pa.array([False], type=pa.bool_()),
                    "LineStrips2D:draw_order": pa.array([4.0], type=pa.float32()),
                }, static=True)
            self._event(f"track {name} born (label {lab})")
        self._live = now
        if born:  # new classes: re-log the context, with the live labels only
            self._class = {lab: self._class[lab] for lab in labels}
            self._colors = {lab: self._colors[lab] for lab in labels}
            self._log_context()

    def _truth_changed(self, k: int, t: int, ids: tuple[str, ...]) -> None:
        now = set(ids)
        self._at(k, t)
        for gone in sorted(self._truth_live - now):
            self._event(f"truth {gone} ended (last seen at frame {self._prev_frame})", level="DEBUG")
        for new in ids:
            if new not in self._truth_live:
                self._event(f"truth {new} born", level="DEBUG")
        self._truth_live = now

    def _log_scalars(self, k: int, t: int, frame: Frame, estimate: Estimate,
                     ospa: OspaResult | None, ospa2: float | None,
                     health: Mapping[str, float] | None) -> None:
        keep = self._scalars
        n_est = float(len(estimate.tracks))
        card = [n_est, float(len(frame.truth.ids))] if frame.truth is not None else [n_est]
        keep.setdefault(CARDINALITY, []).append((k, t, card))
        if ospa is not None:
            keep.setdefault(OSPA, []).append(
                (k, t, [float(ospa.total), float(ospa.localisation), float(ospa.cardinality)]))
        if ospa2 is not None:
            keep.setdefault(OSPA2, []).append((k, t, [float(ospa2)]))
        paths = self._paths
        for key, value in estimate.diagnostics.items():
            entity = paths.get(("diag", key))
            if entity is None:
                entity = paths[("diag", key)] = f"{DIAGNOSTICS}/{_escape(str(key))}"
                if entity not in self._styled:
                    self._series_style(entity, [str(key)], [(120, 190, 255)])
            keep.setdefault(entity, []).append((k, t, [float(value)]))
        if health:
            for key, value in health.items():
                entity = paths.get(("health", key))
                if entity is None:
                    entity = paths[("health", key)] = f"{HEALTH}/{_escape(str(key))}"
                    self._series_style(entity, [str(key)], [label_color(str(key))[:3]])
                keep.setdefault(entity, []).append((k, t, [float(value)]))

    # -- columnar send -------------------------------------------------------------------
    def _send(self, path: str, ks: np.ndarray, ts: np.ndarray,
              comps: list[tuple[str, pa.Array, np.ndarray]]) -> None:
        """One chunk: rows at frames ``ks`` / stamps ``ts``; ``comps`` = (key, flat array,
        per-row instance counts)."""
        offs = []
        for _key, _arr, counts in comps:
            o = np.zeros(len(counts) + 1, dtype=np.int32)
            np.cumsum(counts, out=o[1:])
            offs.append(o)
        ks = np.asarray(ks, dtype=np.int64)
        stamps = np.asarray(ts, dtype=np.int64).astype("datetime64[ns]")
        cols = [rr.ComponentColumn(self._s.d[key], _Batch(self._s.d[key], arr), offsets=o)
                for (key, arr, _c), o in zip(comps, offs)]
        self._rec.send_columns(
            path,
            indexes=[rr.TimeColumn("frame", sequence=ks), rr.TimeColumn("stamp", timestamp=stamps)],
            columns=cols,
            strict=True,
        )

    def _send_kept(self) -> None:
        """Turn the kept frames into one chunk per entity and send them."""
        frames, self._frames = self._frames, []
        scalars, self._scalars = self._scalars, {}
        clears, self._clears = self._clears, []
        if frames:
            self._send_tracks(frames, clears)
            self._send_measurements(frames)
            self._send_truth(frames)
        s = self._s
        for entity, rows in scalars.items():
            ks = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
            ts = np.fromiter((r[1] for r in rows), dtype=np.int64, count=len(rows))
            vals = [r[2] for r in rows]
            flat = pa.array([v for row in vals for v in row], type=pa.float64())
            self._send(entity, ks, ts, [("Scalars:scalars", flat, np.array([len(v) for v in vals]))])
        for path, k, t in clears:
            self._send(path, np.array([k]), np.array([t]),
                       [("Clear:is_recursive", pa.array([True], type=pa.bool_()), np.array([1]))])
        del s

    def _send_tracks(self, frames: list[_Rec], clears: list[tuple[str, int, int]]) -> None:
        s = self._s
        # group the kept frames by label, in order
        per: dict[str, tuple[list[int], list[int], list[np.ndarray], list[np.ndarray]]] = {}
        for r in frames:
            for i, lab in enumerate(r.labels):
                g = per.get(lab)
                if g is None:
                    g = per[lab] = ([], [], [], [])
                g[0].append(r.k)
                g[1].append(r.t)
                g[2].append(r.pos[i])
                g[3].append(r.cov[i])
        # a label that ended (Clear) and came back starts a new trail after the clear
        cleared: dict[str, list[int]] = {}
        for path, k, _t in clears:
            cleared.setdefault(path, []).append(k)
        keep = self.trail - 1
        Le = self._circle.shape[0]
        for lab, (ks, ts, ps, cs) in per.items():
            path = self._track_path(lab)
            P = np.array(ps)
            W = P.shape[0]
            kk = np.asarray(ks, dtype=np.int64)
            hist = self._history.get(lab, _EMPTY2)
            H = hist.shape[0]
            full = np.concatenate([hist, P]) if H else P
            ends = H + np.arange(W) + 1
            starts = np.maximum(ends - self.trail, 0)
            lo = 0
            for c in sorted(cleared.get(path, ())):
                first = int(np.searchsorted(kk, c))  # first row at or after the clear
                lo = H + first
                starts[first:] = np.maximum(starts[first:], lo)
            ell = _ellipses(P, np.array(cs), self._circle, ELLIPSE_SIGMA).reshape(-1, 2)
            # two strips per row, [trail, ellipse], gathered from concat(full, ell)
            base = full.shape[0]
            st = np.empty(2 * W, dtype=np.int64)
            en = np.empty(2 * W, dtype=np.int64)
            st[0::2], en[0::2] = starts, ends
            st[1::2] = base + np.arange(W) * Le
            en[1::2] = st[1::2] + Le
            pts, lengths = _gather(np.concatenate([full, ell]), st, en)
            self._send(path, kk, np.asarray(ts), [
                ("Points2D:positions", s.positions(P), np.ones(W, dtype=np.int64)),
                ("LineStrips2D:strips", s.strip_array(pts, lengths), np.full(W, 2)),
            ])
            self._history[lab] = full[max(base - keep, lo):] if keep else _EMPTY2
        for lab in [lab for lab in self._history if lab not in self._live]:
            del self._history[lab]

    def _measurement_model(self, kind: str) -> Any:
        model = self._meas_models.get(kind)
        if model is None:
            if self._params is not None:
                model = self._params.measurement(kind)
            else:
                from tracker.models.measurement import measurement_kind

                model = measurement_kind(kind).model()
            self._meas_models[kind] = model
        return model

    def _send_measurements(self, frames: list[_Rec]) -> None:
        """Measurements, measurement->track lines and (range-only) rings of all kept frames."""
        s = self._s
        for kind in dict.fromkeys(r.kind for r in frames):
            rows = [r for r in frames if r.kind == kind]
            ks = np.array([r.k for r in rows], dtype=np.int64)
            ts = np.array([r.t for r in rows], dtype=np.int64)
            counts = np.array([r.z.shape[0] for r in rows], dtype=np.int64)
            ntr = np.array([r.pos.shape[0] for r in rows], dtype=np.int64)
            Z = np.concatenate([r.z for r in rows])
            tpos = np.concatenate([r.pos for r in rows])
            tcls = np.concatenate([r.tcls for r in rows])
            tcol = np.concatenate([r.tcol for r in rows])
            has = np.repeat(np.array([r.idx is not None for r in rows]), counts)
            idx = np.concatenate([r.idx if r.idx is not None else np.full(r.z.shape[0], -1)
                                  for r in rows]).astype(np.int64)
            tr_off = np.concatenate([[0], np.cumsum(ntr)[:-1]])
            hit = idx >= 0
            gidx = np.where(hit, idx + np.repeat(tr_off, counts), 0)
            model = self._measurement_model(kind)
            sx, sy = float(getattr(model, "sensor_x", 0.0)), float(getattr(model, "sensor_y", 0.0))
            if kind != "range":  # bearing_range, xy: the measured position
                xy = model.to_cartesian(Z)[0] if Z.shape[0] else _EMPTY2
            else:
                # range-only: the point of the range ring nearest the assigned track, else on
                # the boresight (+y); the rings themselves go to world/measurements/rings
                r_ = Z[:, 0]
                ang = np.zeros(Z.shape[0])
                if hit.any():
                    tp = tpos[gidx[hit]]
                    ang[hit] = np.arctan2(tp[:, 0] - sx, tp[:, 1] - sy)
                xy = np.stack([sx + r_ * np.sin(ang), sy + r_ * np.cos(ang)], axis=-1)
            cls = np.where(hit, tcls[gidx] if tcls.size else 0,
                           np.where(has, CLUTTER_CLASS, UNASSIGNED_CLASS)).astype(np.uint16)
            col = np.where(hit, tcol[gidx] if tcol.size else 0,
                           np.where(has, _pack(GREY_CLUTTER), _pack(WHITE_UNASSIGNED))).astype(np.uint32)
            radii = np.where(hit, R_MEAS_ASSIGNED, R_MEAS_CLUTTER).astype(np.float32)
            self._send(MEASUREMENTS, ks, ts, [
                ("Points2D:positions", s.positions(xy), counts),
                ("Points2D:class_ids", pa.array(cls, type=pa.uint16()), counts),
                ("Points2D:colors", pa.array(col, type=pa.uint32()), counts),
                ("Points2D:radii", pa.array(radii, type=pa.float32()), counts),
            ])
            # measurement -> track lines
            nh = int(hit.sum())
            lines = np.empty((nh, 2, 2))
            lines[:, 0] = xy[hit]
            lines[:, 1] = tpos[gidx[hit]] if nh else lines[:, 1]
            hits_per_row = np.add.reduceat(hit, np.concatenate([[0], np.cumsum(counts)[:-1]])) \
                if Z.shape[0] else np.zeros(len(rows), dtype=np.int64)
            hits_per_row = np.where(counts > 0, hits_per_row, 0)
            self._send(ASSIGNMENTS, ks, ts, [
                ("LineStrips2D:strips", s.strip_array(lines.reshape(-1, 2), np.full(nh, 2)), hits_per_row),
                ("LineStrips2D:colors", pa.array((col[hit] & np.uint32(0xFFFFFF00)) | np.uint32(150),
                                                 type=pa.uint32()), hits_per_row),
                ("LineStrips2D:class_ids", pa.array(cls[hit], type=pa.uint16()), hits_per_row),
            ])
            if kind == "range":
                if RINGS not in self._styled:
                    self._rec.log(RINGS, rr.LineStrips2D.from_fields(
                        radii=[R_RING], show_labels=False, draw_order=0.5), static=True)
                    self._styled.add(RINGS)
                a = self._arc
                r_ = Z[:, 0]
                arcs = np.stack([sx + r_[:, None] * np.sin(a)[None], sy + r_[:, None] * np.cos(a)[None]], -1)
                self._send(RINGS, ks, ts, [
                    ("LineStrips2D:strips", s.strip_array(arcs.reshape(-1, 2), np.full(Z.shape[0], a.size)),
                     counts),
                    ("LineStrips2D:colors", pa.array((col & np.uint32(0xFFFFFF00)) | np.uint32(90),
                                                     type=pa.uint32()), counts),
                    ("LineStrips2D:class_ids", pa.array(cls, type=pa.uint16()), counts),
                ])

    def _send_truth(self, frames: list[_Rec]) -> None:
        """Grey crosses and trails of the true objects of the kept frames that have truth."""
        s = self._s
        rows = [r for r in frames if r.truth_ids is not None]
        if not rows:
            return
        ks = np.array([r.k for r in rows], dtype=np.int64)
        ts = np.array([r.t for r in rows], dtype=np.int64)
        counts = np.array([len(r.truth_ids) for r in rows], dtype=np.int64)
        TP = np.concatenate([r.truth_pos for r in rows])
        h = self._cross
        n = TP.shape[0]
        cross = np.empty((n, 2, 2, 2))
        cross[:, 0, 0] = TP + (-h, -h)
        cross[:, 0, 1] = TP + (h, h)
        cross[:, 1, 0] = TP + (-h, h)
        cross[:, 1, 1] = TP + (h, -h)
        labels = pa.array([f"truth {tid}" for r in rows for tid in r.truth_ids for _ in (0, 1)],
                          type=pa.string())
        self._send(TRUTH, ks, ts, [
            ("LineStrips2D:strips", s.strip_array(cross.reshape(-1, 2), np.full(2 * n, 2)), 2 * counts),
            ("LineStrips2D:labels", labels, 2 * counts),
        ])
        # trails: per object, its positions (with the history from before) -> per row slices
        per: dict[str, list[np.ndarray]] = {}
        for r in rows:
            for tid, p in zip(r.truth_ids, r.truth_pos):
                per.setdefault(tid, []).append(p)
        full: dict[str, np.ndarray] = {}
        seen: dict[str, int] = {}
        base: dict[str, int] = {}
        blocks, off = [], 0
        for tid, ps in per.items():
            hist = self._truth_history.get(tid, _EMPTY2)
            f = np.concatenate([hist, np.array(ps)]) if hist.shape[0] else np.array(ps)
            full[tid], seen[tid], base[tid] = f, hist.shape[0], off
            blocks.append(f)
            off += f.shape[0]
        st, en = [], []
        for r in rows:
            for tid in r.truth_ids:
                e = seen[tid] + 1
                seen[tid] = e
                st.append(base[tid] + max(e - self.trail, 0))
                en.append(base[tid] + e)
        pts, lengths = _gather(np.concatenate(blocks), np.array(st, dtype=np.int64), np.array(en, dtype=np.int64))
        self._send(TRUTH_TRAILS, ks, ts, [("LineStrips2D:strips", s.strip_array(pts, lengths), counts)])
        keep = self.trail - 1
        live = set(rows[-1].truth_ids)
        self._truth_history = {tid: f[max(f.shape[0] - keep, 0):] for tid, f in full.items()
                               if tid in live and keep} if keep else {}

# --------------------------------------------------------------------------- helpers


def _ellipses(center: np.ndarray, cov: np.ndarray, circle: np.ndarray, k: float) -> np.ndarray:
    """``(n, K, 2)`` polygons of the ``k``-sigma ellipses ``{c + k L u : |u| = 1}``, ``L L^T = P``.

    ``L`` is the closed-form Cholesky factor of each ``2 x 2`` covariance (any square root
    traces the same ellipse); a non-positive-definite input is clipped to semidefinite.
    """
    a = np.maximum(cov[:, 0, 0], 0.0)
    b = 0.5 * (cov[:, 0, 1] + cov[:, 1, 0])
    c = np.maximum(cov[:, 1, 1], 0.0)
    l11 = np.sqrt(a)
    l21 = np.divide(b, l11, out=np.zeros_like(b), where=l11 > 0)
    l22 = np.sqrt(np.maximum(c - l21 * l21, 0.0))
    u, v = k * circle[:, 0], k * circle[:, 1]  # (K,)
    out = np.empty((cov.shape[0], circle.shape[0], 2))
    out[:, :, 0] = center[:, 0, None] + l11[:, None] * u[None]
    out[:, :, 1] = center[:, 1, None] + l21[:, None] * u[None] + l22[:, None] * v[None]
    return out


def _gather(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Concatenation of ``points[starts[i]:ends[i]]`` for all ``i`` and the segment lengths."""
    lengths = (ends - starts).astype(np.int64)
    offsets = np.zeros(lengths.size + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    idx = np.arange(offsets[-1]) - np.repeat(offsets[:-1] - starts, lengths)
    return points[idx], lengths


def _fov_bounds(range_max: float, half_fov: float) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) box around the sensor's field of view, with a 5% margin."""
    a = np.linspace(-half_fov, half_fov, 181)
    xs = np.concatenate([[0.0], range_max * np.sin(a)])
    ys = np.concatenate([[0.0], range_max * np.cos(a)])
    m = 0.05 * range_max
    return float(xs.min() - m), float(xs.max() + m), float(ys.min() - m), float(ys.max() + m)


def _escape(part: str) -> str:
    """One entity-path part (labels like ``10.3`` are fine; escape anything unusual)."""
    if part and all(ch.isalnum() or ch in "._-" for ch in part):
        return part
    return rr.escape_entity_path_part(part)


def _ident(key: str) -> str:
    out = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in key)
    return out if out and not out[0].isdigit() else f"k_{out}"


def _md(value: str) -> str:
    return value.replace("|", "\\|").replace("\n", " ")


def _version(dist: str) -> str:
    try:
        from importlib.metadata import version

        return version(dist)
    except Exception:  # pragma: no cover - not installed
        return "unknown"


# --------------------------------------------------------------------------- convenience


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
