"""The two-level DDP (tracker/groups.py), the ``groups`` scene families and the adjusted Rand index."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sinks.partitions import adjusted_rand_index
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.bnp import TRACKER_PRESETS, BnpTracker
from bnptrack.tracker.config import apply_overrides
from bnptrack.tracker.bnp.group_sample import Block, sample_partition, urn_log_weights
from bnptrack.tracker.bnp.group_share import share_velocity
from bnptrack.tracker.bnp.group_theta import theta_posterior
from bnptrack.tracker.bnp.groups import GroupState, GroupTracker
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.registry import build
from bnptrack.tracker.state import restore, run, snapshot

CONVOY = ("n_objects=1", "group_sizes=[4,4]", "passing_pairs=0", "K=60")


# -- conjugate theta, urn weights, Gibbs conditional ------------------------------------------
def test_theta_posterior_hand_computed():
    # prior N(0, 4 I); members (2, 0) and (4, 2), each with R = I:
    # Lambda = I/4 + 2 I = 2.25 I, eta = (6, 2), mean = eta / 2.25, cov = I / 2.25
    mean, cov = theta_posterior(np.zeros(2), 4.0 * np.eye(2), np.array([[2.0, 0.0], [4.0, 2.0]]),
                                np.stack([np.eye(2), np.eye(2)]))
    np.testing.assert_allclose(mean, [6 / 2.25, 2 / 2.25])
    np.testing.assert_allclose(cov, np.eye(2) / 2.25)


def test_theta_posterior_anisotropic_hand_computed():
    # prior N((1, 1), diag(1, 2)); one member (3, -1) with R = diag(1, 2):
    # per axis: x: (1*1 + 3*1) / 2 = 2, var 1/2; y: (1/2 - 1/2) / 1 = 0, var 1
    mean, cov = theta_posterior(np.ones(2), np.diag([1.0, 2.0]), np.array([[3.0, -1.0]]), np.diag([1.0, 2.0])[None])
    np.testing.assert_allclose(mean, [2.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(cov, np.diag([0.5, 1.0]))


def test_urn_weights_for_objects_hand_computed():
    # cluster 0: 2 objects this frame + v* = 1 -> 3 (case D1); cluster 1: transitioned, not yet
    # chosen, v* = 3 -> 3 (case D2); new: alpha = 0.5 (case D3)
    np.testing.assert_allclose(np.exp(urn_log_weights(np.array([2.0, 0.0]), np.array([1.0, 3.0]), 0.5, 0.0)),
                               [3.0, 3.0, 0.5])
    # Pitman-Yor, d = 0.2: n + v* - d, new alpha + d K with K = 2 occupied tables
    np.testing.assert_allclose(np.exp(urn_log_weights(np.array([2.0, 0.0]), np.array([1.0, 3.0]), 0.5, 0.2)),
                               [2.8, 2.8, 0.9])
    # an empty table (n = v* = 0) has weight 0 and is not counted in K
    np.testing.assert_allclose(np.exp(urn_log_weights(np.array([1.0, 0.0]), np.array([0.0, 0.0]), 1.0, 0.5)),
                               [0.5, 0.0, 1.5])


def _flat_block(L: int, G: int) -> Block:
    """Every table (transitioned or new) with the same prior: the likelihood cannot favour any."""
    return Block(np.zeros((L, 2)), np.stack([np.eye(2)] * L), np.zeros((G, 2)), np.stack([np.eye(2)] * G),
                 np.zeros(2), np.eye(2))


def test_gibbs_conditional_is_the_urn_when_likelihoods_tie():
    # one object, two transitioned clusters with v* = 2 and 3, alpha = 0.5: (2, 3, 0.5) / 5.5
    _, shares = sample_partition(np.random.default_rng(0), [_flat_block(1, 2)], np.array([2.0, 3.0]), 0.5, 0.0,
                                 np.array([-1]), sweeps=1)
    np.testing.assert_allclose(np.sort(shares.w), np.sort(np.array([2.0, 3.0, 0.5]) / 5.5))


def test_gibbs_groups_by_velocity():
    # two tight velocity groups far apart in velocity: the last sample separates them exactly
    v = np.array([[10.0, 0.0], [10.2, 0.1], [9.9, -0.1], [-10.0, 5.0], [-10.1, 5.2]])
    b = Block(v, np.stack([0.1 * np.eye(2)] * 5), np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(2),
              900.0 * np.eye(2))
    z, _ = sample_partition(np.random.default_rng(3), [b], np.zeros(0), 0.5, 0.0, -np.ones(5, dtype=np.int64), 10)
    assert adjusted_rand_index(z.tolist(), [0, 0, 0, 1, 1]) == 1.0


def test_share_velocity_single_option_is_a_kalman_update():
    # state velocity N((4, 0), 4 I), no position-velocity correlation; option theta N((0, 0), I)
    # with S_w = I: pseudo-measurement covariance 2 I, gain 4 / 6 -> velocity (4/3, 0), var 4/3
    from bnptrack.tracker.bnp.group_sample import Shares

    mean = np.array([[0.0, 4.0, 0.0, 0.0, 0.0]])
    cov = np.diag([1.0, 4.0, 1.0, 4.0, 0.01])[None]
    sh = Shares(np.array([0]), np.array([1.0]), np.zeros((1, 2)), np.eye(2)[None])
    m, P = share_velocity(mean, cov, sh, np.eye(2))
    np.testing.assert_allclose(m[0], [0.0, 4 / 3, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(np.diag(P[0]), [1.0, 4 / 3, 1.0, 4 / 3, 0.01])


# -- the tracker ------------------------------------------------------------------------------
def _convoy(seed: int = 101):
    sc = get_scenario("groups", seed, scene=CONVOY)
    params = sc.adapt_params(load_params("vo2017"))
    return sc, params, simulate_all(sc, params, seed)


def test_registry_names():
    params = load_params("vo2017")
    mb = build("ddp-mb", params)
    assert isinstance(mb, BnpTracker) and mb.name == "ddp-mb" and mb.config == TRACKER_PRESETS["ddp-mb"]
    assert build("dpyp-mb", params).config == TRACKER_PRESETS["dpyp-mb"]
    g = build("ddp", params)
    assert isinstance(g, GroupTracker) and g.config.d == 0.0 and not g.config.infer_d
    assert build("dpyp", params).config.infer_d


def test_snapshot_round_trip_and_determinism():
    _, params, frames = _convoy()
    tr = build("ddp", params)
    states, ests = [], []
    for _, e, s in run(tr, frames[:40], seed=7):
        states.append(s)
        ests.append(e)
    mid = states[29]
    back = restore(snapshot(mid), GroupState)
    for name in GroupState.__dataclass_fields__:
        a, b = getattr(mid, name), getattr(back, name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, name
    resumed = [e for _, e, _ in run(tr, frames[30:40], seed=7, state=back)]
    again = [e for _, e, _ in run(tr, frames[:40], seed=7)]
    for x, y, z in zip(ests[30:], resumed, again[30:]):
        assert x.labels == y.labels == z.labels
        assert [t.cluster for t in x.tracks] == [t.cluster for t in y.tracks] == [t.cluster for t in z.tracks]
        for a, b in zip(x.tracks, y.tracks):
            np.testing.assert_array_equal(a.state, b.state)


def _velocity_error(params, frames, config) -> float:
    tr = GroupTracker(params, config)
    err = []
    for f, e, _ in run(tr, frames, seed=5):
        for t in e.tracks:
            d = np.linalg.norm(f.truth.positions - t.position, axis=1)
            if d.size and d.min() < 50.0:
                err.append(np.linalg.norm(f.truth.states[d.argmin(), [1, 3]] - t.state[[1, 3]]))
    return float(np.mean(err))


@pytest.mark.slow  # four runs of the convoy; the fast subset keeps the cluster and own-estimate checks
def test_sharing_reduces_velocity_error_on_a_clean_convoy():
    sc, params, frames = _convoy()
    params = apply_overrides(params, ["clutter_rate=2.0"])
    frames = simulate_all(sc, params, 101)
    # the inflated share (share_inflation_std, the default) and the un-inflated one both help
    # sharing at every scan (share_after = 0); the default shares from a convoy's thirteenth scan
    default = build("ddp", params).config
    cfg = apply_overrides(default, ["share_after=0"])
    alone = _velocity_error(params, frames, apply_overrides(cfg, ["sharing=false"]))
    shared = _velocity_error(params, frames, cfg)
    tight = _velocity_error(params, frames, apply_overrides(cfg, ["within_std=3.0", "share_inflation_std=0"]))
    later = _velocity_error(params, frames, default)
    print(f"velocity error: alone {alone:.2f}, shared {shared:.2f}, tight {tight:.2f}, default {later:.2f} m/s")
    assert max(tight, shared) < 0.9 * alone, (tight, shared, alone)
    assert shared < later < 0.95 * alone, (shared, later, alone)


def test_tracks_carry_their_cluster_and_convoys_group():
    sc, params, frames = _convoy()
    group_of = {i: k for k, g in enumerate(sc.groups) for i in g}
    tr = build("ddp", params)
    est = [e for _, e, _ in run(tr, frames, seed=3)]
    last = est[-1]
    member = tr.config.member_existence
    assert last.tracks and all((t.cluster is not None) == (t.existence >= member) for t in last.tracks)
    assert sum(t.cluster is not None for t in last.tracks) >= 6
    f = frames[-1]
    pairs = []
    for t in last.tracks:
        d = np.linalg.norm(f.truth.positions - t.position, axis=1)
        if d.min() < 50.0 and t.cluster is not None:
            pairs.append((group_of.get(f.truth.ids[d.argmin()], -1), t.cluster))
    assert len(pairs) >= 6
    assert adjusted_rand_index([p[0] for p in pairs], [p[1] for p in pairs]) > 0.5


# -- scenes and metric ------------------------------------------------------------------------
def test_groups_scene_members_share_velocity_and_turn():
    sc = get_scenario("groups", 4)
    assert len(sc.groups) == 5 and all(2 <= len(g) <= 5 for g in sc.groups)
    st = sc.states()
    idx = {t: i for i, t in enumerate(sc.ids)}
    for g in sc.groups:
        cols = [idx[i] for i in g]
        for k in range(sc.K):
            present = [c for c in cols if np.isfinite(st[k, c, 0])]
            if len(present) > 1:
                np.testing.assert_allclose(st[k, present][:, [1, 3, 4]], np.repeat(st[k, present[:1]][:, [1, 3, 4]],
                                                                                    len(present), axis=0), atol=1e-9)
    grouped = {i for g in sc.groups for i in g}
    assert 3 <= len(set(sc.ids) - grouped) <= 6  # independent objects


def test_group_sizes_setting_and_power_law_family():
    sc = get_scenario("groups", 1, scene=("group_sizes=[3,3,2]",))
    assert sorted(len(g) for g in sc.groups) == [2, 3, 3]
    sizes = [len(g) for s in range(1, 31) for g in get_scenario("groups-pl", s).groups]
    counts = np.bincount(sizes, minlength=11)
    assert counts[2] > counts[5] > 0 and counts[2] > 2 * counts[8]


@pytest.mark.parametrize("a, b, expected", [
    ([0, 0, 1, 1], [5, 5, 7, 7], 1.0),
    ([0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 2, 2], 0.8 / 3.3),  # index 2, E = 6 * 3 / 15, max 4.5
    ([0, 0, 1, 2], [0, 1, 2, 3], 0.0),  # all-singleton guess: no agreeing pair
    ([0, 1, 2], [0, 1, 2], 1.0),
    (["a", "a", "b", "b"], ["x", "y", "x", "y"], -0.5),  # index 0, E = 4 / 6, max 2
])
def test_adjusted_rand_index_hand_values(a, b, expected):
    assert adjusted_rand_index(a, b) == pytest.approx(expected)
