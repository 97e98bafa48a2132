"""Non-finite measurements at the API edge: refused with a message naming the
frame and the row; NaN distances are outside the gate; the moment-matched update touches only
the pairs that carry weight, so no 0 * NaN reaches a track state.

The codec / MCAP / pipeline-stage path refuses NaN and inf earlier (as a rejected sample):
tests/tracker/test_codec.py, tests/sources/test_mcap_log.py and tests/pipeline/test_pipeline_stages.py cover it."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker import filtering as kf
from bnptrack.tracker.bnp import make_tracker
from bnptrack.tracker.bnp.filter import _moment_match
from bnptrack.tracker.state import tracker_frame_rng, run
from bnptrack.tracker.types import Frame


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_frame_rejects_non_finite_row_naming_frame_and_row(bad):
    z = [[0.1, 100.0], [0.2, 300.0], [bad, 5.0]]
    with pytest.raises(ValueError, match=r"^Frame 7: measurement row 2 is not finite"):
        Frame(7, 0, "radar", "bearing_range", z)
    with pytest.raises(ValueError, match=r"^Frame 3: measurement row 0 is not finite"):
        Frame(3, 0, "radar", "range", [[bad], [10.0]])


def test_frame_message_is_one_line_and_counts_rows():
    with pytest.raises(ValueError) as exc:
        Frame(4, 0, "radar", "bearing_range", [[np.nan, 1.0], [0.0, 2.0], [0.0, np.inf]])
    msg = str(exc.value)
    assert "\n" not in msg and "row 0" in msg and "(2 such row(s))" in msg


def test_step_rejects_a_frame_edited_in_place(vo_params, vo_frames):
    """Frame.z is a plain array: a NaN written after construction is caught by step itself."""
    tr = make_tracker("ddp-mb", vo_params)
    *_, (_, _, state) = run(tr, vo_frames[:5], 1)
    f = vo_frames[5]
    bad = Frame(f.frame, f.stamp_ns, f.sensor, f.kind, f.z.copy())
    bad.z[1, 0] = np.nan
    with pytest.raises(ValueError, match=rf"^Frame {f.frame}: measurement row 1 is not finite"):
        tr.step(state, bad, tracker_frame_rng(1, f.frame))


def _innovation(vo_params):
    meas = vo_params.measurement()
    m = np.array([[0.0, 5.0, 800.0, 0.0, 0.0], [300.0, 0.0, 900.0, -5.0, 0.0]])
    P = np.tile(np.diag([400.0, 25.0, 400.0, 25.0, 1e-4]), (2, 1, 1))
    return meas, m, P, kf.ukf_innovation(meas, m, P)


@pytest.mark.parametrize("gate", [0.9999, None])
def test_nan_distance_is_outside_the_gate(vo_params, gate):
    meas, _, _, innov = _innovation(vo_params)
    Z = np.vstack([innov.z_pred[0], [np.nan, 800.0], [0.0, np.inf], innov.z_pred[1]])
    ll = kf.log_likelihood_matrix(meas, innov, Z, gate)
    assert np.all(ll[:, 1:3] == -np.inf)
    ref = kf.log_likelihood_matrix(meas, innov, Z[[0, 3]], gate)
    np.testing.assert_array_equal(ll[:, [0, 3]], ref)
    assert np.isfinite(ll[0, 0]) and np.isfinite(ll[1, 3])


def test_moment_match_skips_pairs_without_weight(vo_params):
    """A NaN measurement no cluster takes leaves every state exactly as without it."""
    from bnptrack.tracker.bnp.filter import _Prediction

    meas, m, P, innov = _innovation(vo_params)
    pred = _Prediction(m, P, np.array([0.9, 0.8]), np.array([0.98, 0.98]))
    Z = np.vstack([innov.z_pred[0] + [0.01, 5.0], [np.nan, 700.0], innov.z_pred[1] - [0.01, 3.0]])
    p_lm = np.array([[0.7, 0.0, 0.1], [0.0, 0.0, 0.6]])
    w_miss = np.array([0.05, 0.1])
    r = p_lm.sum(axis=1) + w_miss
    def pairs(p):  # every (cluster, measurement) pair, zero weights included (the update skips them)
        ti, mi = np.nonzero(np.ones_like(p))
        return ti, mi, p[ti, mi]

    mean, cov = _moment_match(meas, innov, pred, Z, w_miss, *pairs(p_lm), r)
    ref_mean, ref_cov = _moment_match(meas, innov, pred, Z[[0, 2]], w_miss, *pairs(p_lm[:, [0, 2]]), r)
    assert np.isfinite(mean).all() and np.isfinite(cov).all()
    np.testing.assert_array_equal(mean, ref_mean)
    np.testing.assert_array_equal(cov, ref_cov)
    # hand check of cluster 1 (one measurement, weight 0.6/0.7, missed 0.1/0.7)
    upd = kf.update_pairs(meas, innov, m, Z, np.array([1]), np.array([2]))[0]
    expect = (0.1 * m[1] + 0.6 * upd) / 0.7
    np.testing.assert_allclose(mean[1], expect, rtol=1e-12)
