"""Parts of the two-level tracker: the exclusive merge, the
arrivals' Pitman-Yor likelihood of (alpha_2, d) and the shared turn rate (hand-computed values)."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp.clusters import _Clusters, merge_duplicates
from bnptrack.tracker.bnp.group_hyper import arrivals_loglik_grid
from bnptrack.tracker.bnp.group_merge import merge_exclusive, taken_measurements
from bnptrack.tracker.bnp.group_sample import Block, sample_partition
from bnptrack.tracker.bnp.group_share import share_turn, share_velocity


def _clusters(labels, existence, dx=5.0) -> _Clusters:
    n = len(labels)
    mean = np.zeros((n, 5))
    mean[:, 0] = dx * np.arange(n)  # 5 m apart, covariance 100 I: well within merge distance 9
    return _Clusters(tuple(labels), mean, np.stack([100.0 * np.eye(5)] * n), np.array(existence), np.ones(n))


def test_two_newborns_of_one_scan_are_never_merged():
    c = _clusters(["5.0", "5.1"], [0.4, 0.3])
    assert len(merge_duplicates(c, 9.0).labels) == 1  # the object level folds them into one
    merged, renamed = merge_exclusive(c, 9.0, {})
    assert merged.labels == ("5.0", "5.1") and renamed == {}


def test_a_newborn_merges_into_an_older_cluster_unless_they_took_different_measurements():
    c = _clusters(["3.2", "5.0", "5.1"], [0.5, 0.4, 0.3])
    merged, renamed = merge_exclusive(c, 9.0, {})
    # leader 3.2 (0.5) absorbs 5.0 (0.4; sum 0.9); 5.1 would exceed 1 and stays
    assert merged.labels == ("3.2", "5.1") and renamed == {"5.0": "3.2"}
    np.testing.assert_allclose(merged.existence, [0.9, 0.3])
    np.testing.assert_allclose(merged.mean[0, 0], (0.5 * 0.0 + 0.4 * 5.0) / 0.9)
    # scan 5: 5.0 and 5.1 were born from measurements 0 and 1; 3.2 took measurement 2
    taken = taken_measurements([None, None, "3.2"], [0.8, 0.7, 0.9], 0.5, c.labels, 5)
    assert taken == {"3.2": 2, "5.0": 0, "5.1": 1}
    merged, renamed = merge_exclusive(c, 9.0, taken)  # three measurements, three objects
    assert merged.labels == ("3.2", "5.0", "5.1") and renamed == {}
    assert taken_measurements([None, None, "3.2"], [0.8, 0.7, 0.4], 0.5) == {}  # below min_prob


def test_a_fading_older_hypothesis_does_not_rename_a_reported_track():
    # 2.0 (existence 0.05: a track fading after its object was lost) lies on 7.3 (0.9, reported):
    # leader 7.3 absorbs it (sum 0.95)
    c = _clusters(["7.3", "2.0"], [0.9, 0.05])
    merged, renamed = merge_exclusive(c, 9.0, {})
    assert merged.labels == ("2.0",) and renamed == {"7.3": "2.0"}  # the oldest label
    merged, renamed = merge_exclusive(c, 9.0, {}, reported=0.35)
    assert merged.labels == ("7.3",) and renamed == {"2.0": "7.3"}  # the reported one's
    np.testing.assert_allclose(merged.existence, [0.95])
    np.testing.assert_allclose(merged.mean[0, 0], (0.9 * 0.0 + 0.05 * 5.0) / 0.95)
    # every member below the threshold, or a newborn duplicate of a reported track: the oldest
    merged, renamed = merge_exclusive(_clusters(["7.3", "2.0"], [0.3, 0.05]), 9.0, {}, reported=0.35)
    assert merged.labels == ("2.0",) and renamed == {"7.3": "2.0"}
    merged, renamed = merge_exclusive(_clusters(["9.1", "4.0"], [0.5, 0.4]), 9.0, {}, reported=0.35)
    assert merged.labels == ("4.0",) and renamed == {"9.1": "4.0"}


@pytest.mark.parametrize("alpha, d", [(0.7, 0.3), (2.0, 0.0), (0.1, 0.9)])
def test_arrivals_likelihood_is_the_pitman_yor_eppf(alpha, d):
    # five objects arrive: tables sizes 2 and 3; EPPF = (a + d) / ((a+1)(a+2)(a+3)(a+4)) (1-d) (1-d)(2-d)
    z = np.array([0, 0, 1, 1, 1])
    got = arrivals_loglik_grid(np.array([alpha]), np.array([d]), z, np.ones(5, dtype=bool))
    eppf = (alpha + d) / ((alpha + 1) * (alpha + 2) * (alpha + 3) * (alpha + 4)) * (1 - d) * (1 - d) * (2 - d)
    np.testing.assert_allclose(got, [np.log(eppf)])


def test_arrivals_are_seated_after_the_members_already_there():
    # object 0 already at table 0; 1 joins it: (1 - d) / (a + 1); 2 opens a table: (a + d K) / (a + 2), K = 1
    a, d = np.array([[0.5], [3.0]]), np.array([[0.0, 0.4]])
    got = arrivals_loglik_grid(a, d, np.array([0, 0, 7]), np.array([False, True, True]))
    want = np.log((1 - d) / (a + 1)) + np.log((a + d) / (a + 2))
    np.testing.assert_allclose(got, want)
    # nobody new: no information about (alpha, d)
    np.testing.assert_array_equal(arrivals_loglik_grid(a, d, np.array([0, 0, 1]), np.zeros(3, dtype=bool)), 0.0)


def test_share_turn_hand_computed():
    # members 0 and 1 in one cluster (turn 0.01 and 0.03 rad/s, variance 1e-4 each), 2 alone:
    # 0 takes y = 0.03 with r = 1e-4 (+ within 0): gain 1/2 -> 0.02, variance 5e-5; 1 likewise; 2 unchanged
    mean = np.zeros((3, 5))
    mean[:, 4] = [0.01, 0.03, 0.05]
    cov = np.stack([np.diag([1.0, 1.0, 1.0, 1.0, 1e-4])] * 3)
    m, P = share_turn(mean, cov, mean[:, 4], cov[:, 4, 4], np.array([0, 0, 1]), 0.0)
    np.testing.assert_allclose(m[:, 4], [0.02, 0.02, 0.05])
    np.testing.assert_allclose(P[:, 4, 4], [5e-5, 5e-5, 1e-4])
    np.testing.assert_array_equal(m[:, :4], 0.0)
    np.testing.assert_array_equal(P[:, :4, :4], cov[:, :4, :4])


@pytest.mark.parametrize("flat, want_vx", [(True, 20.0), (False, 20.0 - 20.0 * 64.0 / (64.0 + 100.0 + 900.0))])
def test_a_member_alone_shares_nothing_under_the_flat_prior(flat, want_vx):
    # one object, velocity (20, 0), P_v = 64 I, S_w = 100 I, H_2 = N(0, 900 I): its only option is a
    # new cluster.  Flat prior (kappa_0 = 0): no other member, no pseudo-measurement.  H_2 prior: the
    # pseudo-measurement y = 0 with covariance 900 + 100 pulls vx by the gain 64 / (64 + 100 + 900).
    b = Block(np.array([[20.0, 0.0]]), (64.0 + 100.0) * np.eye(2)[None], np.zeros((0, 2)), np.zeros((0, 2, 2)),
              np.zeros(2), 900.0 * np.eye(2))
    _, shares = sample_partition(np.random.default_rng(0), [b], np.zeros(0), 1.0, 0.0, np.array([-1]), 1,
                                 flat_share=flat)
    mean = np.array([[0.0, 20.0, 0.0, 0.0, 0.0]])
    cov = np.diag([100.0, 64.0, 100.0, 64.0, 1e-4])[None]
    m, _ = share_velocity(mean, cov, shares, 100.0 * np.eye(2))
    np.testing.assert_allclose(m[0, 1], want_vx, atol=1e-6)


def test_the_tracker_passes_the_reporting_threshold_to_the_merge_only_with_merge_label_reported(monkeypatch):
    import msgspec

    from bnptrack.sources.scenarios import get_scenario
    from bnptrack.sources.synthetic import simulate_all
    from bnptrack.tracker.bnp import groups
    from bnptrack.tracker.models.params import load_params
    from bnptrack.tracker.state import run

    seen = []

    def spy(c, max_d2, taken, arrays=None, reported=None):
        seen.append(reported)
        return merge_exclusive(c, max_d2, taken, arrays, reported)

    monkeypatch.setattr(groups, "merge_exclusive", spy)
    sc = get_scenario("groups", 101, scene=("n_objects=2", "group_sizes=[3,3]", "passing_pairs=1", "K=40"))
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, 101)[:3]
    base = groups.GROUP_PRESETS["ddp"]
    for label, expected in (("oldest", None), ("reported", base.objects.existence_threshold)):
        seen.clear()
        list(run(groups.GroupTracker(params, msgspec.structs.replace(base, merge_label=label)), frames, seed=5))
        assert seen and all(r == expected for r in seen)
