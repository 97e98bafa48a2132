"""The rules of the message contract beyond JSON types (private to :mod:`tracker.messages`).

Every function raises :class:`CodecError` naming topic, frame and JSON path.  The checks read
messages by attribute (``msg.frame``, ``msg.z``, ...), so this module does not import the
message structs: :mod:`tracker.messages` imports it.  They are the one statement of the rules,
for decoding and encoding alike, and work on the decoded lists in plain Python: each rule is a
quick test of the whole field (a few C-level calls: ``len``, ``set``, ``zip``, ``min``, ``max``,
``sum`` on lists of a few dozen floats), and only when it fails the field's exhaustive check
(numpy on the error path), which names the first entry that breaks the rule, or passes a
field the quick test was too cautious for (a sum of large finite values that overflows).  On
the pipeline's frame path a stage decodes one frame every 50 ms with its caches gone cold,
where one small numpy call costs about 10 us (docs/pipeline.md, "Latency"); numpy
is used on the common path only for what needs it (``R``'s eigenvalues).  The topic names, schema versions and
size limits of the contract live here because both modules need them;
:mod:`tracker.messages` re-exports the public ones.
"""

from __future__ import annotations

import math
import re
import sys
from typing import Any

import msgspec
import numpy as np

from bnptrack.tracker.models.measurement import KINDS, MeasurementKind
from bnptrack.tracker.types import STATE_DIM

# --------------------------------------------------------------------------- contract constants

TOPIC_MEASUREMENTS = "/measurements"
TOPIC_TRUTH = "/truth"
TOPIC_TRACKS = "/tracks"

SCHEMA_VERSION = 1
"""Schema version of ``/truth`` and ``/tracks`` (and of ``/measurements`` that use none of
version 2's additions)."""
MEASUREMENTS_SCHEMA_VERSION = 2
"""``/measurements`` version 2 adds ``pose``, ``R`` and the kinds registered after version 1;
readers accept 1 and 2, writers write 1 when a message uses none of them (so version-1 readers
still read it)."""
TRACKS_SCHEMA_VERSION = 3
"""``/tracks`` version 2 adds the optional ``cluster`` of a track (two-level trackers); version 3
the optional ``cardinality_pmf`` of a frame; version 4 the optional header field ``lag`` (the
scans of hindsight of a fixed-lag output).  Writers write the lowest version that has the
fields a message uses: 4 with a ``lag`` above 0, else 3 with a ``cardinality_pmf``, else 2 when a
track carries a ``cluster``, else 1."""
#: ``/tracks`` version that added the header field ``lag``.
TRACKS_LAG_VERSION = 4
#: ``/tracks`` version that added ``cluster`` (a message with a cluster and no pmf is written so).
TRACKS_CLUSTER_VERSION = 2
#: Versions read per topic (a topic not listed reads only :data:`SCHEMA_VERSION`).
READ_VERSIONS = {TOPIC_MEASUREMENTS: (1, 2), TOPIC_TRACKS: (1, 2, 3, 4)}
#: ``sum(cardinality_pmf)`` must be within this of 1 (the writer's tail cut is 1e-9).
PMF_SUM_TOL = 1e-6
#: Entries a ``cardinality_pmf`` may have (``n = 0 .. 100 000``).
MAX_PMF = 100_001
#: The kinds of ``/measurements`` version 1.  A fixed historical record, deliberately not
#: derived from the registry: version-1 readers know exactly these two kinds, so a frame of
#: any kind registered since (``xy``, or one added later) must be written as version 2.
V1_KINDS = frozenset({"bearing_range", "range"})

MAX_MEASUREMENTS = 100_000
MAX_TRACKS = 10_000
MAX_OBJECTS = 10_000
MAX_DIAGNOSTICS = 1_000
MAX_STAMP = 2**63 - 1
#: Columns a ``z`` row or ``R`` may have on decode (the kind's dimension is checked after).
MAX_ROW_DIM = 64
COV_DIM = STATE_DIM * STATE_DIM

_FMAX = sys.float_info.max
_V1 = (SCHEMA_VERSION,)
_STR = frozenset({str})
_LABEL_TYPES = frozenset({str, type(None)})


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


# --------------------------------------------------------------------------- shared checks


def is_int(x: Any) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _versions(topic: str) -> tuple[int, ...]:
    return READ_VERSIONS.get(topic, _V1)


def _versions_text(topic: str) -> str:
    versions = _versions(topic)
    return f"version{'s' if len(versions) > 1 else ''} {' and '.join(map(str, versions))}"


def _version_error(topic: str, frame: int | None, version: Any) -> CodecError:
    return CodecError(
        topic, frame, f"unsupported schema version {version!r} (this build reads {_versions_text(topic)}) - at `$.v`"
    )


def check_header(topic: str, msg: Any) -> int:
    """Check v / frame / stamp_ns / run of the shared header; return the frame index."""
    v, frame, stamp = msg.v, msg.frame, msg.stamp_ns
    if type(v) is int and type(frame) is int and type(stamp) is int and type(msg.run) is str \
            and v in READ_VERSIONS.get(topic, _V1) and frame >= 0 and 0 <= stamp <= MAX_STAMP:
        return frame  # the quick test: a decoded header
    known = frame if is_int(frame) else None
    if not is_int(v) or v not in _versions(topic):
        raise _version_error(topic, known, v)
    if known is None or frame < 0:
        raise CodecError(topic, known, f"frame must be an integer >= 0, got {frame!r} - at `$.frame`")
    if not is_int(stamp) or not 0 <= stamp <= MAX_STAMP:
        raise CodecError(topic, frame, f"stamp_ns must be an integer in [0, 2**63), got {stamp!r} - at `$.stamp_ns`")
    if not isinstance(msg.run, str):
        raise CodecError(topic, frame, "run must be a string - at `$.run`")
    return int(frame)


def unit_ok(values: list) -> bool:
    """Quick test: every value a number in ``[0, 1]`` (NaN and inf fail: the sum is not finite)."""
    try:
        return not values or (math.isfinite(sum(values)) and min(values) >= 0.0 and max(values) <= 1.0)
    except TypeError:
        return False


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


def _check_strings(topic: str, frame: int, names: list, attr: str, path: str, what: str) -> None:
    """The ``attr`` of every item (``names``, in order) must be a string, and unique."""
    if set(map(type, names)) <= _STR and len(set(names)) == len(names):
        return
    for i, name in enumerate(names):
        if not isinstance(name, str):
            raise CodecError(topic, frame, f"{attr} must be a string - at `{path}[{i}].{attr}`")
    _check_unique(topic, frame, names, path, what)


def _check_unit(topic: str, frame: int, values: Any, what: str, path: str) -> None:
    """Every value in ``[0, 1]`` (NaN fails); ``path`` formats index ``i``."""
    if unit_ok(values):
        return
    p = np.array(values, dtype=float)
    bad = ~((p >= 0.0) & (p <= 1.0))
    if bad.any():
        i = int(np.argmax(bad))
        raise CodecError(topic, frame, f"{what} must be in [0, 1], got {float(p[i])!r} - at `{path.format(i=i)}`")


# --------------------------------------------------------------------------- /measurements


def check_measurements(msg: Any) -> None:
    """Validate a measurements message."""
    topic = TOPIC_MEASUREMENTS
    frame = check_header(topic, msg)
    kind = KINDS.get(msg.kind) if isinstance(msg.kind, str) else None
    if kind is None:
        raise CodecError(topic, frame, f"unknown kind {msg.kind!r} (known: {', '.join(KINDS)}) - at `$.kind`")
    if not isinstance(msg.sensor, str):
        raise CodecError(topic, frame, "sensor must be a string - at `$.sensor`")
    rows = msg.z
    if len(rows) > MAX_MEASUREMENTS:
        _check_size(topic, frame, rows, MAX_MEASUREMENTS, "$.z")
    if msg.pose is not None or msg.R is not None:
        _check_pose_r(topic, frame, msg, kind.dim)
    if rows and not _within(rows, kind):
        _measurement_error(topic, frame, msg.kind, rows, kind)


def _within(rows: list, kind: MeasurementKind) -> bool:
    """Quick test of ``z``: rows of the kind's dimension, every column finite (its sum; an
    overflow fails too) and within the kind's bounds (its min and max)."""
    try:
        return set(map(len, rows)) == {kind.dim} and all(
            math.isfinite(sum(col)) and lo <= min(col) and max(col) <= hi
            for col, lo, hi in zip(zip(*rows), kind.low, kind.high))
    except TypeError:
        return False


def _check_pose_r(topic: str, frame: int, msg: Any, d: int) -> None:
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


def _column_names(kind: MeasurementKind) -> tuple[str, ...]:
    """Column names of a kind from its registry entry's ``columns`` (``"[bearing_rad, range_m]"``
    -> ``("bearing", "range")``: the unit suffix dropped), else ``column j``."""
    names = tuple(c.strip().rsplit("_", 1)[0] for c in kind.columns.strip("[]").split(","))
    if len(names) != kind.dim or not all(names):
        return tuple(f"column {j}" for j in range(kind.dim))
    return names


def _bound_text(lo: float, hi: float) -> str:
    if lo == 0.0 and hi >= _FMAX:
        return "must be >= 0"
    return f"must be within [{'-pi' if lo == -math.pi else f'{lo:g}'}, {'pi' if hi == math.pi else f'{hi:g}'}]"


def _measurement_error(topic: str, frame: int, name: str, rows: list, kind: MeasurementKind) -> None:
    """The exhaustive check of ``z`` (rows of a kind ``name``): raise a CodecError for the
    first invalid row or entry (bounds of the kind's registry entry); pass when there is none."""
    z = _rows_array(topic, frame, rows, kind.dim, "$.z[{i}]", f"z row (kind {name!r})")
    _check_finite(topic, frame, z, "$.z")
    names = _column_names(kind)
    for j in reversed(range(kind.dim)):  # range before bearing (the historical order of checks)
        col, lo, hi = z[:, j], kind.low[j], kind.high[j]
        bad = (col < lo) | (col > hi)
        if bad.any():
            i = int(np.argmax(bad))
            raise CodecError(topic, frame, f"{names[j]} {_bound_text(lo, hi)}, got {float(col[i])!r} - at `$.z[{i}][{j}]`")


# --------------------------------------------------------------------------- /truth, /tracks


def check_truth(msg: Any) -> None:
    """Validate a truth message."""
    topic = TOPIC_TRUTH
    frame = check_header(topic, msg)
    objects = msg.objects
    if len(objects) > MAX_OBJECTS:
        _check_size(topic, frame, objects, MAX_OBJECTS, "$.objects")
    _check_strings(topic, frame, [o.id for o in objects], "id", "$.objects", "object id")
    try:  # the quick test
        if all(len(o.state) == STATE_DIM and math.isfinite(sum(o.state)) for o in objects):
            return
    except TypeError:
        pass
    _check_rows(topic, frame, [o.state for o in objects], STATE_DIM, "$.objects[{i}].state", "state")


def _check_rows(topic: str, frame: int, rows: list, width: int, row_path: str, what: str) -> None:
    """The exhaustive check of rows of ``width`` finite numbers (``row_path`` formats row
    ``i``, e.g. ``"$.tracks[{i}].state"``), after their quick test failed."""
    arr = _rows_array(topic, frame, rows, width, row_path, what)
    if not np.isfinite(arr).all():
        i, j = np.argwhere(~np.isfinite(arr))[0]
        raise CodecError(topic, frame, f"non-finite value {float(arr[i, j])!r} - at `{row_path.format(i=i)}[{j}]`")


def check_tracks(msg: Any) -> None:
    """Validate a tracks message."""
    topic = TOPIC_TRACKS
    frame = check_header(topic, msg)
    _check_size(topic, frame, msg.tracks, MAX_TRACKS, "$.tracks")
    _check_size(topic, frame, msg.assignments, MAX_MEASUREMENTS, "$.assignments")
    _check_size(topic, frame, msg.assignment_prob, MAX_MEASUREMENTS, "$.assignment_prob")
    _check_size(topic, frame, msg.diagnostics, MAX_DIAGNOSTICS, "$.diagnostics")
    _check_track_rows(frame, msg.tracks)
    _check_assignments(frame, msg)
    _check_pmf(frame, msg)
    _check_lag(frame, msg)
    diag = msg.diagnostics
    if diag and not _finite_sum(diag.values()):
        keys = list(diag)
        vals = np.array([diag[k] for k in keys], dtype=float)
        if not np.isfinite(vals).all():
            i = int(np.argmax(~np.isfinite(vals)))
            raise CodecError(topic, frame, f"non-finite value {float(vals[i])!r} - at `$.diagnostics.{keys[i]}`")


def _finite_sum(values: Any) -> bool:
    try:
        return math.isfinite(sum(values))
    except TypeError:
        return False


def _check_track_rows(frame: int, tracks: list) -> None:
    """Labels (strings, unique), states (5), covariances (25), all finite; existence in [0, 1]."""
    topic = TOPIC_TRACKS
    _check_strings(topic, frame, [t.label for t in tracks], "label", "$.tracks", "track label")
    try:  # the quick test, one pass
        if all(len(t.state) == STATE_DIM and len(t.covariance) == COV_DIM and 0.0 <= t.existence <= 1.0
               and math.isfinite(sum(t.state) + sum(t.covariance)) for t in tracks):
            return
    except TypeError:
        pass
    states, covs = [t.state for t in tracks], [t.covariance for t in tracks]
    _rows_array(topic, frame, states, STATE_DIM, "$.tracks[{i}].state", "state")  # lengths of both, then values
    _rows_array(topic, frame, covs, COV_DIM, "$.tracks[{i}].covariance", "covariance")
    _check_rows(topic, frame, states, STATE_DIM, "$.tracks[{i}].state", "state")
    _check_rows(topic, frame, covs, COV_DIM, "$.tracks[{i}].covariance", "covariance")
    _check_unit(topic, frame, [t.existence for t in tracks], "existence", "$.tracks[{i}].existence")


def _check_assignments(frame: int, msg: Any) -> None:
    """One probability in [0, 1] per assignment; every assignment a label or null."""
    topic = TOPIC_TRACKS
    assignments, probs = msg.assignments, msg.assignment_prob
    if len(assignments) != len(probs):
        raise CodecError(topic, frame, f"len(assignments) = {len(assignments)} != len(assignment_prob) = "
                                       f"{len(probs)} - at `$.assignment_prob`")
    if not set(map(type, assignments)) <= _LABEL_TYPES:
        for i, a in enumerate(assignments):
            if a is not None and not isinstance(a, str):
                raise CodecError(topic, frame, f"assignment must be a label or null - at `$.assignments[{i}]`")
    if probs:
        _check_unit(topic, frame, probs, "probability", "$.assignment_prob[{i}]")


def pmf_ok(p: np.ndarray) -> bool:
    """A cardinality pmf: at least one entry, all finite and >= 0, summing to 1 within
    :data:`PMF_SUM_TOL`, at most :data:`MAX_PMF` entries."""
    return bool(0 < p.size <= MAX_PMF and np.isfinite(p).all() and (p >= 0.0).all()
                and abs(float(p.sum()) - 1.0) <= PMF_SUM_TOL)


def pmf_list_ok(pmf: list) -> bool:
    """Quick test of :func:`pmf_ok` for a list of floats: its sum taken exactly
    (``math.fsum``) and held to half the tolerance, so that a sum near the limit is left to
    :func:`pmf_ok` (numpy's summation, the rule)."""
    if not 0 < len(pmf) <= MAX_PMF:
        return False
    try:
        s = math.fsum(pmf)
    except (OverflowError, ValueError, TypeError):
        return False
    return math.isfinite(s) and min(pmf) >= 0.0 and abs(s - 1.0) <= PMF_SUM_TOL / 2


def _check_lag(frame: int, msg: Any) -> None:
    """``lag`` (version 4; absent is fine): an integer >= 0, only in version 4."""
    lag = getattr(msg, "lag", msgspec.UNSET)
    if lag is msgspec.UNSET:
        return
    if not is_int(lag) or lag < 0:
        raise CodecError(TOPIC_TRACKS, frame, f"lag must be an integer >= 0, got {lag!r} - at `$.lag`")
    if msg.v < TRACKS_LAG_VERSION:
        raise CodecError(TOPIC_TRACKS, frame, f"lag needs schema version {TRACKS_LAG_VERSION}, the message says "
                                              f"{msg.v} - at `$.lag`")


def _check_pmf(frame: int, msg: Any) -> None:
    """``cardinality_pmf`` (version 3; absent is fine): see :func:`pmf_ok`; one line naming the
    field on failure."""
    pmf = getattr(msg, "cardinality_pmf", msgspec.UNSET)
    if pmf is msgspec.UNSET or pmf is None:
        return
    topic = TOPIC_TRACKS
    if msg.v < 3:
        raise CodecError(topic, frame, f"cardinality_pmf needs schema version 3, the message says {msg.v} - at `$.cardinality_pmf`")
    if pmf_list_ok(pmf):
        return
    p = np.array(pmf, dtype=float)
    if not pmf_ok(p):
        why = (f"{p.size} entries (1 to {MAX_PMF} allowed)" if not 0 < p.size <= MAX_PMF
               else "a non-finite entry" if not np.isfinite(p).all()
               else f"a negative entry {float(p.min())!r}" if (p < 0).any()
               else f"a sum of {float(p.sum())!r}")
        raise CodecError(topic, frame, f"cardinality_pmf must be finite, >= 0 and sum to 1 (within {PMF_SUM_TOL:g}):"
                                       f" it has {why} - at `$.cardinality_pmf`")


# --------------------------------------------------------------------------- decode errors


class _Peek(msgspec.Struct):
    """Lenient view used only on the error path to name the frame and version."""

    v: Any = None
    frame: Any = None


_PEEK_DECODER = msgspec.json.Decoder(_Peek)
_FRAME_RE = re.compile(rb'"frame"\s*:\s*(-?\d+)')
_NONFINITE_RE = re.compile(rb"\b(NaN|-?Infinity|-?inf|nan)\b")


def decode_error(topic: str, data: bytes, exc: Exception) -> CodecError:
    """Turn a msgspec error into a CodecError naming the frame (and the version if wrong)."""
    frame: int | None = None
    version: Any = None
    try:
        peek = _PEEK_DECODER.decode(data)
        version = peek.v
        if is_int(peek.frame):
            frame = int(peek.frame)
    except Exception:
        m = _FRAME_RE.search(bytes(data[:4096]))
        if m:
            frame = int(m.group(1))
    if is_int(version) and version not in _versions(topic):
        return _version_error(topic, frame, version)
    detail = str(exc)
    if isinstance(exc, msgspec.DecodeError) and not isinstance(exc, msgspec.ValidationError):
        if _NONFINITE_RE.search(bytes(data)):
            detail = f"non-finite number (NaN/Infinity) is not valid JSON here: {detail}"
    return CodecError(topic, frame, detail)
