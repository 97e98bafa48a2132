"""The unit (and meaning) of every field of the ``/measurements``, ``/truth`` and ``/tracks``
messages (docs/formats.md), for ``bnptrack schema``: :func:`described_schema` is the JSON Schema
of :func:`tracker.messages.json_schema` with each property's ``description`` set from
:data:`FIELD_UNITS`.  The schema stored in MCAP logs stays :func:`~tracker.messages.json_schema`'s."""

from __future__ import annotations

import copy

from bnptrack.tracker.messages import json_schema

__all__ = ["FIELD_UNITS", "described_schema"]

_STATE = "[px m, vx m/s, py m, vy m/s, omega rad/s] (x east, y north; omega anticlockwise)"
_HEADER = {
    "v": "schema version (integer, no unit)",
    "run": "run id (text, no unit)",
    "frame": "frame (scan) number, no unit",
    "stamp_ns": "time stamp, ns (since the Unix epoch, UTC, or since the log's own origin)",
}

#: Message definition -> property -> its unit and meaning.
FIELD_UNITS: dict[str, dict[str, str]] = {
    "MeasurementsMsg": {
        **_HEADER,
        "sensor": "sensor name (text, no unit)",
        "kind": "measurement kind (text): sets the units of z",
        "z": "measurement rows: bearing_range [bearing rad from the boresight, clockwise; range m], "
             "range [range m], xy [x m east, y m north]",
        "pose": "sensor pose [x m, y m, heading rad from +y towards +x]",
        "R": "measurement noise covariance, d x d, in the units of z squared (rad^2, m^2, rad m)",
    },
    "TruthMsg": {**_HEADER, "objects": "true objects (see TruthObject)"},
    "TruthObject": {"id": "object id (text, no unit)", "state": "state " + _STATE},
    "TracksMsg": {
        **_HEADER,
        "lag": "scans of hindsight (integer, no unit): 0 or absent online; N for a fixed-lag output, "
               "made when frame + N had arrived",
        "tracks": "reported tracks (see TrackMsg)",
        "assignments": "per measurement, in the order of z: the track label it was assigned to, or null",
        "assignment_prob": "per measurement: probability of its assignment, 0..1 (no unit)",
        "diagnostics": "tracker diagnostics by name: alpha, d, n_clusters, n_tracks, log_joint (no unit), "
                       "ms (milliseconds per frame)",
        "cardinality_pmf": "posterior probability of n = 0, 1, ... objects, 0..1 (no unit)",
    },
    "TrackMsg": {
        "label": "track label (text; its display name is tracker.types.display_name(label))",
        "state": "mean state " + _STATE,
        "covariance": "state covariance, 5 x 5 row-major, in products of the state units (m^2, m^2/s^2, ...)",
        "existence": "existence probability, 0..1 (no unit)",
        "cluster": "motion cluster id (integer, no unit)",
    },
}


def described_schema(topic: str) -> dict:
    """The JSON Schema of ``topic``'s messages with each property's unit as its ``description``."""
    schema = copy.deepcopy(json_schema(topic))
    for name, definition in schema.get("$defs", {}).items():
        units = FIELD_UNITS.get(name, {})
        for prop, body in definition.get("properties", {}).items():
            if prop in units:
                body["description"] = units[prop]
    return schema
