"""Membership on each object's own, sharing-free estimate
(``GroupConfig.membership = "own"``, :func:`tracker.bnp.group_share.own_update`)."""

from __future__ import annotations

import dataclasses

import msgspec
import numpy as np

from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.bnp.group_share import own_update
from bnptrack.tracker.bnp.groups import GroupConfig, GroupState, GroupTracker
from bnptrack.tracker.bnp import TRACKER_PRESETS
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.state import restore, run, snapshot

_H = np.zeros((2, 5))
_H[0, 0] = _H[1, 2] = 1.0  # a Cartesian position measurement of (p_x, v_x, p_y, v_y, omega)
_R = np.diag([25.0, 16.0])


def _kalman(m: np.ndarray, P: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    S = _H @ P @ _H.T + _R
    K = P @ _H.T @ np.linalg.inv(S)
    return m + K @ (z - _H @ m), P - K @ S @ K.T


def _spd(rng: np.random.Generator, scale: np.ndarray) -> np.ndarray:
    A = rng.normal(size=(5, 5)) * 0.3
    return np.diag(scale) + A @ A.T


def test_own_update_is_the_kalman_update_of_the_own_prediction_for_a_linear_measurement() -> None:
    rng = np.random.default_rng(3)
    scale = np.array([100.0, 40.0, 100.0, 40.0, 1e-3])
    m_s, P_s = rng.normal(size=5) * 10, _spd(rng, scale)  # the shared prediction
    m_o, P_o = rng.normal(size=5) * 10, _spd(rng, 2 * scale)  # the own one: other numbers
    z = np.array([3.0, -7.0])
    post = _kalman(m_s, P_s, z)
    want = _kalman(m_o, P_o, z)
    got = own_update((m_s[None], P_s[None]), (post[0][None], post[1][None]), (m_o[None], P_o[None]))
    np.testing.assert_allclose(got[0][0], want[0], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(got[1][0], want[1], rtol=1e-8, atol=1e-10)


def test_own_update_without_a_detection_is_the_own_prediction() -> None:
    rng = np.random.default_rng(4)
    scale = np.array([100.0, 40.0, 100.0, 40.0, 1e-3])
    m_s, P_s = rng.normal(size=(1, 5)), _spd(rng, scale)[None]
    m_o, P_o = rng.normal(size=(1, 5)), _spd(rng, scale)[None]
    got_m, got_P = own_update((m_s, P_s), (m_s, P_s), (m_o, P_o))  # the update added nothing
    np.testing.assert_allclose(got_m, m_o, atol=1e-9)
    np.testing.assert_allclose(got_P, P_o, rtol=1e-9)


def test_own_update_ignores_a_widening_of_the_shared_covariance() -> None:
    # a mixture with a missed-detection branch widened the velocity: no negative information
    m_s, P_s = np.zeros((1, 5)), np.diag([100.0, 40.0, 100.0, 40.0, 1e-3])[None]
    post_P = P_s.copy()
    post_P[0, 1, 1] = 60.0
    m_o, P_o = np.ones((1, 5)), np.diag([90.0, 30.0, 90.0, 30.0, 1e-3])[None]
    got_m, got_P = own_update((m_s, P_s), (m_s, post_P), (m_o, P_o))
    np.testing.assert_allclose(got_P, P_o, rtol=1e-9)
    np.testing.assert_allclose(got_m, m_o, atol=1e-9)


def _convoy_run(config: GroupConfig, k: int = 40):
    sc = get_scenario("groups", 101, scene=("n_objects=1", "group_sizes=[4,4]", "passing_pairs=0", "K=60"))
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, 101)[:k]
    tr = GroupTracker(params, config)
    return tr, frames, list(run(tr, frames, seed=7))


def test_own_estimates_stay_sharing_free_and_the_shared_states_differ_for_convoy_members() -> None:
    cfg = GroupConfig(objects=TRACKER_PRESETS["ddp-mb"], membership="own")
    _, _, out = _convoy_run(cfg)
    state = out[-1][2]
    assert state.own_mean.shape == state.mean.shape and state.own_cov.shape == state.cov.shape
    members = state.cluster >= 0
    apart = np.any(state.own_mean != state.mean, axis=1)
    assert apart[members].sum() >= 4  # convoy members took shares; their own estimates did not
    # with the sharing off the own estimate is the state, row for row
    _, _, off = _convoy_run(msgspec.structs.replace(cfg, sharing=False, turn_within_std_deg=0.0), k=25)
    s = off[-1][2]
    assert np.array_equal(s.own_mean, s.mean) and np.array_equal(s.own_cov, s.cov)


def test_own_membership_snapshot_resume_and_an_old_snapshot_loads() -> None:
    cfg = GroupConfig(objects=TRACKER_PRESETS["ddp-mb"], membership="own")
    tr, frames, out = _convoy_run(cfg, k=36)
    mid = out[29][2]
    back = restore(snapshot(mid), GroupState)
    assert np.array_equal(back.own_mean, mid.own_mean) and np.array_equal(back.own_cov, mid.own_cov)
    resumed = [e for _, e, _ in run(tr, frames[30:], seed=7, state=back)]
    for (_, e, _), r in zip(out[30:], resumed):
        assert [t.label for t in e.tracks] == [t.label for t in r.tracks]
        for a, b in zip(e.tracks, r.tracks):
            np.testing.assert_array_equal(a.state, b.state)
    # a snapshot without own estimates loads and runs on
    old = dataclasses.replace(mid, own_mean=np.zeros((0, 5)), own_cov=np.zeros((0, 5, 5)))
    doc = restore(snapshot(old), GroupState)
    later = list(run(tr, frames[30:], seed=7, state=doc))
    assert later[-1][2].own_mean.shape == later[-1][2].mean.shape
