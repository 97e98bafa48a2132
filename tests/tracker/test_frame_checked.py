"""``Frame.checked`` (the frame path's latency): the codec's frames are
built without checking ``z`` a second time, and are the frames the public constructor builds
from the same data; the public constructor and the codec still check what they checked."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bnptrack.tracker.messages import TOPIC_MEASUREMENTS, CodecError, decode, encode, to_frame
from bnptrack.tracker.types import Frame


def _validated(msg) -> Frame:
    """The frame the public constructor builds from a decoded message (the path before)."""
    return Frame(frame=msg.frame, stamp_ns=msg.stamp_ns, sensor=msg.sensor, kind=msg.kind,
                 z=np.array(msg.z, dtype=float) if msg.z else np.zeros((0, 0)),
                 pose=None if msg.pose is None else tuple(msg.pose),
                 R=None if msg.R is None else np.array(msg.R, dtype=float))


def _same(a: Frame, b: Frame) -> None:
    assert (a.frame, a.stamp_ns, a.sensor, a.kind, a.truth, a.pose) == (b.frame, b.stamp_ns, b.sensor, b.kind,
                                                                        b.truth, b.pose)
    assert a.z.dtype == b.z.dtype == np.float64 and a.z.shape == b.z.shape
    assert a.z.tobytes() == b.z.tobytes()
    assert (a.R is None) == (b.R is None)
    if a.R is not None:
        assert a.R.tobytes() == b.R.tobytes()


def _raw(**over) -> bytes:
    obj = {"v": 2, "run": "r", "frame": 9, "stamp_ns": 450_000_000, "sensor": "radar0", "kind": "bearing_range",
           "z": [[0.25, 120.5], [-1.5, 3000.0], [3.0, 0.5]]}
    obj.update(over)
    return json.dumps(obj).encode()


@pytest.mark.parametrize("kind,d", [("bearing_range", 2), ("range", 1), ("xy", 2)])
@pytest.mark.parametrize("m", [0, 1, 25])
def test_codec_frame_equals_validated_frame(kind, d, m):
    rng = np.random.default_rng(10 * m + d)
    z = rng.uniform(0.1, 0.9, (m, d))
    msg = decode(TOPIC_MEASUREMENTS, encode(Frame(4, 200_000_000, "s", kind, z), "r"))
    got = to_frame(msg)
    want = _validated(msg) if m else Frame(4, 200_000_000, "s", kind, np.zeros((0, d)))
    _same(got, want)
    assert got.z.tobytes() == z.tobytes() and got.n_measurements == m
    assert got.z.flags.c_contiguous


def test_codec_frame_reference_values():
    f = to_frame(decode(TOPIC_MEASUREMENTS, _raw()))
    assert (f.frame, f.stamp_ns, f.sensor, f.kind, f.truth, f.pose, f.R) == (9, 450_000_000, "radar0",
                                                                            "bearing_range", None, None, None)
    assert f.z.tolist() == [[0.25, 120.5], [-1.5, 3000.0], [3.0, 0.5]]
    assert f.z.shape == (3, 2) and f.z.dtype == np.float64


def test_codec_frame_pose_and_r_normalised_as_by_the_constructor():
    r = [[2.0, 0.5], [0.5 + 1e-13, 1.0]]  # symmetric within the tolerance: stored symmetrised
    msg = decode(TOPIC_MEASUREMENTS, _raw(pose=[1, 2.5, -0.5], R=r))
    got = to_frame(msg)
    _same(got, _validated(msg))
    assert got.pose == (1.0, 2.5, -0.5) and all(type(v) is float for v in got.pose)
    assert got.R.tolist() == [[2.0, 0.5 + 0.5e-13], [0.5 + 0.5e-13, 1.0]]


def test_checked_still_checks_pose_and_r():
    z = np.array([[0.1, 10.0]])
    with pytest.raises(ValueError, match="pose must be 3 finite numbers"):
        Frame.checked(1, 0, "s", "bearing_range", z, pose=(0.0, math.nan, 0.0))
    with pytest.raises(ValueError, match="symmetric positive definite"):
        Frame.checked(1, 0, "s", "bearing_range", z, R=np.array([[1.0, 0.0], [0.0, -1.0]]))


def test_the_public_constructor_still_checks_z():
    with pytest.raises(ValueError, match="measurement row 1 is not finite"):
        Frame(3, 0, "s", "bearing_range", np.array([[0.1, 10.0], [math.inf, 5.0]]))
    with pytest.raises(ValueError, match="unknown sensor kind"):
        Frame(3, 0, "s", "sonar", np.zeros((0, 2)))
    f = Frame(3, 0, "s", "range", [1.0, 2.0])  # lists, reshaped by the kind's width
    assert f.z.tolist() == [[1.0], [2.0]]


@pytest.mark.parametrize("over", [{"z": [[0.1, 1e999]]}, {"z": [[0.1]]}, {"z": [[0.1, 10.0, 3.0]]},
                                  {"z": [[0.1, -5.0]]}, {"kind": "sonar"}])
def test_the_codec_refuses_what_checked_would_take(over):
    """What ``Frame.checked`` does not check again, ``decode`` refuses before ``to_frame``."""
    with pytest.raises(CodecError):
        decode(TOPIC_MEASUREMENTS, _raw(**over))
