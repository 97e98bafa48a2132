"""The message contract: versioned JSON messages of the bus and the MCAP logs (public).

Three messages, each a JSON object that starts with the shared :class:`Header`
(``v``, ``run``, ``frame``, ``stamp_ns``), used both on the Zenoh bus and in MCAP logs:

``/measurements`` (:class:`MeasurementsMsg`)::

    {"v": 2, "run": "", "frame": 0, "stamp_ns": 0, "sensor": "radar0",
     "kind": "bearing_range", "z": [[bearing_rad, range_m], ...]}

  (the kinds and their row layouts are the registry ``tracker.models.measurement.KINDS``,
  e.g. ``"range"``: ``"z": [[range_m], ...]``).  ``v`` and ``run`` are optional on decode
  (default ``1`` and ``""``) so logs that carry only the five core fields decode.

``/truth`` (:class:`TruthMsg`)::

    {"v": 2, "run": "", "frame": 0, "stamp_ns": 0,
     "objects": [{"id": "obj0", "state": [px, vx, py, vy, omega]}, ...]}

``/tracks`` (:class:`TracksMsg`)::

    {"v": 2, "run": "", "frame": 0, "stamp_ns": 0, "lag": 3,   # lag: optional (v4)
     "tracks": [{"label": "t1", "state": [5 floats], "covariance": [25 floats, row-major],
                 "existence": 0.97}, ...],
     "assignments": ["t1", null, ...],          # one per measurement, input order
     "assignment_prob": [0.93, 0.71, ...],      # one per measurement
     "diagnostics": {"alpha": 1.2, ...},        # optional, default {}
     "cardinality_pmf": [0.01, 0.2, ...]}       # optional (v3): p(n), n = 0 .. N_max

  ``lag`` (version 4, a header field of ``/tracks`` only; absent = 0) is the number of scans of
  hindsight of a fixed-lag output (:mod:`tracker.lag`): the message of frame ``k`` was made when
  frame ``k + lag`` had arrived.

The API: :func:`decode` (bytes -> validated message), :func:`encode` (message, ``Frame`` or
``Estimate`` -> validated bytes), the conversions :func:`from_frame`, :func:`from_truth`,
:func:`from_estimate` and :func:`to_frame`, :func:`to_truth`, :func:`to_estimate`,
:func:`json_schema`, and :class:`CodecError`.

Validation beyond the JSON types (all errors are :class:`CodecError`, naming topic, frame
and the JSON path; the rules are in the private ``tracker._message_checks``): finite floats
only, ``frame >= 0``, ``0 <= stamp_ns < 2**63``, ``z`` rows of the kind's dimension with values
within the kind's registry bounds (``range >= 0``, ``bearing`` in ``[-pi, pi]``), state
length 5, covariance length 25, existence and probabilities in ``[0, 1]``,
``len(assignments) == len(assignment_prob)``, ``cardinality_pmf`` finite, non-negative and
summing to 1 within 1e-6 (and only in version 3), unique truth ids / track labels, size limits
(``MAX_MEASUREMENTS``, ``MAX_TRACKS``, ``MAX_OBJECTS``, ``MAX_DIAGNOSTICS``), and ``v`` among
the versions the topic reads (anything else: "unsupported schema version").  Unknown fields
are rejected: a change of fields is a new schema version.

Encoding validates too (a NaN would otherwise be written as ``null`` by msgspec).
Pure: msgspec, numpy and ``tracker`` only (no mcap, no zenoh).
"""

from __future__ import annotations

import math
from itertools import chain
from typing import Annotated, Any, Union

import msgspec
import numpy as np

from bnptrack.tracker._message_checks import (
    COV_DIM,
    MAX_DIAGNOSTICS,
    MAX_MEASUREMENTS,
    MAX_OBJECTS,
    MAX_PMF,
    MAX_ROW_DIM,
    MAX_STAMP,
    MAX_TRACKS,
    MEASUREMENTS_SCHEMA_VERSION,
    SCHEMA_VERSION,
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    TRACKS_CLUSTER_VERSION,
    TRACKS_LAG_VERSION,
    TRACKS_SCHEMA_VERSION,
    V1_KINDS,
    CodecError,
    check_measurements,
    check_tracks,
    check_truth,
    decode_error,
    is_int,
    pmf_list_ok,
    unit_ok,
)
from bnptrack.tracker.config import NonNegInt, Prob
from bnptrack.tracker.models.measurement import KINDS, measurement_kind
from bnptrack.tracker.types import STATE_DIM, Estimate, Frame, TrackEstimate, Truth

__all__ = [
    "METADATA_NAME",
    "SCHEMA_VERSION",
    "TOPIC_MEASUREMENTS",
    "TOPIC_TRUTH",
    "TOPIC_TRACKS",
    "MSG_TYPES",
    "CodecError",
    "MeasurementsMsg",
    "TruthMsg",
    "TracksMsg",
    "decode",
    "encode",
    "from_frame",
    "from_truth",
    "from_estimate",
    "to_frame",
    "to_truth",
    "to_estimate",
    "json_schema",
]

#: Name of the MCAP ``Metadata`` record that describes how a log was produced (written by
#: ``sinks.mcap_writer``, read by ``sources.mcap_log``; docs/formats.md).
METADATA_NAME = "bnptrack.scenario"

_chain = chain.from_iterable
_F64 = np.dtype(float)

# --------------------------------------------------------------------------- schema

# The schema's own constraint aliases (the shared ones come from tracker.config).
StampNs = Annotated[int, msgspec.Meta(ge=0, le=MAX_STAMP)]
StateVec = Annotated[list[float], msgspec.Meta(min_length=STATE_DIM, max_length=STATE_DIM)]
CovVec = Annotated[list[float], msgspec.Meta(min_length=COV_DIM, max_length=COV_DIM)]
# The decoder bounds a row (and R) by MAX_ROW_DIM columns; the kind's own dimension is checked
# by tracker._message_checks against the registry, and json_schema states the registry's kinds
# and largest dimension as the registry stands when it is called (a kind registered later is
# read and written without editing this module).
ZRow = Annotated[list[float], msgspec.Meta(min_length=1, max_length=MAX_ROW_DIM)]


class Header(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The four fields every message starts with (in this order on the wire)."""

    v: int = SCHEMA_VERSION
    run: str = ""
    frame: NonNegInt
    stamp_ns: StampNs


class MeasurementsMsg(Header, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """One scan of measurements from one sensor (topic ``/measurements``)."""

    sensor: str
    kind: str
    """A kind of the registry ``tracker.models.measurement.KINDS`` (checked on decode)."""
    z: Annotated[list[ZRow], msgspec.Meta(max_length=MAX_MEASUREMENTS)]
    pose: Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)] | None = None
    """``[x_m, y_m, heading_rad]`` of the sensor for this scan (v2)."""
    R: Annotated[list[Annotated[list[float], msgspec.Meta(max_length=MAX_ROW_DIM)]],
                 msgspec.Meta(max_length=MAX_ROW_DIM)] | None = None
    """``d x d`` measurement noise covariance of this scan's rows (v2)."""


class _MeasurementsMsgV1(Header, frozen=True, kw_only=True):
    """The version-1 fields, to write messages that use no version-2 field."""

    sensor: str
    kind: str
    z: list


class TruthObject(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """One ground-truth object: id and state ``[px, vx, py, vy, omega]``."""

    id: str
    state: StateVec


class TruthMsg(Header, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Ground truth at one frame (topic ``/truth``)."""

    objects: Annotated[list[TruthObject], msgspec.Meta(max_length=MAX_OBJECTS)]


class TrackMsg(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True, omit_defaults=True):
    """One labelled track: mean (5), row-major covariance (25), existence probability, and
    (schema 2, two-level trackers only; omitted otherwise) the id of its motion cluster."""

    label: str
    state: StateVec
    covariance: CovVec
    existence: Prob
    cluster: Union[Annotated[int, msgspec.Meta(ge=0)], None] = None


class TracksMsg(Header, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A tracker's output for one frame (topic ``/tracks``)."""

    lag: Union[NonNegInt, msgspec.UnsetType] = msgspec.UNSET
    """(version 4; not written when 0) scans of hindsight: the output of a fixed-lag layer
    (:mod:`tracker.lag`), made when frame ``frame + lag`` had arrived.  On the wire it follows
    the shared header's four fields."""
    tracks: Annotated[list[TrackMsg], msgspec.Meta(max_length=MAX_TRACKS)]
    assignments: Annotated[
        list[Union[str, None]], msgspec.Meta(max_length=MAX_MEASUREMENTS)
    ]
    assignment_prob: Annotated[list[Prob], msgspec.Meta(max_length=MAX_MEASUREMENTS)]
    diagnostics: Annotated[
        dict[str, float], msgspec.Meta(max_length=MAX_DIAGNOSTICS)
    ] = {}
    cardinality_pmf: Union[Annotated[list[float], msgspec.Meta(max_length=MAX_PMF)], msgspec.UnsetType] = msgspec.UNSET
    """(version 3; not written when unset) the posterior cardinality distribution ``p(n)``,
    ``n = 0 .. N_max`` (:mod:`tracker.cardinality`)."""


Msg = Union[MeasurementsMsg, TruthMsg, TracksMsg]

#: Message type per topic.
MSG_TYPES: dict[str, type] = {
    TOPIC_MEASUREMENTS: MeasurementsMsg,
    TOPIC_TRUTH: TruthMsg,
    TOPIC_TRACKS: TracksMsg,
}
#: The validation of each message type.
_CHECKS = {MeasurementsMsg: check_measurements, TruthMsg: check_truth, TracksMsg: check_tracks}

_ENCODER = msgspec.json.Encoder()
_DECODERS = {topic: msgspec.json.Decoder(t) for topic, t in MSG_TYPES.items()}


def json_schema(msg_type: type | str) -> dict:
    """JSON schema (draft 2020-12, via ``msgspec.json.schema``) of a message type or topic."""
    if isinstance(msg_type, str):
        try:
            msg_type = MSG_TYPES[msg_type]
        except KeyError:
            raise ValueError(f"unknown topic {msg_type!r}") from None
    schema = msgspec.json.schema(msg_type)
    if msg_type is MeasurementsMsg:
        _registry_bounds(schema["$defs"]["MeasurementsMsg"]["properties"])
    return schema


def _registry_bounds(props: dict) -> None:
    """State the registry's kinds (an ``enum``) and largest row dimension (``maxItems`` of a
    ``z`` row and of ``R``) in the ``/measurements`` schema's properties, in place."""
    d = max(k.dim for k in KINDS.values())
    props["kind"] = {"enum": list(KINDS)}
    props["z"]["items"]["maxItems"] = d
    r = props["R"]["anyOf"][0]
    r["maxItems"] = r["items"]["maxItems"] = d


# --------------------------------------------------------------------------- decode


def decode(topic: str, data: bytes | bytearray | memoryview | str) -> Msg:
    """Decode and validate the message of a known topic (``ValueError`` for another topic)."""
    try:
        decoder = _DECODERS[topic]
    except KeyError:
        raise ValueError(f"unknown topic {topic!r}") from None
    try:
        msg = decoder.decode(data)
    except msgspec.DecodeError as exc:  # ValidationError is a subclass
        raw = data.encode() if isinstance(data, str) else data
        raise decode_error(topic, raw, exc) from None
    _CHECKS[type(msg)](msg)
    return msg


def to_frame(msg: MeasurementsMsg, truth: Truth | None = None) -> Frame:
    """A measurements message checked by :func:`decode` as a :class:`Frame`.  Its ``z`` is
    not checked again (:meth:`Frame.checked`: the codec's checks are the edge's); a message
    not from :func:`decode` goes through ``Frame(...)`` instead."""
    d = measurement_kind(msg.kind).dim
    z = (
        np.fromiter(_chain(msg.z), dtype=float, count=len(msg.z) * d).reshape(-1, d)
        if msg.z
        else np.zeros((0, d))
    )
    return Frame.checked(msg.frame, msg.stamp_ns, msg.sensor, msg.kind, z, truth,
                         None if msg.pose is None else tuple(msg.pose),
                         None if msg.R is None else np.array(msg.R, dtype=float))


def to_truth(msg: TruthMsg) -> Truth:
    """A (validated) truth message as :class:`Truth` (its frame and stamp are ``msg.frame`` and
    ``msg.stamp_ns``)."""
    states = (
        np.array([o.state for o in msg.objects], dtype=float)
        if msg.objects
        else np.zeros((0, STATE_DIM))
    )
    return Truth(ids=tuple(o.id for o in msg.objects), states=states)


def to_estimate(msg: TracksMsg) -> Estimate:
    """A (validated) tracks message as an :class:`Estimate`.  A message older than version 4
    that carries its lag as the diagnostic ``lag`` (as fixed-lag logs once did) gets it as
    :attr:`Estimate.lag`."""
    diagnostics = dict(msg.diagnostics)
    lag = msg.lag
    if lag is msgspec.UNSET:
        old = diagnostics.pop("lag", 0.0)
        lag = int(old) if float(old).is_integer() and old >= 0 else 0
        if lag == 0 and old != 0.0:
            diagnostics["lag"] = old
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
        diagnostics=diagnostics,
        cardinality_pmf=None if msg.cardinality_pmf is msgspec.UNSET else np.array(msg.cardinality_pmf, dtype=float),
        lag=lag,
    )


# --------------------------------------------------------------------------- encode


def _as_int(topic: str, frame: Any, value: Any, name: str) -> int:
    if not is_int(value):
        raise CodecError(topic, frame if is_int(frame) else None, f"{name} must be an integer, got {value!r} - at `$.{name}`")
    return int(value)


def from_frame(frame: Frame, run: str = "") -> MeasurementsMsg:
    """The ``/measurements`` message of ``frame`` (built, not validated: :func:`encode` checks;
    version 2 only when it uses a version-2 addition)."""
    topic = TOPIC_MEASUREMENTS
    idx = _as_int(topic, frame.frame, frame.frame, "frame")
    z = np.asarray(frame.z, dtype=float)
    pose = getattr(frame, "pose", None)
    R = getattr(frame, "R", None)
    v2 = pose is not None or R is not None or frame.kind not in V1_KINDS
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


def from_truth(frame_index: int, stamp_ns: int, truth: Truth, run: str = "") -> TruthMsg:
    """The ``/truth`` message of ``truth`` at a frame (built, not validated)."""
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


def _tracks_version(tracks: list[TrackMsg], pmf: Any, lag: Any = msgspec.UNSET) -> int:
    """The lowest ``/tracks`` version with the fields used (4: a lag; 3: a pmf; 2: a cluster;
    else 1)."""
    if lag is not msgspec.UNSET:
        return TRACKS_LAG_VERSION
    if pmf is not msgspec.UNSET:
        return TRACKS_SCHEMA_VERSION
    return TRACKS_CLUSTER_VERSION if any(t.cluster is not None for t in tracks) else SCHEMA_VERSION


def _pmf_field(pmf: Any) -> Any:
    """The wire value of an estimate's ``cardinality_pmf`` (``UNSET``: not written)."""
    return msgspec.UNSET if pmf is None else np.asarray(pmf, dtype=float).ravel().tolist()


def from_estimate(est: Estimate, run: str = "") -> TracksMsg:
    """The ``/tracks`` message of ``est`` (built, not validated)."""
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
    pmf = _pmf_field(getattr(est, "cardinality_pmf", None))
    lag = _lag_field(getattr(est, "lag", 0))
    return TracksMsg(
        v=_tracks_version(tracks, pmf, lag),
        run=run,
        frame=idx,
        stamp_ns=_as_int(topic, idx, est.stamp_ns, "stamp_ns"),
        lag=lag,
        tracks=tracks,
        assignments=[None if a is None else str(a) for a in est.assignments],
        assignment_prob=np.asarray(est.assignment_prob, dtype=float).ravel().tolist(),
        diagnostics={str(k): float(v) for k, v in est.diagnostics.items()},
        cardinality_pmf=pmf,
    )


def _lag_field(lag: Any) -> Any:
    """The wire value of an estimate's ``lag`` (``UNSET``: 0, not written; anything else than
    an integer is left to the check to name)."""
    return msgspec.UNSET if is_int(lag) and lag == 0 else lag


def _plain_tracks_msg(est: Estimate, run: str) -> TracksMsg | None:
    """The message :func:`from_estimate` builds, checked as it is built by the contract's quick
    tests (``tracker._message_checks``: plain Python on lists; two numpy calls to stack track
    arrays that are not float64, none otherwise): ``None`` when one fails or the estimate is
    not the common one, and :func:`encode` then takes the reference path (:func:`from_estimate`
    and every check), which names the error or writes what the quick tests were too cautious
    for (the same bytes)."""
    tracks, n = est.tracks, len(est.tracks)
    frame, stamp, lag = est.frame, est.stamp_ns, est.lag
    if type(frame) is not int or frame < 0 or type(stamp) is not int or not 0 <= stamp <= MAX_STAMP \
            or type(lag) is not int or lag < 0 \
            or type(run) is not str or n > MAX_TRACKS or len(est.diagnostics) > MAX_DIAGNOSTICS:
        return None
    try:
        probs = [float(p) for p in est.assignment_prob]
        exist = [float(t.existence) for t in tracks]
        diag = {str(k): float(v) for k, v in est.diagnostics.items()}
        rows = _plain_rows(tracks, n)
        pmf = _plain_pmf_field(getattr(est, "cardinality_pmf", None))
    except (TypeError, ValueError):
        return None
    labels = [str(t.label) for t in tracks]
    if rows is None or pmf is None or len(set(labels)) != n or len(est.assignments) != len(probs) \
            or len(probs) > MAX_MEASUREMENTS or not (unit_ok(probs) and unit_ok(exist)) \
            or not math.isfinite(sum(diag.values())):
        return None
    msgs = [TrackMsg(label=lab, state=st, covariance=cv, existence=ex,
                     cluster=None if t.cluster is None else int(t.cluster))
            for lab, st, cv, ex, t in zip(labels, rows[0], rows[1], exist, tracks)]
    lag = msgspec.UNSET if lag == 0 else lag
    return TracksMsg(v=_tracks_version(msgs, pmf, lag), run=run, frame=frame, stamp_ns=stamp, lag=lag, tracks=msgs,
                     assignments=[None if a is None else str(a) for a in est.assignments],
                     assignment_prob=probs, diagnostics=diag, cardinality_pmf=pmf)


def _plain_rows(tracks: tuple, n: int) -> tuple[list, list] | None:
    """The tracks' states ``(n, 5)`` and covariances ``(n, 25)`` as lists of rows, all finite
    (``None`` otherwise; ``ValueError`` for ragged ones): each float64 array read by its own
    ``tolist`` (no array built), anything else stacked by numpy."""
    if all(type(t.state) is np.ndarray and t.state.dtype == _F64 and t.state.shape == (STATE_DIM,)
           and type(t.covariance) is np.ndarray and t.covariance.dtype == _F64
           and t.covariance.shape == (STATE_DIM, STATE_DIM) for t in tracks):
        s = [t.state.tolist() for t in tracks]
        c = [list(_chain(t.covariance.tolist())) for t in tracks]
    elif n:
        states = np.array([t.state for t in tracks], dtype=float)
        covs = np.array([t.covariance for t in tracks], dtype=float)
        if states.shape != (n, STATE_DIM) or covs.shape != (n, STATE_DIM, STATE_DIM):
            return None
        s, c = states.tolist(), covs.reshape(n, COV_DIM).tolist()
    else:
        return [], []
    return (s, c) if math.isfinite(sum(map(sum, s)) + sum(map(sum, c))) else None


def _plain_pmf_field(pmf: Any) -> Any:
    """The wire value of a ``cardinality_pmf`` (``UNSET``: none) when it passes
    ``pmf_list_ok``, else ``None``."""
    if pmf is None:
        return msgspec.UNSET
    if type(pmf) is np.ndarray and pmf.dtype == _F64 and pmf.ndim == 1:
        values = pmf.tolist()
    else:
        values = np.asarray(pmf, dtype=float).ravel().tolist()
    return values if pmf_list_ok(values) else None


def _encode_msg(msg: Msg) -> bytes:
    """Validate and JSON-encode a message struct (a ``/measurements`` message without
    ``pose`` and ``R`` is written without those fields)."""
    check = _CHECKS.get(type(msg))
    if check is None:
        raise TypeError(f"not a bnptrack message: {type(msg).__name__}")
    check(msg)
    if isinstance(msg, MeasurementsMsg) and msg.pose is None and msg.R is None:
        return _ENCODER.encode(_MeasurementsMsgV1(v=msg.v, run=msg.run, frame=msg.frame, stamp_ns=msg.stamp_ns,
                                                  sensor=msg.sensor, kind=msg.kind, z=msg.z))
    return _ENCODER.encode(msg)


def encode(item: Msg | Frame | Estimate, run: str = "") -> bytes:
    """Validated JSON bytes of a message.

    ``item`` is a message struct (it carries its own ``run``: pass none), a :class:`Frame`
    (its ``/measurements`` message; the truth is not included: encode :func:`from_truth`) or an
    :class:`Estimate` (its ``/tracks`` message: the common estimate's checked by the rules'
    quick tests as it is built; anything off takes the message path, :func:`from_estimate`
    and every check, which names the exact error).  The rules are those of
    ``tracker._message_checks``, for decoding and encoding alike.
    """
    if isinstance(item, Estimate):
        msg = _plain_tracks_msg(item, run)
        return _encode_msg(from_estimate(item, run)) if msg is None else _ENCODER.encode(msg)
    if isinstance(item, Frame):
        return _encode_msg(from_frame(item, run))
    if run:
        raise ValueError("encode: a message carries its own run; pass run only with a Frame or an Estimate")
    return _encode_msg(item)
