"""The ``/tracks`` header field ``lag`` (schema version 4): written only when above 0, read back
as ``Estimate.lag``; older messages (no field, or the lag once carried as a diagnostic) decode."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bnptrack.tracker.message_encode import _encode_msg
from bnptrack.tracker.messages import TOPIC_TRACKS, CodecError, decode, encode, from_estimate, to_estimate
from bnptrack.tracker.types import Estimate, TrackEstimate


def _est(lag: int, pmf=None) -> Estimate:
    t = TrackEstimate("t1", np.arange(5.0), np.eye(5), 0.8)
    return Estimate(7, 1_000, (t,), ("t1",), (0.9,), {"alpha": 1.5}, pmf, lag=lag)


def _raw(**over) -> bytes:
    obj = {"v": 4, "run": "", "frame": 7, "stamp_ns": 0, "lag": 2, "tracks": [], "assignments": [],
           "assignment_prob": []}
    obj.update(over)
    return json.dumps(obj).encode()


def test_a_lagged_estimate_is_version_4_with_lag_after_the_header():
    data = encode(_est(3))
    assert list(json.loads(data))[:5] == ["v", "run", "frame", "stamp_ns", "lag"]
    assert json.loads(data)["v"] == 4 and json.loads(data)["lag"] == 3
    back = to_estimate(decode(TOPIC_TRACKS, data))
    assert back.lag == 3 and back.diagnostics == {"alpha": 1.5}
    assert encode(back) == data == _encode_msg(from_estimate(back))  # quick path == message path
    both = json.loads(encode(_est(1, pmf=[0.25, 0.75])))
    assert both["v"] == 4 and both["cardinality_pmf"] == [0.25, 0.75]


def test_an_online_estimate_writes_no_lag_and_keeps_its_version():
    obj = json.loads(encode(_est(0)))
    assert "lag" not in obj and obj["v"] == 1
    assert json.loads(encode(_est(0, pmf=[1.0])))["v"] == 3


@pytest.mark.parametrize("v", [1, 2, 3])
def test_old_messages_decode_with_lag_0_or_their_diagnostic_lag(v):
    raw = {"v": v, "run": "", "frame": 7, "stamp_ns": 0, "tracks": [], "assignments": [], "assignment_prob": []}
    assert to_estimate(decode(TOPIC_TRACKS, json.dumps(raw).encode())).lag == 0
    old = to_estimate(decode(TOPIC_TRACKS, json.dumps({**raw, "diagnostics": {"lag": 3.0, "alpha": 1.0}}).encode()))
    assert old.lag == 3 and old.diagnostics == {"alpha": 1.0}


@pytest.mark.parametrize("over, fragment", [
    ({"v": 3}, "lag needs schema version 4"),
    ({"lag": -1}, "$.lag"),
    ({"lag": 1.5}, "$.lag"),
])
def test_a_bad_lag_is_rejected_in_one_line_naming_the_field(over, fragment):
    with pytest.raises(CodecError) as ei:
        decode(TOPIC_TRACKS, _raw(**over))
    assert fragment in str(ei.value) and "\n" not in str(ei.value)


def test_encode_rejects_a_negative_lag():
    with pytest.raises(CodecError, match=r"\$\.lag"):
        encode(_est(-2))
