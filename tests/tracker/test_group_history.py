"""The object partition's whole history as the likelihood of (alpha_2, d):
the Pitman-Yor EPPF on the grid (hand values, the urn's EPPF), the history's bookkeeping (hand
case) and the Pitman-Yor scene partition (generative checks against closed forms)."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sources.scene_families import pitman_yor_sizes
from bnptrack.sources.scenarios import get_scenario
from bnptrack.tracker.bnp.group_hyper import eppf_grid, size_factor, update_history
from bnptrack.tracker.bnp.groups import GroupConfig, GroupState, GroupTracker
from bnptrack.tracker.bnp.urn import ALPHA_GRID, D_GRID, grid_mean, log_eppf
from bnptrack.tracker.models.params import load_params


def _eppf(sizes, alpha, d) -> float:
    f = size_factor(np.array([d]), np.array(sizes))
    return float(eppf_grid(np.array([[alpha]]), np.array([[d]]), len(sizes), int(sum(sizes)), f)[0, 0])


def test_eppf_hand_value():
    # seats 1, then table 1 with (1 - d) / (alpha + 1), then new with (alpha + d) / (alpha + 2)
    assert _eppf([2, 1], 1.0, 0.5) == pytest.approx(np.log(1.0 * 0.5 / 2.0 * 1.5 / 3.0))
    assert _eppf([3], 2.0, 0.0) == pytest.approx(np.log(1.0 / 3.0 * 2.0 / 4.0))
    assert _eppf([1, 1], 2.0, 0.0) == pytest.approx(np.log(2.0 / 3.0))


@pytest.mark.parametrize("sizes", [[5, 3, 1, 1], [1], [2, 2, 2, 1, 1, 1, 1], [7]])
@pytest.mark.parametrize("alpha, d", [(0.7, 0.3), (2.0, 0.0), (0.05, 0.9), (1.0, 0.05)])
def test_eppf_grid_is_the_urns_eppf(sizes, alpha, d):
    assert _eppf(sizes, alpha, d) == pytest.approx(log_eppf(np.array(sizes), alpha, d), abs=1e-9)


def test_update_history_moves_counts_and_keeps_the_dead():
    totals = {5: 3, 6: 1}
    counted = update_history(np.array([5, 5, 6, -1]), np.array([0, 1, 3]), np.array([5, 7, 7]), totals)
    np.testing.assert_array_equal(counted, [5, 7, 6, 7])  # "c" (row 2) is no member: stays counted in 6
    assert totals == {5: 2, 6: 1, 7: 2}
    # counted in a cluster that has died (not in totals): counted again, the old count stays
    totals = {9: 1}
    assert update_history(np.array([4]), np.array([0]), np.array([9]), totals).tolist() == [9]
    assert totals == {9: 2}


def test_tracker_history_folds_clusters_that_stop_transitioning():
    tr = GroupTracker(load_params("vo2017"), GroupConfig(d=0.1, infer_d=True, hyper_likelihood="history"))
    state = GroupState(labels=("a", "b", "c"), counted=np.array([5, 5, 6]), group_ids=np.array([5, 6]),
                       hist_total=np.array([3, 1]), dead_k=1, dead_n=2, dead_factor=size_factor(D_GRID, [2]))
    # this frame: a -> 5, b -> 7, new object e -> 7; c is no member and cluster 6 does not transition
    counted, total, dead_k, dead_n, factor = tr.hyper.history(state, ("a", "b", "c", "e"), np.array([0, 1, 3]),
                                                              np.array([5, 7, 7]), np.array([5, 7]))
    np.testing.assert_array_equal(counted, [5, 7, 6, 7])
    np.testing.assert_array_equal(total, [2, 2])
    assert (dead_k, dead_n) == (2, 3)
    np.testing.assert_allclose(factor, size_factor(D_GRID, [2, 1]))
    ll = tr.hyper.history_loglik((counted, total, dead_k, dead_n, factor))
    i, j = 10, 6
    assert ll[i, j] == pytest.approx(log_eppf(np.array([2, 2, 2, 1]), ALPHA_GRID[i], D_GRID[j]))


def test_pitman_yor_sizes_mean_number_of_tables():
    # E K_n = (alpha/d) [(alpha+d)^(n) / alpha^(n) - 1] (Pitman 2006, eq. 3.24)
    rng = np.random.default_rng(3)
    n, alpha, d = 12, 1.0, 0.5
    K = np.array([len(pitman_yor_sizes(rng, n, alpha, d)) for _ in range(3000)])
    i = np.arange(n)
    expected = alpha / d * (np.prod((alpha + d + i) / (alpha + i)) - 1.0)
    assert abs(K.mean() - expected) < 3 * K.std() / np.sqrt(K.size)
    assert all(sum(pitman_yor_sizes(rng, n, alpha, d)) == n for _ in range(20))


def _posterior_d(sizes) -> float:
    f = size_factor(D_GRID, np.array(sizes))
    ll = eppf_grid(ALPHA_GRID[:, None], D_GRID[None, :], len(sizes), int(sum(sizes)), f) + np.log(ALPHA_GRID)[:, None]
    return grid_mean(ll, ALPHA_GRID, D_GRID)[1]


def test_the_eppf_identifies_the_discount():
    rng = np.random.default_rng(11)
    py = np.mean([_posterior_d(pitman_yor_sizes(rng, 1000, 1.0, 0.6)) for _ in range(5)])
    dp = np.mean([_posterior_d(pitman_yor_sizes(rng, 1000, 5.0, 0.0)) for _ in range(5)])
    assert 0.5 < py < 0.7 and dp < 0.2 and py - dp > 0.3


def test_groups_pl_is_a_pitman_yor_partition():
    sizes = []
    for seed in range(1, 11):
        sc = get_scenario("groups-pl", seed)
        grouped = sum(len(g) for g in sc.groups)
        assert len(sc.targets) == 25  # 24 partitioned objects (singletons included) + 1 free object
        sizes += [len(g) for g in sc.groups] + [1] * (24 - grouped)
        assert max(len(g) for g in sc.groups) <= 10
    # many singletons and a few big groups: about 0.7 of the clusters are singletons at d = 0.6
    ones = sizes.count(1) / len(sizes)
    assert 0.5 < ones < 0.85
