"""The codec's plain-Python checks (the frame path's latency; one set of rules,
tracker._message_checks): the common message is checked without numpy
(each rule's quick test), anything else by the rule's exhaustive check, which names the error
or passes what the quick test was too cautious for; encode(estimate) builds the common
estimate's message checked by the same quick tests, to the bytes of from_estimate, and leaves
anything else to from_estimate and the checks."""

from __future__ import annotations

import hashlib

import msgspec
import numpy as np
import pytest

from bnptrack.tracker._message_checks import check_measurements, check_tracks, check_truth, pmf_list_ok
from bnptrack.tracker.message_encode import _plain_tracks_msg
from bnptrack.tracker.messages import (
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    CodecError,
    MeasurementsMsg,
    TrackMsg,
    TracksMsg,
    TruthMsg,
    TruthObject,
    decode,
    encode,
    from_estimate,
)
from bnptrack.tracker.types import Estimate, TrackEstimate


def _estimate(rng: np.random.Generator, k: int, n: int = 4, m: int = 7, pmf: bool = True, cluster: bool = True) -> Estimate:
    tracks = []
    for i in range(n):
        a = rng.normal(size=(5, 5))
        tracks.append(TrackEstimate(f"{k}.{i}", rng.normal(0, 100, 5), a @ a.T, float(rng.uniform()),
                                    cluster=i % 2 if cluster else None))
    labels = [t.label for t in tracks] + [None]
    p = rng.uniform(size=6)
    return Estimate(k, 10**9 * k, tuple(tracks), tuple(labels[int(j)] for j in rng.integers(0, n + 1, m)),
                    tuple(float(x) for x in rng.uniform(0, 1, m)),
                    {"alpha": 1.25, "n_clusters": 3.0, "log_joint": -123.456, "ms": 2.5},
                    p / p.sum() if pmf else None)


def test_plain_encode_gives_the_reference_bytes_and_golden_digest():
    rng = np.random.default_rng(5)
    cases = [_estimate(rng, k, n=k % 5, pmf=k % 3 > 0, cluster=k % 2 == 0) for k in range(30)]
    cases.append(Estimate(0, 0, ()))
    digest = hashlib.sha256()
    # states and covariances that are not float64 arrays take numpy's stacking, to the same bytes
    t0 = cases[3].tracks[0]
    odd = (TrackEstimate("f32", t0.state.astype(np.float32), t0.covariance.astype(np.float32), 0.5),
           TrackEstimate("list", list(t0.state), t0.covariance.tolist(), 0.5),
           TrackEstimate("view", t0.state, t0.covariance.T, 0.5))
    for est in (Estimate(1, 0, odd), Estimate(1, 0, odd[2:], (), (), {}, [0.25, 0.75])):
        assert _plain_tracks_msg(est, "r") == from_estimate(est, "r")
        assert encode(est, "r") == msgspec.json.encode(from_estimate(est, "r"))
    for est in cases:
        msg = _plain_tracks_msg(est, "r")
        assert msg is not None and msg == from_estimate(est, "r")
        data = encode(est, "r")
        assert data == msgspec.json.encode(from_estimate(est, "r"))
        digest.update(data)
    # the golden digest of these 31 estimates' bytes, as msgspec encodes from_estimate's messages
    assert digest.hexdigest()[:16] == "28d87f71011e9cf0"


def test_encode_names_the_error_of_any_estimate_by_the_one_check():
    rng = np.random.default_rng(6)
    good = _estimate(rng, 3)
    t0 = good.tracks[0]
    # numpy integers and ragged rows are not the common estimate: from_estimate builds those
    wide = TrackEstimate("w", np.r_[t0.state, 0.0], t0.covariance, 0.5)
    assert _plain_tracks_msg(Estimate(np.int64(3), 9, good.tracks), "r") is None
    assert _plain_tracks_msg(Estimate(1, 0, (wide,)), "r") is None
    assert encode(Estimate(np.int64(3), 9, good.tracks), "r") == encode(Estimate(3, 9, good.tracks), "r")
    bad = [(Estimate(1, 0, (t0, t0)), rf"duplicate track label '{t0.label}' - at `\$\.tracks\[1\]`"),
           (Estimate(1, 0, (TrackEstimate("x", t0.state, t0.covariance, 1.5),)),
            r"existence must be in \[0, 1\], got 1\.5 - at `\$\.tracks\[0\]\.existence`"),
           (Estimate(1, 0, (TrackEstimate("x", np.r_[t0.state[:4], np.inf], t0.covariance, 0.5),)),
            r"non-finite value inf - at `\$\.tracks\[0\]\.state\[4\]`"),
           (Estimate(1, 0, (wide,)), r"state of length 6, expected 5 - at `\$\.tracks\[0\]\.state`"),
           (Estimate(1, 0, (), ("a",), (np.nan,)), r"probability must be in \[0, 1\], got nan"),
           (Estimate(1, 0, (), (), (), {"a": np.nan}), r"non-finite value nan - at `\$\.diagnostics\.a`"),
           (Estimate(1, 2**63, ()), r"stamp_ns must be an integer in \[0, 2\*\*63\)"),
           (Estimate(1, 0, (), (), (), {}, [0.5, 0.6]), r"it has a sum of 1\.1"),
           (Estimate(1, 0, (), (), (), {}, [0.5, 0.5 + 2e-6]), r"it has a sum of 1\.0000019")]
    for est, text in bad:
        assert _plain_tracks_msg(est, "r") is None  # the reference path names it
        with pytest.raises(CodecError, match=text):
            encode(est, "r")
    # within the tolerance but nearer the limit than the quick test's half of it: the
    # reference path's rule (numpy's sum) passes it
    pmf = np.array([0.5, 0.5 + 0.9e-6])
    est = Estimate(1, 0, (), (), (), {}, pmf)
    assert not pmf_list_ok(pmf.tolist()) and _plain_tracks_msg(est, "r") is None
    assert encode(est, "r") == msgspec.json.encode(from_estimate(est, "r"))


def _meas(**over) -> MeasurementsMsg:
    fields = dict(v=1, run="r", frame=7, stamp_ns=1000, sensor="s", kind="bearing_range",
                  z=[[0.1, 10.0], [-0.2, 20.0]])
    fields.update(over)
    return MeasurementsMsg(**fields)


def test_measurements_check_accepts_the_common_message_and_names_errors():
    for msg in (_meas(), _meas(z=[]), _meas(kind="range", z=[[5.0]]), _meas(pose=[0.0, 0.0, 0.0]),
                _meas(R=[[0.01, 0.0], [0.0, 4.0]])):
        check_measurements(msg)
    # a sum of large finite values overflows: the quick test fails, the exhaustive check passes
    check_measurements(_meas(z=[[0.1, 1e308], [0.2, 1e308]]))
    bad = [(_meas(v=3), "unsupported schema version 3"), (_meas(frame=-1), "frame must be an integer >= 0"),
           (_meas(stamp_ns=2**63), "stamp_ns must be an integer"), (_meas(kind="nope"), "unknown kind 'nope'"),
           (_meas(z=[[0.1]]), r"z row \(kind 'bearing_range'\) of length 1, expected 2 - at `\$\.z\[0\]`"),
           (_meas(z=[[0.1, float("nan")]]), r"non-finite value nan - at `\$\.z\[0\]\[1\]`"),
           (_meas(z=[[4.0, 1.0]]), r"bearing must be within \[-pi, pi\], got 4\.0 - at `\$\.z\[0\]\[0\]`"),
           (_meas(z=[[0.1, -1.0]]), r"range must be >= 0, got -1\.0 - at `\$\.z\[0\]\[1\]`"),
           (_meas(z=[[0.1, float("inf")]]), r"non-finite value inf - at `\$\.z\[0\]\[1\]`"),
           (_meas(run=None), "run must be a string"), (_meas(sensor=3), "sensor must be a string")]
    for msg, text in bad:
        with pytest.raises(CodecError, match=text):
            check_measurements(msg)


def _tracks(**over) -> TracksMsg:
    fields = dict(v=3, run="r", frame=7, stamp_ns=1000,
                  tracks=[TrackMsg(label="a", state=[1.0] * 5, covariance=[0.0] * 25, existence=0.9)],
                  assignments=["a", None], assignment_prob=[0.8, 0.1], diagnostics={"x": 1.0},
                  cardinality_pmf=[0.25, 0.75])
    fields.update(over)
    return TracksMsg(**fields)


def test_tracks_and_truth_checks_accept_the_common_message_and_name_errors():
    track = TrackMsg(label="a", state=[1.0] * 5, covariance=[0.0] * 25, existence=0.9)
    check_tracks(_tracks())
    check_tracks(_tracks(v=1, cardinality_pmf=msgspec.UNSET))
    bad = [(_tracks(v=5), "unsupported schema version 5"),
           (_tracks(tracks=[track, track]), r"duplicate track label 'a' - at `\$\.tracks\[1\]`"),
           (_tracks(assignment_prob=[0.8]), r"len\(assignments\) = 2 != len\(assignment_prob\) = 1"),
           (_tracks(assignment_prob=[0.8, 1.5]), r"probability must be in \[0, 1\], got 1\.5 - at `\$\.assignment_prob\[1\]`"),
           (_tracks(assignments=["a", 3]), r"assignment must be a label or null - at `\$\.assignments\[1\]`"),
           (_tracks(diagnostics={"x": float("nan")}), r"non-finite value nan - at `\$\.diagnostics\.x`"),
           (_tracks(cardinality_pmf=[0.5, 0.6]), r"it has a sum of 1\.1"),
           (_tracks(cardinality_pmf=[-0.5, 1.5]), "it has a negative entry -0.5"),
           (_tracks(v=2, cardinality_pmf=[1.0]), "cardinality_pmf needs schema version 3"),
           (_tracks(tracks=[TrackMsg(label="a", state=[float("nan")] * 5, covariance=[0.0] * 25, existence=0.9)]),
            r"non-finite value nan - at `\$\.tracks\[0\]\.state\[0\]`"),
           (_tracks(tracks=[TrackMsg(label="a", state=[1.0] * 5, covariance=[0.0] * 24, existence=0.9)]),
            r"covariance of length 24, expected 25 - at `\$\.tracks\[0\]\.covariance`"),
           (_tracks(tracks=[TrackMsg(label="a", state=[1.0] * 5, covariance=[0.0] * 25, existence=1.1)]),
            r"existence must be in \[0, 1\], got 1\.1 - at `\$\.tracks\[0\]\.existence`")]
    for msg, text in bad:
        with pytest.raises(CodecError, match=text):
            check_tracks(msg)
    check_truth(TruthMsg(v=1, run="r", frame=1, stamp_ns=0, objects=[TruthObject(id="a", state=[1.0] * 5)]))
    for msg, text in ((TruthMsg(v=2, run="r", frame=1, stamp_ns=0, objects=[]), "unsupported schema version 2"),
                      (TruthMsg(v=1, run="r", frame=1, stamp_ns=0, objects=[TruthObject(id="a", state=[1.0] * 5)] * 2),
                       r"duplicate object id 'a' - at `\$\.objects\[1\]`"),
                      (TruthMsg(v=1, run="r", frame=1, stamp_ns=0, objects=[TruthObject(id=5, state=[1.0] * 5)]),
                       r"id must be a string - at `\$\.objects\[0\]\.id`"),
                      (TruthMsg(v=1, run="r", frame=1, stamp_ns=0, objects=[TruthObject(id="a", state=[float("inf")] * 5)]),
                       r"non-finite value inf - at `\$\.objects\[0\]\.state\[0\]`")):
        with pytest.raises(CodecError, match=text):
            check_truth(msg)


def test_decode_of_the_common_messages_round_trips_and_still_names_errors():
    rng = np.random.default_rng(8)
    est = _estimate(rng, 4)
    data = encode(est, "r")
    msg = decode(TOPIC_TRACKS, data)
    assert msgspec.json.encode(msg) == data
    assert decode(TOPIC_TRUTH, b'{"frame":1,"stamp_ns":0,"objects":[{"id":"a","state":[1,2,3,4,5]}]}').objects[0].state[4] == 5.0
    with pytest.raises(CodecError, match=r"range must be >= 0, got -1.0 - at `\$\.z\[1\]\[1\]`"):
        decode(TOPIC_MEASUREMENTS, b'{"frame":1,"stamp_ns":0,"sensor":"s","kind":"bearing_range","z":[[0,1],[0,-1]]}')
    with pytest.raises(CodecError, match="cardinality_pmf needs schema version 3"):
        decode(TOPIC_TRACKS, b'{"v":2,"frame":1,"stamp_ns":0,"tracks":[],"assignments":[],"assignment_prob":[],'
                             b'"cardinality_pmf":[1.0]}')
