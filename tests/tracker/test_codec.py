"""Tests for the versioned JSON message schema (tracker.messages)."""

from __future__ import annotations

import json
import math
import pickle

import msgspec
import numpy as np
import pytest

from bnptrack.tracker._message_checks import check_measurements, check_tracks
from bnptrack.tracker.messages import (
    MAX_MEASUREMENTS,
    MAX_TRACKS,
    SCHEMA_VERSION,
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    CodecError,
    MeasurementsMsg,
    TracksMsg,
    TruthMsg,
    decode,
    encode,
    from_truth,
    json_schema,
    to_estimate,
    to_frame,
    to_truth,
)
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, Truth

from testkit import REPO_ROOT


# --------------------------------------------------------------------------- helpers


def make_frame(rng, k=7, kind="bearing_range", m=20, stamp=None) -> Frame:
    if kind == "bearing_range":
        z = np.c_[rng.uniform(-np.pi, np.pi, m), rng.uniform(0.0, 2000.0, m)]
    else:
        z = rng.uniform(0.0, 2000.0, (m, 1))
    return Frame(
        frame=k,
        stamp_ns=stamp if stamp is not None else 1_700_000_000_000_000_000 + k,
        sensor="radar0",
        kind=kind,
        z=z,
    )


def make_truth(rng, n=4) -> Truth:
    return Truth(ids=tuple(f"obj{i}" for i in range(n)), states=rng.normal(0, 100, (n, 5)))


def make_estimate(rng, k=7, n=3, m=6) -> Estimate:
    tracks = []
    for i in range(n):
        a = rng.normal(size=(5, 5))
        tracks.append(
            TrackEstimate(
                label=f"t{i}",
                state=rng.normal(0, 100, 5),
                covariance=a @ a.T,
                existence=float(rng.uniform()),
            )
        )
    labels = [f"t{i}" for i in range(n)] + [None]
    assignments = tuple(labels[int(j)] for j in rng.integers(0, n + 1, m))
    return Estimate(
        frame=k,
        stamp_ns=123_456_789 + k,
        tracks=tuple(tracks),
        assignments=assignments,
        assignment_prob=tuple(float(p) for p in rng.uniform(0, 1, m)),
        diagnostics={"alpha": 1.25, "n_clusters": 3.0, "loglik": -123.456, "ms": 2.5},
    )


def assert_frames_equal(a: Frame, b: Frame) -> None:
    assert (a.frame, a.stamp_ns, a.sensor, a.kind) == (b.frame, b.stamp_ns, b.sensor, b.kind)
    assert a.z.shape == b.z.shape
    assert np.array_equal(a.z, b.z)


def assert_estimates_equal(a: Estimate, b: Estimate) -> None:
    assert (a.frame, a.stamp_ns) == (b.frame, b.stamp_ns)
    assert len(a.tracks) == len(b.tracks)
    for s, t in zip(a.tracks, b.tracks):
        assert s.label == t.label
        assert np.array_equal(np.asarray(s.state), t.state)
        assert np.array_equal(np.asarray(s.covariance), t.covariance)
        assert t.covariance.shape == (5, 5)
        assert s.existence == t.existence
    assert tuple(a.assignments) == tuple(b.assignments)
    assert tuple(a.assignment_prob) == tuple(b.assignment_prob)
    assert a.diagnostics == b.diagnostics


def raw(obj) -> bytes:
    return json.dumps(obj).encode()


def meas_obj(**over):
    obj = {
        "frame": 7,
        "stamp_ns": 1000,
        "sensor": "radar0",
        "kind": "bearing_range",
        "z": [[0.1, 10.0], [-0.2, 20.0]],
    }
    obj.update(over)
    return obj


def tracks_obj(**over):
    obj = {
        "frame": 7,
        "stamp_ns": 1000,
        "tracks": [
            {"label": "t1", "state": [1.0] * 5, "covariance": [0.0] * 25, "existence": 0.9}
        ],
        "assignments": ["t1", None],
        "assignment_prob": [0.8, 0.1],
    }
    obj.update(over)
    return obj


def truth_obj(**over):
    obj = {"frame": 7, "stamp_ns": 1000, "objects": [{"id": "a", "state": [1.0] * 5}]}
    obj.update(over)
    return obj


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("kind", ["bearing_range", "range"])
@pytest.mark.parametrize("m", [0, 1, 57])
def test_measurements_round_trip(kind, m):
    rng = np.random.default_rng(1 + m)
    f = make_frame(rng, kind=kind, m=m)
    g = to_frame(decode(TOPIC_MEASUREMENTS, encode(f)))
    assert_frames_equal(f, g)
    assert g.truth is None
    assert g.z.dtype == np.float64


def test_measurements_round_trip_edge_values():
    z = np.array([[np.pi, 0.0], [-np.pi, 1e-300], [-0.0, 1e300], [1 / 3, 5e-324]])
    f = Frame(0, 0, "s", "bearing_range", z)
    g = to_frame(decode(TOPIC_MEASUREMENTS, encode(f)))
    assert np.array_equal(g.z, z)
    assert math.copysign(1.0, g.z[2, 0]) == -1.0  # -0.0 survives


def test_measurements_json_field_names_and_run():
    rng = np.random.default_rng(2)
    f = make_frame(rng, k=3, m=2)
    obj = json.loads(encode(f, run="run-42"))
    assert set(obj) == {"v", "run", "frame", "stamp_ns", "sensor", "kind", "z"}
    assert obj["v"] == SCHEMA_VERSION == 1  # version 2 only when a message uses its additions
    assert obj["run"] == "run-42"
    assert obj["frame"] == 3 and obj["kind"] == "bearing_range" and obj["sensor"] == "radar0"
    assert obj["z"] == f.z.tolist()
    assert decode(TOPIC_MEASUREMENTS, encode(f, run="run-42")).run == "run-42"


def test_measurements_five_fields_only_decode():
    f = to_frame(decode(TOPIC_MEASUREMENTS, raw(meas_obj())))
    assert f.frame == 7 and f.stamp_ns == 1000
    assert np.array_equal(f.z, [[0.1, 10.0], [-0.2, 20.0]])
    msg = decode(TOPIC_MEASUREMENTS, raw(meas_obj()))
    assert msg.v == SCHEMA_VERSION and msg.run == ""
    g = to_frame(decode(TOPIC_MEASUREMENTS, raw(meas_obj(kind="range", z=[[1.0], [2.5]]))))
    assert g.z.shape == (2, 1)


def test_integer_json_numbers_accepted_as_floats():
    f = to_frame(decode(TOPIC_MEASUREMENTS, raw(meas_obj(z=[[0, 10]]))))
    assert f.z.dtype == np.float64 and np.array_equal(f.z, [[0.0, 10.0]])


def test_numpy_scalars_encode():
    rng = np.random.default_rng(3)
    f = Frame(np.int64(4), np.int64(99), "s", "range", rng.uniform(0, 1, (3, 1)))
    assert to_frame(decode(TOPIC_MEASUREMENTS, encode(f))).frame == 4


def test_truth_round_trip():
    rng = np.random.default_rng(4)
    t = make_truth(rng, 5)
    data = encode(from_truth(11, 777, t, run="r"))
    obj = json.loads(data)
    assert set(obj) == {"v", "run", "frame", "stamp_ns", "objects"}
    assert set(obj["objects"][0]) == {"id", "state"}
    msg = decode(TOPIC_TRUTH, data)
    k, stamp, u = msg.frame, msg.stamp_ns, to_truth(msg)
    assert (k, stamp) == (11, 777)
    assert u.ids == t.ids
    assert np.array_equal(u.states, t.states)


def test_truth_empty_round_trip():
    t = Truth(ids=(), states=np.zeros((0, 5)))
    u = to_truth(decode(TOPIC_TRUTH, encode(from_truth(0, 0, t))))
    assert u.ids == () and u.states.shape == (0, 5)


def test_tracks_round_trip():
    rng = np.random.default_rng(5)
    est = make_estimate(rng)
    data = encode(est, run="r1")
    obj = json.loads(data)
    assert set(obj) == {
        "v", "run", "frame", "stamp_ns", "tracks", "assignments", "assignment_prob", "diagnostics",
    }
    assert set(obj["tracks"][0]) == {"label", "state", "covariance", "existence"}
    assert len(obj["tracks"][0]["covariance"]) == 25
    # row-major covariance
    assert obj["tracks"][0]["covariance"][1] == est.tracks[0].covariance[0, 1]
    assert obj["tracks"][0]["covariance"][5] == est.tracks[0].covariance[1, 0]
    assert_estimates_equal(est, to_estimate(decode(TOPIC_TRACKS, data)))


def test_tracks_empty_and_default_diagnostics():
    est = Estimate(frame=0, stamp_ns=0, tracks=())
    out = to_estimate(decode(TOPIC_TRACKS, encode(est)))
    assert out.tracks == () and out.assignments == () and out.diagnostics == {}
    # diagnostics is optional on decode
    obj = tracks_obj()
    assert "diagnostics" not in obj
    assert to_estimate(decode(TOPIC_TRACKS, raw(obj))).diagnostics == {}


def test_json_schema():
    for t, topic in [
        (MeasurementsMsg, TOPIC_MEASUREMENTS),
        (TruthMsg, TOPIC_TRUTH),
        (TracksMsg, TOPIC_TRACKS),
    ]:
        s = json_schema(t)
        assert s == json_schema(topic)
        json.dumps(s)
        defs = s["$defs"][t.__name__]
        assert "frame" in defs["properties"] and "v" in defs["properties"]
        assert "v" not in defs["required"] and "run" not in defs["required"]
        assert defs["additionalProperties"] is False
    props = json_schema(MeasurementsMsg)["$defs"]["MeasurementsMsg"]["properties"]
    assert props["kind"]["enum"] == ["bearing_range", "range", "xy"]
    with pytest.raises(ValueError):
        json_schema("/nope")


# --------------------------------------------------------------------------- rejection


def check_err(exc_info, topic, frame, *fragments):
    e = exc_info.value
    assert isinstance(e, ValueError)
    assert e.topic == topic
    assert e.frame == frame
    text = str(e)
    assert topic in text
    if frame is not None:
        assert f"frame {frame}" in text
    for frag in fragments:
        assert frag in text, text


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_encode_rejects_non_finite_measurement(bad):
    rng = np.random.default_rng(6)
    f = make_frame(rng, k=7, m=5)
    z = f.z.copy()
    z[3, 1] = bad
    with pytest.raises(ValueError, match=r"^Frame 7: measurement row 3 is not finite"):
        Frame(7, 1, "s", "bearing_range", z)  # refused at construction (tracker/types.py)
    edited = Frame(7, 1, "s", "bearing_range", f.z.copy())
    edited.z[3, 1] = bad  # written in place after construction: the encoder still refuses it
    with pytest.raises(CodecError) as ei:
        encode(edited)
    check_err(ei, TOPIC_MEASUREMENTS, 7, "non-finite", "$.z[3][1]")


@pytest.mark.parametrize(
    "text, fragment",
    [
        (b'{"frame": 7, "stamp_ns": 1, "sensor": "s", "kind": "range", "z": [[NaN]]}', "non-finite"),
        (b'{"frame": 7, "stamp_ns": 1, "sensor": "s", "kind": "range", "z": [[Infinity]]}', "non-finite"),
        (b'{"frame": 7, "stamp_ns": 1, "sensor": "s", "kind": "range", "z": [[null]]}', "$.z[0][0]"),
        (b'{"frame": 7, "stamp_ns": 1, "sensor": "s", "kind": "range", "z": [[1e999]]}', "$.z[0][0]"),
    ],
)
def test_decode_rejects_non_finite(text, fragment):
    with pytest.raises(CodecError) as ei:
        to_frame(decode(TOPIC_MEASUREMENTS, text))
    check_err(ei, TOPIC_MEASUREMENTS, 7, fragment)


def test_validate_rejects_nan_in_hand_built_struct():
    msg = MeasurementsMsg(frame=2, stamp_ns=0, sensor="s", kind="bearing_range", z=[[0.0, 1.0], [0.1, math.nan]])
    with pytest.raises(CodecError) as ei:
        check_measurements(msg)
    check_err(ei, TOPIC_MEASUREMENTS, 2, "non-finite", "$.z[1][1]")
    with pytest.raises(CodecError):
        encode(msg)
    tmsg = TracksMsg(
        frame=3, stamp_ns=0, tracks=[], assignments=[None], assignment_prob=[math.nan]
    )
    with pytest.raises(CodecError) as ei:
        check_tracks(tmsg)
    check_err(ei, TOPIC_TRACKS, 3, "$.assignment_prob[0]")


@pytest.mark.parametrize(
    "over, frame, fragments",
    [
        ({"frame": -1}, -1, ["$.frame"]),
        ({"stamp_ns": -5}, 7, ["$.stamp_ns"]),
        ({"z": [[0.1]]}, 7, ["length 1, expected 2", "$.z[0]"]),
        ({"z": [[0.1, 1.0], [0.2, 3.0, 4.0]]}, 7, ["$.z[1]"]),
        ({"kind": "range", "z": [[1.0], [0.1, 2.0]]}, 7, ["length 2, expected 1", "$.z[1]"]),
        ({"z": [[0.1, -1.0]]}, 7, ["range must be >= 0", "$.z[0][1]"]),
        ({"kind": "range", "z": [[-0.5]]}, 7, ["range must be >= 0", "$.z[0][0]"]),
        ({"z": [[0.0, 1.0], [3.2, 1.0]]}, 7, ["bearing", "$.z[1][0]"]),
        ({"z": [[-3.15, 1.0]]}, 7, ["bearing", "$.z[0][0]"]),
        ({"v": 3}, 7, ["unsupported schema version 3", "reads versions 1 and 2"]),
        ({"v": 0}, 7, ["unsupported schema version 0"]),
        ({"v": 3, "new_field": [1, 2]}, 7, ["unsupported schema version 3"]),
        ({"extra": 1}, 7, ["unknown field", "extra"]),
        ({"pose": [1.0, 2.0]}, 7, ["$.pose"]),
        ({"pose": "abc"}, 7, ["$.pose"]),
        ({"R": [[1.0, 0.0], [0.0]]}, 7, ["R must be 2x2", "$.R"]),
        ({"R": [[1.0, 2.0], [2.0, 1.0]]}, 7, ["positive definite", "$.R"]),
        ({"kind": "range", "z": [[1.0]], "R": [[1.0, 0.0], [0.0, 1.0]]}, 7, ["R must be 1x1"]),
        ({"frame": "7"}, None, ["$.frame"]),
        ({"frame": 7.5}, None, ["$.frame"]),
        ({"z": "abc"}, 7, ["$.z"]),
        ({"z": [["a", 1.0]]}, 7, ["$.z[0][0]"]),
        ({"kind": "sonar"}, 7, ["$.kind"]),
        ({"sensor": 5}, 7, ["$.sensor"]),
        ({"run": None}, 7, ["$.run"]),
    ],
)
def test_decode_measurements_rejects(over, frame, fragments):
    with pytest.raises(CodecError) as ei:
        to_frame(decode(TOPIC_MEASUREMENTS, raw(meas_obj(**over))))
    check_err(ei, TOPIC_MEASUREMENTS, frame, *fragments)


def test_decode_rejects_missing_field_and_garbage():
    obj = meas_obj()
    del obj["kind"]
    with pytest.raises(CodecError) as ei:
        to_frame(decode(TOPIC_MEASUREMENTS, raw(obj)))
    check_err(ei, TOPIC_MEASUREMENTS, 7, "kind")
    with pytest.raises(CodecError) as ei:
        to_frame(decode(TOPIC_MEASUREMENTS, b"\x00\x01garbage"))
    assert ei.value.frame is None and "/measurements" in str(ei.value)
    with pytest.raises(CodecError):
        to_frame(decode(TOPIC_MEASUREMENTS, b"[1, 2]"))


def test_too_many_measurements():
    z = [[0.0, 1.0]] * (MAX_MEASUREMENTS + 1)
    with pytest.raises(CodecError) as ei:
        to_frame(decode(TOPIC_MEASUREMENTS, raw(meas_obj(z=z))))
    check_err(ei, TOPIC_MEASUREMENTS, 7, "$.z")
    with pytest.raises(CodecError):
        encode(Frame(7, 0, "s", "bearing_range", np.array(z)))
    # the limit itself is fine
    assert to_frame(decode(TOPIC_MEASUREMENTS, raw(meas_obj(z=z[:-1])))).n_measurements == MAX_MEASUREMENTS


@pytest.mark.parametrize(
    "over, fragments",
    [
        ({"objects": [{"id": "a", "state": [1.0] * 4}]}, ["$.objects[0].state"]),
        ({"objects": [{"id": "a", "state": [1.0] * 5}, {"id": "a", "state": [2.0] * 5}]}, ["duplicate", "$.objects[1]"]),
        ({"objects": [{"id": 3, "state": [1.0] * 5}]}, ["$.objects[0].id"]),
        ({"objects": [{"id": "a", "state": [1.0] * 5, "x": 1}]}, ["unknown field"]),
        ({"v": 3}, ["unsupported schema version 3"]),
        ({"frame": -2}, ["$.frame"]),
    ],
)
def test_decode_truth_rejects(over, fragments):
    with pytest.raises(CodecError) as ei:
        decode(TOPIC_TRUTH, raw(truth_obj(**over)))
    frame = over.get("frame", 7)
    check_err(ei, TOPIC_TRUTH, frame, *fragments)


def test_encode_truth_rejects_nan():
    t = Truth(ids=("a", "b"), states=np.array([[0.0] * 5, [0.0, 1.0, np.nan, 0.0, 0.0]]))
    with pytest.raises(CodecError) as ei:
        encode(from_truth(9, 0, t))
    check_err(ei, TOPIC_TRUTH, 9, "non-finite", "$.objects[1].state[2]")


def _track(**over):
    t = {"label": "t1", "state": [1.0] * 5, "covariance": [0.0] * 25, "existence": 0.9}
    t.update(over)
    return t


@pytest.mark.parametrize(
    "over, fragments",
    [
        ({"tracks": [_track(covariance=[0.0] * 24)]}, ["$.tracks[0].covariance"]),
        ({"tracks": [_track(state=[0.0] * 6)]}, ["$.tracks[0].state"]),
        ({"tracks": [_track(existence=1.5)]}, ["$.tracks[0].existence"]),
        ({"tracks": [_track(existence=-0.1)]}, ["$.tracks[0].existence"]),
        ({"tracks": [_track(), _track()]}, ["duplicate", "t1"]),
        ({"assignment_prob": [0.5, 1.01]}, ["$.assignment_prob[1]"]),
        ({"assignment_prob": [0.5]}, ["len(assignments) = 2", "len(assignment_prob) = 1"]),
        ({"assignments": ["t1", 3]}, ["$.assignments[1]"]),
        ({"diagnostics": {"alpha": "x"}}, ["$.diagnostics"]),
        ({"v": 5}, ["unsupported schema version 5"]),
        ({"tracks": [_track(label=f"t{i}") for i in range(MAX_TRACKS + 1)]}, ["$.tracks"]),
    ],
)
def test_decode_tracks_rejects(over, fragments):
    with pytest.raises(CodecError) as ei:
        to_estimate(decode(TOPIC_TRACKS, raw(tracks_obj(**over))))
    check_err(ei, TOPIC_TRACKS, 7, *fragments)


def test_encode_tracks_rejects_bad_estimates():
    rng = np.random.default_rng(8)
    est = make_estimate(rng, k=12)
    bad_diag = Estimate(est.frame, est.stamp_ns, est.tracks, est.assignments, est.assignment_prob, {"loglik": -np.inf})
    with pytest.raises(CodecError) as ei:
        encode(bad_diag)
    check_err(ei, TOPIC_TRACKS, 12, "non-finite", "$.diagnostics.loglik")
    t0 = est.tracks[0]
    cov = t0.covariance.copy()
    cov[2, 3] = np.nan
    bad_cov = Estimate(12, 0, (TrackEstimate("x", t0.state, cov, 0.5),))
    with pytest.raises(CodecError) as ei:
        encode(bad_cov)
    check_err(ei, TOPIC_TRACKS, 12, "non-finite", "$.tracks[0].covariance[13]")
    mismatch = Estimate(12, 0, est.tracks, ("t0",), (0.5, 0.5))
    with pytest.raises(CodecError):
        encode(mismatch)
    short_state = Estimate(12, 0, (TrackEstimate("x", np.zeros(4), np.eye(5), 0.5),))
    with pytest.raises(CodecError) as ei:
        encode(short_state)
    check_err(ei, TOPIC_TRACKS, 12, "$.tracks[0].state")
    neg = Estimate(-1, 0, ())
    with pytest.raises(CodecError):
        encode(neg)


def test_codec_error_is_value_error_and_picklable():
    with pytest.raises(ValueError):
        to_frame(decode(TOPIC_MEASUREMENTS, raw(meas_obj(frame=-1))))
    e = CodecError("/measurements", 4, "boom")
    e2 = pickle.loads(pickle.dumps(e))
    assert (e2.topic, e2.frame, e2.message, str(e2)) == ("/measurements", 4, "boom", str(e))


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_codec_does_not_import_zenoh():
    import subprocess
    import sys

    code = "import sys, tracker.messages; assert 'zenoh' not in sys.modules, 'zenoh imported'"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=str(REPO_ROOT))


def test_decode_msg_dispatch():
    rng = np.random.default_rng(9)
    f = make_frame(rng)
    assert isinstance(decode(TOPIC_MEASUREMENTS, encode(f)), MeasurementsMsg)
    with pytest.raises(ValueError):
        decode("/other", b"{}")
    assert isinstance(msgspec.json.decode(encode(f)), dict)


def test_encode_tracks_fast_path_gives_the_reference_bytes():
    """encode(estimate) builds and checks the common estimate's message in plain Python
    (``_plain_tracks_msg``); its bytes are those of the reference path (from_estimate +
    validation + encode), and whatever it refuses takes the reference path, which raises the
    precise error."""
    from bnptrack.tracker.message_encode import _plain_tracks_msg, from_estimate

    rng = np.random.default_rng(11)
    cases = [make_estimate(rng, k=k) for k in range(20)]
    cases += [Estimate(frame=0, stamp_ns=0, tracks=()),
              Estimate(frame=np.int64(3), stamp_ns=np.int64(9), tracks=cases[0].tracks,
                       assignments=(None, "t0"), assignment_prob=(np.float64(0.0), 1.0),
                       diagnostics={"alpha": np.float32(1.5)})]
    for est in cases:
        msg = _plain_tracks_msg(est, "r")
        assert msg is None if isinstance(est.frame, np.integer) else msg == from_estimate(est, "r")
        assert encode(est, "r") == encode(from_estimate(est, "r"))
    t0 = cases[3].tracks[0]
    for bad, field in ((Estimate(1, 0, (t0, t0)), "$.tracks[1]"),  # duplicate label
                       (Estimate(1, 0, (TrackEstimate("x", t0.state, t0.covariance, 1.5),)), "$.tracks[0].existence"),
                       (Estimate(1, 0, (), ("a",), (np.nan,)), "$.assignment_prob[0]"),
                       (Estimate(1, 2**63, ()), "$.stamp_ns")):
        assert _plain_tracks_msg(bad, "r") is None
        with pytest.raises(CodecError) as ei:
            encode(bad, "r")
        check_err(ei, TOPIC_TRACKS, 1, field)


def test_track_cluster_schema_2_and_version_1_logs_still_read():
    # schema 2: a two-level tracker's track carries its motion cluster; None is omitted
    t = TrackEstimate("t1", np.ones(5), np.eye(5), 0.9, cluster=4)
    u = TrackEstimate("t2", np.ones(5), np.eye(5), 0.8)
    data = encode(Estimate(3, 0, (t, u)))
    obj = json.loads(data)
    assert obj["v"] == 2 and obj["tracks"][0]["cluster"] == 4 and "cluster" not in obj["tracks"][1]
    out = to_estimate(decode(TOPIC_TRACKS, data))
    assert [x.cluster for x in out.tracks] == [4, None]
    # a version-1 log (no cluster field) reads as before
    old = to_estimate(decode(TOPIC_TRACKS, raw({**tracks_obj(), "v": 1})))
    assert old.tracks[0].cluster is None and old.tracks[0].existence == 0.9
    with pytest.raises(CodecError, match=r"\$\.tracks\[0\]\.cluster"):
        to_estimate(decode(TOPIC_TRACKS, raw(tracks_obj(tracks=[_track(cluster=-1)]))))


def test_tracks_version_is_2_only_with_a_cluster():
    """/tracks is written as version 1 unless a track carries a motion cluster (version 2's only
    addition), so version-1 readers keep reading single-level runs; both decode."""
    track = TrackEstimate("1.0", np.arange(5.0), np.eye(5), 0.9)
    plain = Estimate(4, 4_000_000_000, (track,), (), ())
    grouped = Estimate(4, 4_000_000_000, (TrackEstimate("1.0", np.arange(5.0), np.eye(5), 0.9, cluster=3),), (), ())
    assert json.loads(encode(plain))["v"] == 1
    obj = json.loads(encode(grouped))
    assert obj["v"] == 2 and obj["tracks"][0]["cluster"] == 3
    assert to_estimate(decode(TOPIC_TRACKS, encode(grouped))).tracks[0].cluster == 3
    assert to_estimate(decode(TOPIC_TRACKS, encode(plain))).tracks[0].cluster is None


def test_messages_share_one_header_and_golden_bytes():
    """The three messages derive from one Header (v, run, frame, stamp_ns first on the wire);
    the bytes are those of the contract (docs/formats.md), written out by hand here."""
    from bnptrack.tracker.messages import Header

    for t in (MeasurementsMsg, TruthMsg, TracksMsg):
        assert issubclass(t, Header)
        assert [f.name for f in msgspec.structs.fields(t)][:4] == ["v", "run", "frame", "stamp_ns"]
    f = Frame(3, 3_000_000_000, "sim0", "range", [[452.5], [0.25]])
    assert encode(f, "r1") == (b'{"v":1,"run":"r1","frame":3,"stamp_ns":3000000000,"sensor":"sim0",'
                               b'"kind":"range","z":[[452.5],[0.25]]}')
    g = Frame(2, 10, "cam", "xy", [[-250.5, 1120.75]], pose=(-1000.0, 2500.0, 0.5), R=np.diag([4.0, 9.0]))
    assert encode(g) == (b'{"v":2,"run":"","frame":2,"stamp_ns":10,"sensor":"cam","kind":"xy",'
                         b'"z":[[-250.5,1120.75]],"pose":[-1000.0,2500.0,0.5],"R":[[4.0,0.0],[0.0,9.0]]}')
    t = Truth(("T1",), np.array([[1.0, 2.0, 3.0, 4.0, 0.5]]))
    assert encode(from_truth(1, 1000, t)) == (b'{"v":1,"run":"","frame":1,"stamp_ns":1000,'
                                              b'"objects":[{"id":"T1","state":[1.0,2.0,3.0,4.0,0.5]}]}')
    est = Estimate(12, 5, (TrackEstimate("1.4", np.arange(5.0), np.eye(5), 0.75, cluster=2),), ("1.4", None), (0.5, 1.0),
                   {"alpha": 1.5})
    cov = ",".join("1.0" if i % 6 == 0 else "0.0" for i in range(25)).encode()
    assert encode(est, "x") == (b'{"v":2,"run":"x","frame":12,"stamp_ns":5,"tracks":[{"label":"1.4",'
                                b'"state":[0.0,1.0,2.0,3.0,4.0],"covariance":[' + cov + b'],"existence":0.75,'
                                b'"cluster":2}],"assignments":["1.4",null],"assignment_prob":[0.5,1.0],'
                                b'"diagnostics":{"alpha":1.5}}')


def test_encode_takes_the_run_from_a_message_and_refuses_other_objects():
    msg = decode(TOPIC_MEASUREMENTS, raw(meas_obj(run="a")))
    assert json.loads(encode(msg))["run"] == "a"
    with pytest.raises(ValueError, match="carries its own run"):
        encode(msg, "b")
    with pytest.raises(TypeError, match="not a bnptrack message"):
        encode({"frame": 1})


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_messages_module_is_pure():
    """tracker.messages imports msgspec, numpy and tracker only: no mcap, zenoh, pipeline,
    sources or sinks."""
    import subprocess
    import sys

    code = ("import sys, tracker.messages; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
            "('mcap', 'zenoh', 'pipeline', 'sources', 'sinks', 'rerun')); assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=str(REPO_ROOT))
