"""Versioned JSON wire/log schema for bnptrack messages (a public contract).

Three messages, each a JSON object, used both on the Zenoh bus and in MCAP logs:

``/measurements`` (:class:`MeasurementsMsg`)::

    {"v": 2, "run": "", "frame": 0, "stamp_ns": 0, "sensor": "radar0",
     "kind": "bearing_range", "z": [[bearing_rad, range_m], ...]}

  (``kind == "range"``: ``"z": [[range_m], ...]``).  ``v`` and ``run`` are optional on
  decode (default ``1`` and ``""``) so logs that carry only the five core fields decode.

``/truth`` (:class:`TruthMsg`)::

    {"v": 2, "run": "", "frame": 0, "stamp_ns": 0,
     "objects": [{"id": "obj0", "state": [px, vx, py, vy, omega]}, ...]}

``/tracks`` (:class:`TracksMsg`)::

    {"v": 2, "run": "", "frame": 0, "stamp_ns": 0,
     "tracks": [{"label": "t1", "state": [5 floats], "covariance": [25 floats, row-major],
                 "existence": 0.97}, ...],
     "assignments": ["t1", null, ...],          # one per measurement, input order
     "assignment_prob": [0.93, 0.71, ...],      # one per measurement
     "diagnostics": {"alpha": 1.2, ...}}        # optional, default {}

Validation beyond the JSON types (all errors are :class:`CodecError`, naming topic, frame
and the JSON path): finite floats only, ``frame >= 0``, ``0 <= stamp_ns < 2**63``,
``z`` rows of length 2 (``bearing_range``) or 1 (``range``), ``range >= 0``,
``bearing`` in ``[-pi, pi]``, state length 5, covariance length 25, existence and
probabilities in ``[0, 1]``, ``len(assignments) == len(assignment_prob)``, unique truth
ids / track labels, size limits (:data:`MAX_MEASUREMENTS`, :data:`MAX_TRACKS`,
:data:`MAX_OBJECTS`), and ``v`` in :data:`READABLE_VERSIONS` (anything else: "unsupported schema
version").  Unknown fields are rejected: a change of fields is a new schema version.

Encoding validates too (a NaN would otherwise be written as ``null`` by msgspec).
This module must stay importable without zenoh.
"""

from __future__ import annotations

import math
import re
import sys
from itertools import chain
from typing import Annotated, Any, Literal, Union

import msgspec
import numpy as np

from tracker.models.measurement import KINDS
from tracker.types import (
    MEASUREMENT_DIM,
    STATE_DIM,
    Estimate,
    Frame,
    TrackEstimate,
    Truth,
)

__all__ = [
    "SCHEMA_VERSION",
    "MEASUREMENTS_SCHEMA_VERSION",
    "TRACKS_SCHEMA_VERSION",
    "TOPIC_MEASUREMENTS",
    "TOPIC_TRUTH",
    "TOPIC_TRACKS",
    "MAX_MEASUREMENTS",
    "MAX_TRACKS",
    "MAX_OBJECTS",
    "MAX_DIAGNOSTICS",
    "CodecError",
    "MeasurementsMsg",
    "TruthObject",
    "TruthMsg",
    "TrackMsg",
    "TracksMsg",
    "MSG_TYPES",
    "encode_measurements",
    "decode_measurements",
    "decode_measurements_msg",
    "encode_truth",
    "decode_truth",
    "decode_truth_msg",
    "encode_tracks",
    "decode_tracks",
    "decode_tracks_msg",
    "decode_msg",
    "encode_msg",
    "validate_msg",
    "measurements_msg",
    "truth_msg",
    "tracks_msg",
    "frame_from_msg",
    "truth_from_msg",
    "estimate_from_msg",
    "json_schema",
]

SCHEMA_VERSION = 1
"""Schema version of ``/truth`` and ``/tracks`` (and of ``/measurements`` that use none of
version 2's additions)."""
MEASUREMENTS_SCHEMA_VERSION = 2
"""``/measurements`` version 2 adds ``pose``, ``R`` and the kind ``xy``; readers accept 1 and 2,
writers write 1 when a message uses none of them (so version-1 readers still read it)."""
_READ_VERSIONS = {"/measurements": (1, 2)}
#: The kinds of ``/measurements`` version 1.
_V1_KINDS = ("bearing_range", "range")
TRACKS_SCHEMA_VERSION = 2
"""``/tracks`` version 2 adds the optional ``cluster`` of a track (two-level trackers); writers
write 1 when no track carries one."""
_READ_VERSIONS["/tracks"] = (1, 2)
#: Versions this build reads, over all topics.
READABLE_VERSIONS = (1, 2)

TOPIC_MEASUREMENTS = "/measurements"
TOPIC_TRUTH = "/truth"
TOPIC_TRACKS = "/tracks"

MAX_MEASUREMENTS = 100_000
MAX_TRACKS = 10_000
MAX_OBJECTS = 10_000
MAX_DIAGNOSTICS = 1_000

_MAX_STAMP = 2**63 - 1
_FMAX = sys.float_info.max
_chain = chain.from_iterable
_min_reduce = np.minimum.reduce
_max_reduce = np.maximum.reduce
_COV_DIM = STATE_DIM * STATE_DIM


# --------------------------------------------------------------------------- errors


class CodecError(ValueError):
    """A message that does not satisfy the schema.

    Attributes: ``topic``, ``frame`` (``None`` when unknown), ``message`` (the detail,
    usually ending with the JSON path, e.g. ``"... - at `$.z[3][1]`"``).
    """

    def __init__(self, topic: str, frame: int | None, message: str) -> None:
        self.topic = topic
        self.frame = frame
        self.message = message
        where = f"frame {frame}" if frame is not None else "frame ?"
        super().__init__(f"{topic} {where}: {message}")

    def __reduce__(self):  # keep picklable (multiprocessing) despite the custom __init__
        return (type(self), (self.topic, self.frame, self.message))


# --------------------------------------------------------------------------- schema

NonNegInt = Annotated[int, msgspec.Meta(ge=0)]
StampNs = Annotated[int, msgspec.Meta(ge=0, le=_MAX_STAMP)]
Prob = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
StateVec = Annotated[list[float], msgspec.Meta(min_length=STATE_DIM, max_length=STATE_DIM)]
CovVec = Annotated[list[float], msgspec.Meta(min_length=_COV_DIM, max_length=_COV_DIM)]
_MAX_DIM = max(k.dim for k in KINDS.values())
ZRow = Annotated[list[float], msgspec.Meta(min_length=1, max_length=_MAX_DIM)]
KindName = Literal[tuple(KINDS)]  # the registry's kinds (tracker.models.measurement.KINDS)


class MeasurementsMsg(
    msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True
):
    """One scan of measurements from one sensor (topic ``/measurements``)."""

    v: int = SCHEMA_VERSION
    run: str = ""
    frame: NonNegInt
    stamp_ns: StampNs
    sensor: str
    kind: KindName
    z: Annotated[list[ZRow], msgspec.Meta(max_length=MAX_MEASUREMENTS)]
    pose: Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)] | None = None
    """``[x_m, y_m, heading_rad]`` of the sensor for this scan (v2)."""
    R: Annotated[list[Annotated[list[float], msgspec.Meta(max_length=_MAX_DIM)]],
                 msgspec.Meta(max_length=_MAX_DIM)] | None = None
    """``d x d`` measurement noise covariance of this scan's rows (v2)."""


class _MeasurementsMsgV1(msgspec.Struct, frozen=True, kw_only=True):
    """The version-1 fields, to write messages that use no version-2 field."""

    v: int
    run: str
    frame: int
    stamp_ns: int
    sensor: str
    kind: str
    z: list


class TruthObject(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """One ground-truth object: id and state ``[px, vx, py, vy, omega]``."""

    id: str
    state: StateVec


class TruthMsg(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Ground truth at one frame (topic ``/truth``)."""

    v: int = SCHEMA_VERSION
    run: str = ""
    frame: NonNegInt
    stamp_ns: StampNs
    objects: Annotated[list[TruthObject], msgspec.Meta(max_length=MAX_OBJECTS)]


class TrackMsg(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True, omit_defaults=True):
    """One labelled track: mean (5), row-major covariance (25), existence probability, and
    (schema 2, two-level trackers only; omitted otherwise) the id of its motion cluster."""

    label: str
    state: StateVec
    covariance: CovVec
    existence: Prob
    cluster: Union[Annotated[int, msgspec.Meta(ge=0)], None] = None


class TracksMsg(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A tracker's output for one frame (topic ``/tracks``)."""

    v: int = SCHEMA_VERSION
    run: str = ""
    frame: NonNegInt
    stamp_ns: StampNs
    tracks: Annotated[list[TrackMsg], msgspec.Meta(max_length=MAX_TRACKS)]
    assignments: Annotated[
        list[Union[str, None]], msgspec.Meta(max_length=MAX_MEASUREMENTS)
    ]
    assignment_prob: Annotated[list[Prob], msgspec.Meta(max_length=MAX_MEASUREMENTS)]
    diagnostics: Annotated[
        dict[str, float], msgspec.Meta(max_length=MAX_DIAGNOSTICS)
    ] = {}


Msg = Union[MeasurementsMsg, TruthMsg, TracksMsg]

#: Message type per topic.
MSG_TYPES: dict[str, type] = {
    TOPIC_MEASUREMENTS: MeasurementsMsg,
    TOPIC_TRUTH: TruthMsg,
    TOPIC_TRACKS: TracksMsg,
}
_TOPIC_OF: dict[type, str] = {t: k for k, t in MSG_TYPES.items()}

_ENCODER = msgspec.json.Encoder()
_DECODERS = {topic: msgspec.json.Decoder(t) for topic, t in MSG_TYPES.items()}


class _Peek(msgspec.Struct):
    """Lenient view used only on the error path to name the frame and version."""

    v: Any = None
    frame: Any = None


_PEEK_DECODER = msgspec.json.Decoder(_Peek)
_FRAME_RE = re.compile(rb'"frame"\s*:\s*(-?\d+)')
_NONFINITE_RE = re.compile(rb"\b(NaN|-?Infinity|-?inf|nan)\b")


def json_schema(msg_type: type | str) -> dict:
    """JSON schema (draft 2020-12, via ``msgspec.json.schema``) of a message type or topic."""
    if isinstance(msg_type, str):
        try:
            msg_type = MSG_TYPES[msg_type]
        except KeyError:
            raise ValueError(f"unknown topic {msg_type!r}") from None
    return msgspec.json.schema(msg_type)


# --------------------------------------------------------------------------- validation


def _is_int(x: Any) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _versions_text(topic: str) -> str:
    versions = _READ_VERSIONS.get(topic, (SCHEMA_VERSION,))
    return f"version{'s' if len(versions) > 1 else ''} {' and '.join(map(str, versions))}"


def _check_header(topic: str, msg: Any) -> int | None:
    """Check v / frame / stamp_ns; return the frame index."""
    frame = msg.frame if _is_int(msg.frame) else None
    if not _is_int(msg.v) or msg.v not in _READ_VERSIONS.get(topic, (SCHEMA_VERSION,)):
        raise CodecError(
            topic,
            frame,
            f"unsupported schema version {msg.v!r} (this build reads {_versions_text(topic)}) - at `$.v`",
        )
    if frame is None or frame < 0:
        raise CodecError(topic, frame, f"frame must be an integer >= 0, got {msg.frame!r} - at `$.frame`")
    if not _is_int(msg.stamp_ns) or not 0 <= msg.stamp_ns <= _MAX_STAMP:
        raise CodecError(
            topic, frame, f"stamp_ns must be an integer in [0, 2**63), got {msg.stamp_ns!r} - at `$.stamp_ns`"
        )
    if not isinstance(msg.run, str):
        raise CodecError(topic, frame, "run must be a string - at `$.run`")
    return int(frame)


def _fmt_index(idx: tuple[int, ...]) -> str:
    return "".join(f"[{int(i)}]" for i in idx)


def _check_finite(topic: str, frame: int, arr: np.ndarray, path: str) -> None:
    """Raise on the first non-finite entry of ``arr`` (path prefix e.g. ``$.z``)."""
    if arr.size and not np.isfinite(arr).all():
        idx = tuple(np.argwhere(~np.isfinite(arr))[0])
        raise CodecError(
            topic, frame, f"non-finite value {float(arr[idx])!r} - at `{path}{_fmt_index(idx)}`"
        )


def _rows_array(
    topic: str, frame: int, rows: Any, width: int, row_path: str, what: str
) -> np.ndarray:
    """``rows`` (list of equal-length lists) -> ``(n, width)`` float array, or CodecError.

    ``row_path`` is the JSON path of row ``i`` as a format string, e.g. ``"$.z[{i}]"``.
    """
    n = len(rows)
    if n == 0:
        return np.zeros((0, width))
    try:
        arr = np.array(rows, dtype=float)
    except (ValueError, TypeError):
        arr = None
    if arr is None or arr.ndim != 2 or arr.shape[1] != width:
        for i, row in enumerate(rows):
            if not isinstance(row, (list, tuple, np.ndarray)) or len(row) != width:
                got = len(row) if hasattr(row, "__len__") else type(row).__name__
                raise CodecError(
                    topic,
                    frame,
                    f"{what} of length {got}, expected {width} - at `{row_path.format(i=i)}`",
                )
        raise CodecError(topic, frame, f"{what} values are not numeric - at `{row_path.format(i=0)}`")
    return arr


def _check_size(topic: str, frame: int, seq: Any, limit: int, path: str) -> None:
    if len(seq) > limit:
        raise CodecError(
            topic, frame, f"too many entries ({len(seq)} > {limit}) - at `{path}`"
        )


def _check_unique(topic: str, frame: int, names: list, path: str, what: str) -> None:
    if len(set(names)) != len(names):
        seen: set = set()
        for i, name in enumerate(names):
            if name in seen:
                raise CodecError(topic, frame, f"duplicate {what} {name!r} - at `{path}[{i}]`")
            seen.add(name)


def _validate_measurements(msg: MeasurementsMsg) -> np.ndarray:
    """Validate a measurements message; return ``z`` as an ``(M, d)`` float array."""
    topic = TOPIC_MEASUREMENTS
    frame = _check_header(topic, msg)
    if msg.kind not in KINDS:
        raise CodecError(topic, frame, f"unknown kind {msg.kind!r} (known: {', '.join(KINDS)}) - at `$.kind`")
    if not isinstance(msg.sensor, str):
        raise CodecError(topic, frame, "sensor must be a string - at `$.sensor`")
    rows = msg.z
    _check_size(topic, frame, rows, MAX_MEASUREMENTS, "$.z")
    kind = KINDS[msg.kind]
    d = kind.dim
    _validate_pose_r(topic, frame, msg, d)
    m = len(rows)
    if m == 0:
        return np.zeros((0, d))
    # Fast path: one flat float array, one min and one max reduction.  NaN propagates
    # through min/max and fails every comparison below; +-inf fails the bounds.
    z = None
    if set(map(len, rows)) == {d}:
        try:
            z = np.fromiter(_chain(rows), dtype=float, count=m * d).reshape(m, d)
        except (TypeError, ValueError):
            z = None
    if z is None:
        z = _rows_array(topic, frame, rows, d, "$.z[{i}]", f"z row (kind {msg.kind!r})")
    lo = _min_reduce(z, axis=0).tolist()
    hi = _max_reduce(z, axis=0).tolist()
    ok = all(a <= x and y <= b for a, b, x, y in zip(kind.low, kind.high, lo, hi))
    if not ok:
        _measurement_error(topic, frame, z, msg.kind)
    return z


def _validate_pose_r(topic: str, frame: int, msg: MeasurementsMsg, d: int) -> None:
    """``pose``: 3 finite numbers; ``R``: a finite symmetric positive-definite ``d x d``."""
    if msg.pose is not None and not all(math.isfinite(v) for v in msg.pose):
        raise CodecError(topic, frame, f"pose must be 3 finite numbers [x, y, heading], got {msg.pose!r} - at `$.pose`")
    if msg.R is None:
        return
    if len(msg.R) != d or any(len(row) != d for row in msg.R):
        raise CodecError(topic, frame, f"R must be {d}x{d} for kind {msg.kind!r} - at `$.R`")
    R = np.array(msg.R, dtype=float)
    if not np.isfinite(R).all() or not np.allclose(R, R.T, rtol=1e-9, atol=0.0) \
            or np.any(np.linalg.eigvalsh(0.5 * (R + R.T)) <= 0):
        raise CodecError(topic, frame, "R must be finite, symmetric and positive definite - at `$.R`")


_COLUMN_NAMES = {"bearing_range": ("bearing", "range"), "range": ("range",), "xy": ("x", "y")}


def _measurement_error(topic: str, frame: int, z: np.ndarray, kind_name: str) -> None:
    """Slow path: raise a CodecError for the first invalid entry of ``z`` (bounds of the
    kind's registry entry)."""
    kind = KINDS[kind_name]
    _check_finite(topic, frame, z, "$.z")
    names = _COLUMN_NAMES.get(kind_name, tuple(f"column {j}" for j in range(kind.dim)))
    for j in reversed(range(kind.dim)):  # range before bearing (the historical order of checks)
        col, lo, hi = z[:, j], kind.low[j], kind.high[j]
        bad = (col < lo) | (col > hi)
        if bad.any():
            i = int(np.argmax(bad))
            if lo == 0.0 and hi >= _FMAX:
                what = f"{names[j]} must be >= 0"
            else:
                what = f"{names[j]} must be within [{'-pi' if lo == -math.pi else f'{lo:g}'}, {'pi' if hi == math.pi else f'{hi:g}'}]"
            raise CodecError(topic, frame, f"{what}, got {float(col[i])!r} - at `$.z[{i}][{j}]`")
    raise CodecError(topic, frame, "invalid measurement values - at `$.z`")  # unreachable


def _validate_truth(msg: TruthMsg) -> np.ndarray:
    topic = TOPIC_TRUTH
    frame = _check_header(topic, msg)
    _check_size(topic, frame, msg.objects, MAX_OBJECTS, "$.objects")
    ids = []
    for i, o in enumerate(msg.objects):
        if not isinstance(o.id, str):
            raise CodecError(topic, frame, f"id must be a string - at `$.objects[{i}].id`")
        ids.append(o.id)
    _check_unique(topic, frame, ids, "$.objects", "object id")
    states = _rows_array(
        topic, frame, [o.state for o in msg.objects], STATE_DIM, "$.objects[{i}].state", "state"
    )
    if states.shape[0] and not np.isfinite(states).all():
        i, j = np.argwhere(~np.isfinite(states))[0]
        raise CodecError(
            topic, frame, f"non-finite value {float(states[i, j])!r} - at `$.objects[{i}].state[{j}]`"
        )
    return states


def _validate_tracks(msg: TracksMsg) -> tuple[np.ndarray, np.ndarray]:
    topic = TOPIC_TRACKS
    frame = _check_header(topic, msg)
    _check_size(topic, frame, msg.tracks, MAX_TRACKS, "$.tracks")
    _check_size(topic, frame, msg.assignments, MAX_MEASUREMENTS, "$.assignments")
    _check_size(topic, frame, msg.assignment_prob, MAX_MEASUREMENTS, "$.assignment_prob")
    _check_size(topic, frame, msg.diagnostics, MAX_DIAGNOSTICS, "$.diagnostics")
    tracks = msg.tracks
    labels = []
    for i, t in enumerate(tracks):
        if not isinstance(t.label, str):
            raise CodecError(topic, frame, f"label must be a string - at `$.tracks[{i}].label`")
        labels.append(t.label)
    _check_unique(topic, frame, labels, "$.tracks", "track label")
    n = len(tracks)
    states = _rows_array(topic, frame, [t.state for t in tracks], STATE_DIM, "$.tracks[{i}].state", "state")
    covs = _rows_array(
        topic, frame, [t.covariance for t in tracks], _COV_DIM, "$.tracks[{i}].covariance", "covariance"
    )
    if n:
        for arr, name in ((states, "state"), (covs, "covariance")):
            if not np.isfinite(arr).all():
                i, j = np.argwhere(~np.isfinite(arr))[0]
                raise CodecError(
                    topic, frame, f"non-finite value {float(arr[i, j])!r} - at `$.tracks[{i}].{name}[{j}]`"
                )
        ex = np.array([t.existence for t in tracks], dtype=float)
        bad = ~((ex >= 0.0) & (ex <= 1.0))  # also catches NaN
        if bad.any():
            i = int(np.argmax(bad))
            raise CodecError(
                topic, frame, f"existence must be in [0, 1], got {float(ex[i])!r} - at `$.tracks[{i}].existence`"
            )
    if len(msg.assignments) != len(msg.assignment_prob):
        raise CodecError(
            topic,
            frame,
            f"len(assignments) = {len(msg.assignments)} != len(assignment_prob) = "
            f"{len(msg.assignment_prob)} - at `$.assignment_prob`",
        )
    for i, a in enumerate(msg.assignments):
        if a is not None and not isinstance(a, str):
            raise CodecError(topic, frame, f"assignment must be a label or null - at `$.assignments[{i}]`")
    if msg.assignment_prob:
        p = np.array(msg.assignment_prob, dtype=float)
        bad = ~((p >= 0.0) & (p <= 1.0))
        if bad.any():
            i = int(np.argmax(bad))
            raise CodecError(
                topic, frame, f"probability must be in [0, 1], got {float(p[i])!r} - at `$.assignment_prob[{i}]`"
            )
    if msg.diagnostics:
        keys = list(msg.diagnostics)
        vals = np.array([msg.diagnostics[k] for k in keys], dtype=float)
        if not np.isfinite(vals).all():
            i = int(np.argmax(~np.isfinite(vals)))
            raise CodecError(
                topic, frame, f"non-finite value {float(vals[i])!r} - at `$.diagnostics.{keys[i]}`"
            )
    return states, covs


def validate_msg(msg: Msg) -> None:
    """Check every constraint of the contract on a message struct (e.g. one built by hand).

    Decoding already does this; call it on structs you construct yourself.
    """
    if isinstance(msg, MeasurementsMsg):
        _validate_measurements(msg)
    elif isinstance(msg, TruthMsg):
        _validate_truth(msg)
    elif isinstance(msg, TracksMsg):
        _validate_tracks(msg)
    else:
        raise TypeError(f"not a bnptrack message: {type(msg).__name__}")


# --------------------------------------------------------------------------- decode


def _decode_error(topic: str, data: bytes, exc: Exception) -> CodecError:
    """Turn a msgspec error into a CodecError naming the frame (and the version if wrong)."""
    frame: int | None = None
    version: Any = None
    try:
        peek = _PEEK_DECODER.decode(data)
        version = peek.v
        if _is_int(peek.frame):
            frame = int(peek.frame)
    except Exception:
        m = _FRAME_RE.search(bytes(data[:4096]))
        if m:
            frame = int(m.group(1))
    if _is_int(version) and version not in _READ_VERSIONS.get(topic, (SCHEMA_VERSION,)):
        return CodecError(
            topic,
            frame,
            f"unsupported schema version {version} (this build reads {_versions_text(topic)}) - at `$.v`",
        )
    detail = str(exc)
    if isinstance(exc, msgspec.DecodeError) and not isinstance(exc, msgspec.ValidationError):
        if _NONFINITE_RE.search(bytes(data)):
            detail = f"non-finite number (NaN/Infinity) is not valid JSON here: {detail}"
    return CodecError(topic, frame, detail)


def _decode(topic: str, data: bytes | bytearray | memoryview | str) -> Any:
    try:
        return _DECODERS[topic].decode(data)
    except msgspec.DecodeError as exc:  # ValidationError is a subclass
        raw = data.encode() if isinstance(data, str) else data
        raise _decode_error(topic, raw, exc) from None


def decode_measurements_msg(data: bytes) -> MeasurementsMsg:
    """Decode and validate a ``/measurements`` message, keeping ``v`` and ``run``."""
    msg = _decode(TOPIC_MEASUREMENTS, data)
    _validate_measurements(msg)
    return msg


def decode_truth_msg(data: bytes) -> TruthMsg:
    """Decode and validate a ``/truth`` message."""
    msg = _decode(TOPIC_TRUTH, data)
    _validate_truth(msg)
    return msg


def decode_tracks_msg(data: bytes) -> TracksMsg:
    """Decode and validate a ``/tracks`` message."""
    msg = _decode(TOPIC_TRACKS, data)
    _validate_tracks(msg)
    return msg


_DECODE_MSG = {
    TOPIC_MEASUREMENTS: decode_measurements_msg,
    TOPIC_TRUTH: decode_truth_msg,
    TOPIC_TRACKS: decode_tracks_msg,
}


def decode_msg(topic: str, data: bytes) -> Msg:
    """Decode and validate the message of a known topic."""
    try:
        fn = _DECODE_MSG[topic]
    except KeyError:
        raise ValueError(f"unknown topic {topic!r}") from None
    return fn(data)


def frame_from_msg(msg: MeasurementsMsg, truth: Truth | None = None) -> Frame:
    """A (validated) measurements message as a :class:`Frame`."""
    d = MEASUREMENT_DIM[msg.kind]
    z = (
        np.fromiter(_chain(msg.z), dtype=float, count=len(msg.z) * d).reshape(-1, d)
        if msg.z
        else np.zeros((0, d))
    )
    return Frame(
        frame=msg.frame,
        stamp_ns=msg.stamp_ns,
        sensor=msg.sensor,
        kind=msg.kind,
        z=z,
        truth=truth,
        pose=None if msg.pose is None else tuple(msg.pose),
        R=None if msg.R is None else np.array(msg.R, dtype=float),
    )


def truth_from_msg(msg: TruthMsg) -> Truth:
    """A (validated) truth message as :class:`Truth`."""
    states = (
        np.array([o.state for o in msg.objects], dtype=float)
        if msg.objects
        else np.zeros((0, STATE_DIM))
    )
    return Truth(ids=tuple(o.id for o in msg.objects), states=states)


def estimate_from_msg(msg: TracksMsg) -> Estimate:
    """A (validated) tracks message as an :class:`Estimate`."""
    tracks = tuple(
        TrackEstimate(
            label=t.label,
            state=np.array(t.state, dtype=float),
            covariance=np.array(t.covariance, dtype=float).reshape(STATE_DIM, STATE_DIM),
            existence=float(t.existence),
            cluster=t.cluster,
        )
        for t in msg.tracks
    )
    return Estimate(
        frame=msg.frame,
        stamp_ns=msg.stamp_ns,
        tracks=tracks,
        assignments=tuple(msg.assignments),
        assignment_prob=tuple(float(p) for p in msg.assignment_prob),
        diagnostics=dict(msg.diagnostics),
    )


def decode_measurements(data: bytes) -> Frame:
    """Decode a ``/measurements`` message to a :class:`Frame` (``truth`` is ``None``)."""
    msg = _decode(TOPIC_MEASUREMENTS, data)
    z = _validate_measurements(msg)
    return Frame(
        frame=msg.frame, stamp_ns=msg.stamp_ns, sensor=msg.sensor, kind=msg.kind, z=z,
        pose=None if msg.pose is None else tuple(msg.pose),
        R=None if msg.R is None else np.array(msg.R, dtype=float),
    )


def decode_truth(data: bytes) -> tuple[int, int, Truth]:
    """Decode a ``/truth`` message to ``(frame_index, stamp_ns, truth)``."""
    msg = decode_truth_msg(data)
    return msg.frame, msg.stamp_ns, truth_from_msg(msg)


def decode_tracks(data: bytes) -> Estimate:
    """Decode a ``/tracks`` message to an :class:`Estimate`."""
    return estimate_from_msg(decode_tracks_msg(data))


# --------------------------------------------------------------------------- encode


def _as_int(topic: str, frame: Any, value: Any, name: str) -> int:
    if not _is_int(value):
        raise CodecError(topic, frame if _is_int(frame) else None, f"{name} must be an integer, got {value!r} - at `$.{name}`")
    return int(value)


def measurements_msg(frame: Frame, run: str = "") -> MeasurementsMsg:
    """Build (without validating) the message for ``frame``."""
    topic = TOPIC_MEASUREMENTS
    idx = _as_int(topic, frame.frame, frame.frame, "frame")
    z = np.asarray(frame.z, dtype=float)
    pose = getattr(frame, "pose", None)
    R = getattr(frame, "R", None)
    v2 = pose is not None or R is not None or frame.kind not in _V1_KINDS
    return MeasurementsMsg(
        v=MEASUREMENTS_SCHEMA_VERSION if v2 else SCHEMA_VERSION,
        run=run,
        frame=idx,
        stamp_ns=_as_int(topic, idx, frame.stamp_ns, "stamp_ns"),
        sensor=str(frame.sensor),
        kind=frame.kind,
        z=z.tolist(),
        pose=None if pose is None else [float(v) for v in pose],
        R=None if R is None else np.asarray(R, dtype=float).tolist(),
    )


def truth_msg(frame_index: int, stamp_ns: int, truth: Truth, run: str = "") -> TruthMsg:
    """Build (without validating) the truth message."""
    topic = TOPIC_TRUTH
    idx = _as_int(topic, frame_index, frame_index, "frame")
    states = np.asarray(truth.states, dtype=float)
    if len(truth.ids) != len(states):
        raise CodecError(topic, idx, f"{len(truth.ids)} ids but {len(states)} states - at `$.objects`")
    return TruthMsg(
        v=SCHEMA_VERSION,
        run=run,
        frame=idx,
        stamp_ns=_as_int(topic, idx, stamp_ns, "stamp_ns"),
        objects=[
            TruthObject(id=str(i), state=s)
            for i, s in zip(truth.ids, states.tolist())
        ],
    )


def tracks_msg(est: Estimate, run: str = "") -> TracksMsg:
    """Build (without validating) the tracks message for ``est``."""
    topic = TOPIC_TRACKS
    idx = _as_int(topic, est.frame, est.frame, "frame")
    tracks = [
        TrackMsg(
            label=str(t.label),
            state=np.asarray(t.state, dtype=float).ravel().tolist(),
            covariance=np.asarray(t.covariance, dtype=float).ravel().tolist(),
            existence=float(t.existence),
            cluster=None if t.cluster is None else int(t.cluster),
        )
        for t in est.tracks
    ]
    return TracksMsg(
        v=TRACKS_SCHEMA_VERSION if any(t.cluster is not None for t in tracks) else SCHEMA_VERSION,
        run=run,
        frame=idx,
        stamp_ns=_as_int(topic, idx, est.stamp_ns, "stamp_ns"),
        tracks=tracks,
        assignments=[None if a is None else str(a) for a in est.assignments],
        assignment_prob=np.asarray(est.assignment_prob, dtype=float).ravel().tolist(),
        diagnostics={str(k): float(v) for k, v in est.diagnostics.items()},
    )


def encode_msg(msg: Msg) -> bytes:
    """Validate and JSON-encode a message struct (a ``/measurements`` message without
    ``pose`` and ``R`` is written without those fields)."""
    validate_msg(msg)
    if isinstance(msg, MeasurementsMsg) and msg.pose is None and msg.R is None:
        return _ENCODER.encode(_MeasurementsMsgV1(v=msg.v, run=msg.run, frame=msg.frame, stamp_ns=msg.stamp_ns,
                                                  sensor=msg.sensor, kind=msg.kind, z=msg.z))
    return _ENCODER.encode(msg)


def encode_measurements(frame: Frame, run: str = "") -> bytes:
    """JSON bytes of the ``/measurements`` message for ``frame`` (its truth is not included)."""
    return encode_msg(measurements_msg(frame, run))


def encode_truth(frame_index: int, stamp_ns: int, truth: Truth, run: str = "") -> bytes:
    """JSON bytes of the ``/truth`` message."""
    return encode_msg(truth_msg(frame_index, stamp_ns, truth, run))


def encode_tracks(est: Estimate, run: str = "") -> bytes:
    """JSON bytes of the ``/tracks`` message for ``est`` (the tracker stage's per-frame
    encoding: checked on stacked arrays; anything off takes the slow path, which names the
    exact error)."""
    msg = _checked_tracks_msg(est, run)
    if msg is None:
        return encode_msg(tracks_msg(est, run))
    return _ENCODER.encode(msg)


def _in_unit(a: np.ndarray) -> bool:
    return bool(((a >= 0.0) & (a <= 1.0)).all())  # NaN fails too


def _stack(rows: list, n: int, width: int) -> np.ndarray | None:
    try:
        a = np.array(rows, dtype=float).reshape(n, -1)
    except (ValueError, TypeError):
        return None
    return a if a.shape[1] == width and np.isfinite(a).all() else None


def _checked_tracks_msg(est: Estimate, run: str) -> TracksMsg | None:
    """The message :func:`tracks_msg` builds, when every check of the contract passes on
    the estimate's arrays (one vectorised pass instead of :func:`validate_msg` on the
    lists); ``None`` otherwise."""
    tracks, n = est.tracks, len(est.tracks)
    if not (_is_int(est.frame) and est.frame >= 0 and _is_int(est.stamp_ns) and 0 <= est.stamp_ns <= _MAX_STAMP):
        return None
    if not isinstance(run, str) or n > MAX_TRACKS or len(est.diagnostics) > MAX_DIAGNOSTICS:
        return None
    labels = [str(t.label) for t in tracks]
    probs = np.asarray(est.assignment_prob, dtype=float).ravel()
    if len(set(labels)) != n or len(est.assignments) != probs.size or probs.size > MAX_MEASUREMENTS:
        return None
    diag = {str(k): float(v) for k, v in est.diagnostics.items()}
    if not (_in_unit(probs) and all(map(math.isfinite, diag.values()))):
        return None
    states = _stack([t.state for t in tracks], n, STATE_DIM) if n else np.zeros((0, STATE_DIM))
    covs = _stack([t.covariance for t in tracks], n, _COV_DIM) if n else np.zeros((0, _COV_DIM))
    exist = np.array([float(t.existence) for t in tracks], dtype=float)
    if states is None or covs is None or not _in_unit(exist):
        return None
    return TracksMsg(
        v=TRACKS_SCHEMA_VERSION if any(t.cluster is not None for t in tracks) else SCHEMA_VERSION,
        run=run,
        frame=int(est.frame),
        stamp_ns=int(est.stamp_ns),
        tracks=[TrackMsg(label=lab, state=st, covariance=cv, existence=ex,
                         cluster=None if t.cluster is None else int(t.cluster))
                for lab, st, cv, ex, t in zip(labels, states.tolist(), covs.tolist(), exist.tolist(), tracks)],
        assignments=[None if a is None else str(a) for a in est.assignments],
        assignment_prob=probs.tolist(),
        diagnostics=diag,
    )
