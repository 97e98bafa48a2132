"""`bnptrack schema` states each field's unit; the schema stored in logs is unchanged."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.tracker.message_units import FIELD_UNITS, described_schema
from bnptrack.tracker.messages import MSG_TYPES, json_schema


@pytest.mark.parametrize("topic", sorted(MSG_TYPES))
def test_every_field_has_its_unit(topic):
    doc = json.loads(CliRunner().invoke(main, ["schema", topic]).output)
    assert doc == described_schema(topic)
    for name, definition in doc["$defs"].items():
        for prop, body in definition["properties"].items():
            assert body["description"] == FIELD_UNITS[name][prop], (name, prop)
    # the stored schema (json_schema) carries no per-field descriptions
    stored = json_schema(topic)
    assert all("description" not in body for d in stored["$defs"].values() for body in d["properties"].values())


def test_units_named():
    assert "ns" in FIELD_UNITS["TracksMsg"]["stamp_ns"]
    assert "m/s" in FIELD_UNITS["TrackMsg"]["state"] and "rad/s" in FIELD_UNITS["TruthObject"]["state"]
    assert "heading rad" in FIELD_UNITS["MeasurementsMsg"]["pose"]
