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
Pure: msgspec, numpy and ``tracker`` only (no mcap, no zenoh).  This module decodes; the
schema is :mod:`tracker.message_schema`, the encoding :mod:`tracker.message_encode` (every
name is importable from here).
"""


from __future__ import annotations

from itertools import chain

import msgspec
import numpy as np

from bnptrack.tracker._message_checks import (  # noqa: F401  (the contract's constants, importable from here)
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
    decode_error,
)
from bnptrack.tracker.message_encode import encode, from_estimate, from_frame, from_truth
from bnptrack.tracker.message_schema import (  # noqa: F401  (the schema, importable from here)
    _CHECKS,
    MSG_TYPES,
    CovVec,
    Header,
    MeasurementsMsg,
    Msg,
    StampNs,
    StateVec,
    TrackMsg,
    TracksMsg,
    TruthMsg,
    TruthObject,
    ZRow,
    json_schema,
)
from bnptrack.tracker.models.measurement import measurement_kind
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
_DECODERS = {topic: msgspec.json.Decoder(t) for topic, t in MSG_TYPES.items()}


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
