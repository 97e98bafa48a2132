"""The encoding half of the message contract (:mod:`tracker.messages`): the messages of a
:class:`Frame`, a :class:`Truth` and an :class:`Estimate` (:func:`from_frame`,
:func:`from_truth`, :func:`from_estimate`) and validated JSON bytes of any of them
(:func:`encode`), the common estimate's message checked by the rules' quick tests as it is
built (:func:`_plain_tracks_msg`)."""

from __future__ import annotations

import math
from itertools import chain
from typing import Any

import msgspec
import numpy as np

from bnptrack.tracker._message_checks import (
    COV_DIM,
    MAX_DIAGNOSTICS,
    MAX_MEASUREMENTS,
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
    is_int,
    pmf_list_ok,
    unit_ok,
)
from bnptrack.tracker.message_schema import (_CHECKS, MeasurementsMsg, Msg, TrackMsg, TracksMsg, TruthMsg, TruthObject,
                                             _MeasurementsMsgV1)
from bnptrack.tracker.types import STATE_DIM, Estimate, Frame, Truth

_chain = chain.from_iterable
_F64 = np.dtype(float)
_ENCODER = msgspec.json.Encoder()


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
