"""The message contract's schema (:mod:`tracker.messages`): the msgspec structs of the three
messages (:class:`MeasurementsMsg`, :class:`TruthMsg`, :class:`TracksMsg`, each starting with
the shared :class:`Header`), the message type and the checks of each topic, and their JSON
schema (:func:`json_schema`).  The checks themselves are in ``tracker._message_checks``."""

from __future__ import annotations

from typing import Annotated, Union

import msgspec

from bnptrack.tracker._message_checks import (
    COV_DIM,
    MAX_DIAGNOSTICS,
    MAX_MEASUREMENTS,
    MAX_OBJECTS,
    MAX_PMF,
    MAX_ROW_DIM,
    MAX_STAMP,
    MAX_TRACKS,
    SCHEMA_VERSION,
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    check_measurements,
    check_tracks,
    check_truth,
)
from bnptrack.tracker.config import NonNegInt, Prob
from bnptrack.tracker.models.measurement import KINDS
from bnptrack.tracker.types import STATE_DIM

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

