"""The codec's plain-Python checks (session 11, issue 16: the frame path's latency): the
common message is checked without numpy, and those checks are never looser than the full
ones (tracker._message_checks): what they accept the full check accepts, with the same bytes;
what they refuse goes to the full check, which names the error."""

from __future__ import annotations

import hashlib

import msgspec
import numpy as np
import pytest

from bnptrack.tracker._message_checks import check_measurements, check_tracks, check_truth
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
    _checked_tracks_msg,
    _plain_measurements,
    _plain_tracks,
    _plain_tracks_msg,
    _plain_truth,
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


def test_plain_encode_gives_the_checked_bytes_and_golden_digest():
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
        assert _plain_tracks_msg(est, "r") == _checked_tracks_msg(est, "r")
        assert encode(est, "r") == msgspec.json.encode(from_estimate(est, "r"))
    for est in cases:
        msg = _plain_tracks_msg(est, "r")
        assert msg is not None and msg == _checked_tracks_msg(est, "r")
        data = encode(est, "r")
        assert data == msgspec.json.encode(from_estimate(est, "r"))
        digest.update(data)
    # the bytes of these 31 estimates as the base tree (fdd6353, before the plain path) wrote them
    assert digest.hexdigest()[:16] == "28d87f71011e9cf0"


def test_plain_encode_refuses_what_is_not_the_common_estimate():
    rng = np.random.default_rng(6)
    good = _estimate(rng, 3)
    t0 = good.tracks[0]
    pmf = np.array([0.5, 0.5 + 0.9e-6])  # within the tolerance, but nearer the limit than half of it
    for est in (Estimate(np.int64(3), 9, good.tracks),  # numpy integers: the checked path takes them
                Estimate(1, 0, (t0, t0)),  # duplicate label
                Estimate(1, 0, (TrackEstimate("x", t0.state, t0.covariance, 1.5),)),
                Estimate(1, 0, (TrackEstimate("x", np.r_[t0.state[:4], np.inf], t0.covariance, 0.5),)),
                Estimate(1, 0, (), ("a",), (np.nan,)),
                Estimate(1, 0, (), (), (), {"a": np.nan}),
                Estimate(1, 2**63, ()),
                Estimate(1, 0, (), (), (), {}, pmf)):
        assert _plain_tracks_msg(est, "r") is None
    # the near-limit pmf is valid: the checked path writes it
    assert _checked_tracks_msg(Estimate(1, 0, (), (), (), {}, pmf), "r") is not None
    with pytest.raises(CodecError, match="existence"):
        encode(Estimate(1, 0, (TrackEstimate("x", t0.state, t0.covariance, 1.5),)), "r")


def _meas(**over) -> MeasurementsMsg:
    fields = dict(v=1, run="r", frame=7, stamp_ns=1000, sensor="s", kind="bearing_range",
                  z=[[0.1, 10.0], [-0.2, 20.0]])
    fields.update(over)
    return MeasurementsMsg(**fields)


def test_plain_measurements_check_accepts_the_common_message_and_is_never_looser():
    assert _plain_measurements(_meas()) and _plain_measurements(_meas(z=[]))
    assert _plain_measurements(_meas(kind="range", z=[[5.0]]))
    bad = [_meas(v=3), _meas(frame=-1), _meas(stamp_ns=2**63), _meas(kind="nope"), _meas(z=[[0.1]]),
           _meas(z=[[0.1, float("nan")]]), _meas(z=[[4.0, 1.0]]), _meas(z=[[0.1, -1.0]]),
           _meas(z=[[0.1, float("inf")]]), _meas(run=None)]
    for msg in bad:
        assert not _plain_measurements(msg)
        with pytest.raises(CodecError):
            check_measurements(msg)
    # pose and R: valid, but left to the full check
    with_pose = _meas(pose=[0.0, 0.0, 0.0])
    assert not _plain_measurements(with_pose) and check_measurements(with_pose).shape == (2, 2)


def _tracks(**over) -> TracksMsg:
    fields = dict(v=3, run="r", frame=7, stamp_ns=1000,
                  tracks=[TrackMsg(label="a", state=[1.0] * 5, covariance=[0.0] * 25, existence=0.9)],
                  assignments=["a", None], assignment_prob=[0.8, 0.1], diagnostics={"x": 1.0},
                  cardinality_pmf=[0.25, 0.75])
    fields.update(over)
    return TracksMsg(**fields)


def test_plain_tracks_and_truth_checks_are_never_looser():
    track = TrackMsg(label="a", state=[1.0] * 5, covariance=[0.0] * 25, existence=0.9)
    assert _plain_tracks(_tracks()) and _plain_tracks(_tracks(v=1, cardinality_pmf=msgspec.UNSET))
    bad = [_tracks(v=2), _tracks(tracks=[track, track]), _tracks(assignment_prob=[0.8]),
           _tracks(assignment_prob=[0.8, 1.5]), _tracks(diagnostics={"x": float("nan")}),
           _tracks(cardinality_pmf=[0.5, 0.6]), _tracks(cardinality_pmf=[-0.5, 1.5]),
           _tracks(tracks=[TrackMsg(label="a", state=[float("nan")] * 5, covariance=[0.0] * 25, existence=0.9)]),
           _tracks(tracks=[TrackMsg(label="a", state=[1.0] * 5, covariance=[0.0] * 25, existence=1.1)])]
    for msg in bad:
        assert not _plain_tracks(msg)
        with pytest.raises(CodecError):
            check_tracks(msg)
    truth = TruthMsg(v=1, run="r", frame=1, stamp_ns=0, objects=[TruthObject(id="a", state=[1.0] * 5)])
    assert _plain_truth(truth)
    for msg in (TruthMsg(v=2, run="r", frame=1, stamp_ns=0, objects=[]),
                TruthMsg(v=1, run="r", frame=1, stamp_ns=0, objects=[TruthObject(id="a", state=[1.0] * 5)] * 2),
                TruthMsg(v=1, run="r", frame=1, stamp_ns=0, objects=[TruthObject(id="a", state=[float("inf")] * 5)])):
        assert not _plain_truth(msg)
        with pytest.raises(CodecError):
            check_truth(msg)


def test_decode_of_the_common_messages_round_trips_and_still_names_errors():
    rng = np.random.default_rng(8)
    est = _estimate(rng, 4)
    data = encode(est, "r")
    msg = decode(TOPIC_TRACKS, data)
    assert _plain_tracks(msg) and msgspec.json.encode(msg) == data
    assert decode(TOPIC_TRUTH, b'{"frame":1,"stamp_ns":0,"objects":[{"id":"a","state":[1,2,3,4,5]}]}').objects[0].state[4] == 5.0
    with pytest.raises(CodecError, match=r"range must be >= 0, got -1.0 - at `\$\.z\[1\]\[1\]`"):
        decode(TOPIC_MEASUREMENTS, b'{"frame":1,"stamp_ns":0,"sensor":"s","kind":"bearing_range","z":[[0,1],[0,-1]]}')
    with pytest.raises(CodecError, match="cardinality_pmf needs schema version 3"):
        decode(TOPIC_TRACKS, b'{"v":2,"frame":1,"stamp_ns":0,"tracks":[],"assignments":[],"assignment_prob":[],'
                             b'"cardinality_pmf":[1.0]}')
