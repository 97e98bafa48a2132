"""Plain data types that flow through bnptrack: frames in, estimates out.

Every stage (offline ``bnptrack track``, the Zenoh pipeline, Monte Carlo experiments)
passes the same few types, so the same tracker code runs everywhere.  They are frozen
dataclasses over plain numpy arrays; arrays are batch-first (``(M, d)``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from bnptrack.tracker.models.measurement import KINDS

#: The registry's kinds (:data:`tracker.models.measurement.KINDS`) as a type, for readers;
#: ``Frame`` checks a kind against the registry itself, so a kind registered later is valid.
SensorKind = Literal[tuple(KINDS)]  # type: ignore[valid-type]

def display_name(label: str) -> str:
    """The one name a track is shown by -- in the Rerun recording, ``track``'s summary, the
    ``export`` tables, the Foxglove scene and the Python API (:attr:`TrackEstimate.name`): a
    pure function of its internal label, so it is the same in every reader, for the track's
    whole life and across a resumed run.

    The trackers' labels ``"<birth frame>.<tag>"`` (the frame the track was born at and the
    measurement or hypothesis that started it) read ``T<birth frame>.<tag>``: ``"26.0"`` ->
    ``"T26.0"``, ``"2.z4"`` -> ``"T2.z4"``.  Any other label is shown as it is.
    """
    head, dot, tail = label.partition(".")
    if dot and head.isdigit() and tail.isalnum():
        return f"T{label}"
    return label


#: Object state layout used everywhere: ``[px, vx, py, vy, omega]``.
STATE_DIM = 5
POSITION_INDEX = (0, 2)


@dataclass(frozen=True)
class Truth:
    """Ground-truth objects present at one frame.

    ``ids`` are stable object identifiers (strings); ``states`` is ``(N, 5)``.
    """

    ids: tuple[str, ...]
    states: np.ndarray

    def __post_init__(self) -> None:
        states = np.asarray(self.states, dtype=float).reshape(-1, STATE_DIM)
        object.__setattr__(self, "states", states)
        if len(self.ids) != states.shape[0]:
            raise ValueError(
                f"Truth: {len(self.ids)} ids but {states.shape[0]} states"
            )

    @property
    def positions(self) -> np.ndarray:
        """``(N, 2)`` positions ``[px, py]``."""
        return self.states[:, POSITION_INDEX]


def check_finite_rows(frame: int, z: np.ndarray) -> None:
    """Raise ``ValueError`` naming the frame and the first measurement row with a NaN or inf.

    A non-finite measurement would poison every moment-matched track update downstream, so it
    is refused at the edge; the pipeline's codec refuses it earlier still (a rejected sample).
    """
    bad = ~np.isfinite(z).all(axis=1)
    if bad.any():
        m = int(np.argmax(bad))
        raise ValueError(f"Frame {frame}: measurement row {m} is not finite: {z[m].tolist()}"
                         f" ({int(bad.sum())} such row(s))")


def check_covariance(frame: int, R, d: int) -> np.ndarray:
    """``R`` as a ``(d, d)`` symmetric positive-definite array, or ``ValueError`` naming the frame."""
    R = np.asarray(R, dtype=float)
    if R.shape != (d, d) or not np.isfinite(R).all():
        raise ValueError(f"Frame {frame}: R must be a finite {d}x{d} matrix, got shape {R.shape}")
    if not np.allclose(R, R.T, rtol=1e-9, atol=0.0) or np.any(np.linalg.eigvalsh(0.5 * (R + R.T)) <= 0):
        raise ValueError(f"Frame {frame}: R must be symmetric positive definite")
    return 0.5 * (R + R.T)


@dataclass(frozen=True)
class Frame:
    """One scan of measurements from one sensor.

    Attributes
    ----------
    frame:
        Frame (scan) index, increasing by one per scan.
    stamp_ns:
        Sensor time stamp in nanoseconds.
    sensor:
        Sensor name (free text, e.g. ``"radar0"``).
    kind:
        A measurement kind of the registry :data:`tracker.models.measurement.KINDS`, which
        gives its row layout (e.g. ``"bearing_range"``: ``z = [bearing_rad, range_m]``,
        ``"range"``: ``z = [range_m]``, ``"xy"``: ``z = [x_m, y_m]`` in the world frame).
    z:
        ``(M, d)`` measurements in arrival order; ``d`` follows ``kind``.  Every entry must be
        finite: construction raises ``ValueError`` naming the frame and the row otherwise.
    truth:
        Ground truth at this frame when the source has it, else ``None``.
    pose:
        ``(x, y, heading)`` of the sensor for this scan (m, m, rad; heading from +y towards
        +x), or ``None``: the parameter set's ``[sensors.NAME]`` table (or the default sensor).
    R:
        ``(d, d)`` measurement noise covariance of this scan's rows, or ``None``.
    """

    frame: int
    stamp_ns: int
    sensor: str
    kind: SensorKind
    z: np.ndarray
    truth: Truth | None = None
    pose: tuple[float, float, float] | None = None
    R: np.ndarray | None = None

    def __post_init__(self) -> None:
        entry = KINDS.get(self.kind) if isinstance(self.kind, str) else None
        if entry is None:
            raise ValueError(f"Frame {self.frame}: unknown sensor kind {self.kind!r} (known: {', '.join(KINDS)})")
        d = entry.dim
        z = np.asarray(self.z, dtype=float).reshape(-1, d)
        check_finite_rows(self.frame, z)
        object.__setattr__(self, "z", z)
        self._check_pose_r(d)

    @classmethod
    def checked(cls, frame: int, stamp_ns: int, sensor: str, kind: str, z: np.ndarray,
                truth: Truth | None = None, pose: tuple[float, float, float] | None = None,
                R: np.ndarray | None = None) -> Frame:
        """A frame of data already checked at the edge: the codec's :func:`tracker.messages.decode`
        (:func:`tracker.messages.to_frame` builds its frames here).  ``kind`` must be a kind of
        the registry and ``z`` a float64 ``(M, d)`` array of finite values of that kind: they
        are taken as they are, not checked a second time (the constructor's check of ``z``
        costs about 140 us on a paced pipeline's frame path: docs/pipeline.md,
        "Latency").  ``pose`` and ``R`` are checked and normalised as by the constructor.
        Anything not checked by the codec goes through ``Frame(...)``."""
        self = object.__new__(cls)
        self.__dict__.update(frame=frame, stamp_ns=stamp_ns, sensor=sensor, kind=kind, z=z, truth=truth,
                             pose=pose, R=R)
        if pose is not None or R is not None:
            self._check_pose_r(KINDS[kind].dim)
        return self

    def _check_pose_r(self, d: int) -> None:
        """Check ``pose`` (3 finite numbers, stored as a tuple of floats) and ``R`` (a ``(d, d)``
        symmetric positive-definite matrix, stored symmetrised)."""
        if self.pose is not None:
            pose = tuple(float(v) for v in self.pose)
            if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
                raise ValueError(f"Frame {self.frame}: pose must be 3 finite numbers [x, y, heading], got {self.pose!r}")
            object.__setattr__(self, "pose", pose)
        if self.R is not None:
            object.__setattr__(self, "R", check_covariance(self.frame, self.R, d))

    @property
    def n_measurements(self) -> int:
        return int(self.z.shape[0])


@dataclass(frozen=True)
class TrackEstimate:
    """One labelled object estimate: label, mean ``(5,)``, covariance ``(5, 5)``, existence,
    and (two-level trackers only) ``cluster``: the id of the object's motion cluster."""

    label: str
    state: np.ndarray
    covariance: np.ndarray
    existence: float
    cluster: int | None = None

    @property
    def position(self) -> np.ndarray:
        return self.state[list(POSITION_INDEX)]

    @property
    def name(self) -> str:
        """The track's display name (:func:`display_name` of its label)."""
        return display_name(self.label)


@dataclass(frozen=True)
class Estimate:
    """A tracker's output for one frame.

    ``assignments[m]`` is the label measurement ``m`` was assigned to (``None`` for clutter)
    and ``assignment_prob[m]`` its posterior probability; ``diagnostics`` holds scalar
    tracker diagnostics (alpha, d, number of clusters, log-likelihood, ms per frame);
    ``cardinality_pmf`` the posterior cardinality distribution ``p(n)``, ``n = 0 .. N_max``
    (``(N_max + 1,)``, tail below 1e-9 dropped: :mod:`tracker.cardinality`), or ``None``;
    ``lag`` the scans of hindsight (0: the online estimate; ``N``: a fixed-lag output,
    :mod:`tracker.lag`, made when frame ``frame + N`` had arrived).
    """

    frame: int
    stamp_ns: int
    tracks: tuple[TrackEstimate, ...]
    assignments: tuple[str | None, ...] = ()
    assignment_prob: tuple[float, ...] = ()
    diagnostics: dict[str, float] = field(default_factory=dict)
    cardinality_pmf: np.ndarray | None = None
    lag: int = 0

    @property
    def positions(self) -> np.ndarray:
        """``(N, 2)`` estimated positions."""
        if not self.tracks:
            return np.zeros((0, 2))
        return np.stack([t.position for t in self.tracks])

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(t.label for t in self.tracks)


# --------------------------------------------------------------------------- frame bounds


class FrameBoundError(ValueError):
    """A frame advances beyond :class:`FrameBounds` (or does not advance at all)."""


@dataclass(frozen=True)
class FrameBounds:
    """How far one frame may advance past the previous one.

    A tracker predicts once over the time since the previous frame (:func:`frame_dt`), but an
    unbounded jump (a corrupt or forged frame number, e.g. 10^9) still means a corrupt frame
    (a covariance grown by years of process noise).  Each frame must come after the previous one by at most ``max_frame_gap``
    frame numbers, and its time stamp may not go back nor advance by more than ``max_gap_s``
    seconds.  The first frame of a stream is not bounded.
    """

    max_frame_gap: int = 1000
    max_gap_s: float = 3600.0
    #: skipped frames that agree with each other after which the stream resynchronises
    #: (:class:`FrameGate`); 0: never
    resync_frames: int = 10

    def __post_init__(self) -> None:
        if self.max_frame_gap < 1 or not self.max_gap_s > 0 or self.resync_frames < 0:
            raise ValueError("max_frame_gap must be >= 1, max_gap_s > 0 and resync_frames >= 0")

    def violation(self, prev_frame: int, prev_stamp_ns: int | None, frame: int, stamp_ns: int) -> str | None:
        """Why ``(frame, stamp_ns)`` may not follow ``(prev_frame, prev_stamp_ns)``, or ``None``.
        ``prev_frame < 0``: no previous frame; ``prev_stamp_ns`` ``None``: its stamp is unknown."""
        if prev_frame < 0:
            return None
        if frame <= prev_frame:
            return f"frame {frame} is not after the last processed frame {prev_frame}"
        if frame - prev_frame > self.max_frame_gap:
            return (f"frame {frame} jumps {frame - prev_frame} frames after frame {prev_frame} "
                    f"(more than max_frame_gap = {self.max_frame_gap})")
        if prev_stamp_ns is None:
            return None
        dt = (stamp_ns - prev_stamp_ns) / 1e9
        if dt < 0:
            return f"frame {frame}: time stamp {stamp_ns} ns is before that of frame {prev_frame} ({prev_stamp_ns} ns)"
        if dt > self.max_gap_s:
            return (f"frame {frame}: time stamp {dt:.6g} s after frame {prev_frame} "
                    f"(more than max_gap_s = {self.max_gap_s:g})")
        return None


@dataclass
class FrameGate:
    """The one rule of ``track`` and the pipeline's tracker and sink for frames beyond the
    :class:`FrameBounds` (a number that does not advance or jumps, a stamp that goes back or
    jumps): such a frame is skipped (not tracked, not recorded) and the stream goes on with
    the frames after it, compared with the last admitted frame.  A genuine jump (a log that
    resumes after a long pause, a renumbering) makes every later frame break the bounds:
    after ``resync_frames`` skipped frames each within the bounds of the one before it, the
    next such frame is admitted and the bounds count from it; the tracker starts again from
    its initial state there (``resynced``: no prediction over the jump).  Plain state
    (snapshot-able): the last admitted frame and the run of skipped frames."""

    bounds: FrameBounds = FrameBounds()
    last_frame: int = -1
    last_stamp_ns: int | None = None
    chain: int = 0
    chain_frame: int = -1
    chain_stamp_ns: int | None = None
    resynced: bool = False  # whether the last admitted frame resynchronised the stream

    def admit(self, frame: int, stamp_ns: int) -> str | None:
        """``None`` when the frame is admitted (it becomes the last frame), else why it is
        skipped."""
        why = self.bounds.violation(self.last_frame, self.last_stamp_ns, frame, stamp_ns)
        self.resynced = why is not None
        if why is not None:
            follows = self.chain > 0 and self.bounds.violation(self.chain_frame, self.chain_stamp_ns,
                                                               frame, stamp_ns) is None
            if not (follows and 0 < self.bounds.resync_frames <= self.chain):
                self.chain = self.chain + 1 if follows else 1
                self.chain_frame, self.chain_stamp_ns = frame, stamp_ns
                self.resynced = False
                return why
        self.last_frame, self.last_stamp_ns, self.chain = frame, stamp_ns, 0
        return None

    def state(self) -> tuple[int, int, int | None]:
        """The run of skipped frames (for a snapshot; :meth:`restore`)."""
        return self.chain, self.chain_frame, self.chain_stamp_ns

    def restore(self, last_frame: int, last_stamp_ns: int | None, chain: tuple = (0, -1, None)) -> None:
        self.last_frame, self.last_stamp_ns = last_frame, last_stamp_ns
        self.chain, self.chain_frame, self.chain_stamp_ns = int(chain[0]), int(chain[1]), chain[2]


def gated_segments(frames: Iterable[Frame], gate: FrameGate,
                   skipped: list[tuple[int, str]]) -> Iterator[Iterator[Frame]]:
    """The frames that ``gate`` admits, as segments that each start a tracker afresh (a new
    segment at each resynchronisation); each skipped frame is appended to ``skipped`` as
    ``(frame number, why)``.  Consume each segment before the next."""
    it = iter(frames)
    pending: list[Frame] = []

    def segment(first: Frame | None) -> Iterator[Frame]:
        if first is not None:
            yield first
        for f in it:
            why = gate.admit(f.frame, f.stamp_ns)
            if why is not None:
                skipped.append((f.frame, why))
            elif gate.resynced:
                pending.append(f)
                return
            else:
                yield f

    first = None
    while True:
        yield segment(first)
        if not pending:
            return
        first = pending.pop()


def bounded_frames(frames: Iterable[Frame], bounds: FrameBounds = FrameBounds()) -> Iterator[Frame]:
    """``frames``, raising :class:`FrameBoundError` at the first frame that breaks ``bounds``
    (before it reaches a tracker)."""
    prev_frame, prev_stamp = -1, None
    for f in frames:
        why = bounds.violation(prev_frame, prev_stamp, f.frame, f.stamp_ns)
        if why is not None:
            raise FrameBoundError(why)
        prev_frame, prev_stamp = f.frame, f.stamp_ns
        yield f


# --------------------------------------------------------------------------- time between frames


def frame_dt(prev_frame: int, prev_stamp_ns: int, frame: int, stamp_ns: int, T: float) -> float:
    r"""Seconds to predict over from the last processed frame to this one.

    * Time stamps are used when present: :math:`\Delta t = (\text{stamp} - \text{stamp}_{prev})
      / 10^9`, so irregular intervals and dropped frames are handled.  A stamp difference
      equal, to the nanosecond, to ``(frame - prev_frame) * T`` gives exactly
      ``(frame - prev_frame) * T`` (the simulator's stamps are ``round(k T 10^9)``, so its
      logs predict with the same floats as over frame numbers).
    * Stamps are "absent" when both are 0 (logs that carry none): then
      :math:`\Delta t = (\text{frame} - \text{frame}_{prev})\, T`.
    * Before the first frame (``prev_frame < 0``) the interval is ``T`` (nothing to predict).

    Raises :class:`FrameBoundError` when the stamp goes back in time (frames out of order).
    Equal stamps (two sensors scanning at the same instant) give :math:`\Delta t = 0`.
    """
    steps = 1 if prev_frame < 0 else frame - prev_frame
    if prev_frame < 0 or (prev_stamp_ns == 0 and stamp_ns == 0):
        return steps * T
    why = FrameBounds(max_frame_gap=max(steps, 1), max_gap_s=math.inf).violation(
        prev_frame, prev_stamp_ns, frame, stamp_ns)
    if why is not None:
        raise FrameBoundError(why)
    d_ns = int(stamp_ns) - int(prev_stamp_ns)
    if d_ns == steps * int(round(T * 1e9)):
        return steps * T
    return d_ns / 1e9
