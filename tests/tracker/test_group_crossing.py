"""``share_min_info``, the velocity sharing only to informed members, by hand values."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.bnp.group_share import informed, restrict
from bnptrack.tracker.bnp.group_sample import Shares
from bnptrack.tracker.bnp.group_share import share_velocity
from bnptrack.tracker.bnp.groups import GroupConfig, GroupTracker
from bnptrack.tracker.models.params import load_params


def _cov(vx: float, vy: float, cxy: float = 0.0) -> np.ndarray:
    P = np.eye(5)
    P[1, 1], P[3, 3], P[1, 3], P[3, 1] = vx, vy, cxy, cxy
    return P


def test_informed_uses_the_largest_velocity_variance() -> None:
    # eigenvalues of [[100, 0], [0, 50]] -> 100; of [[60, 40], [40, 60]] -> 100 and 20; [[10, 0], [0, 10]] -> 10
    cov = np.stack([_cov(100.0, 50.0), _cov(60.0, 60.0, 40.0), _cov(10.0, 10.0)])
    assert informed(cov, 400.0, 4.0).tolist() == [True, True, True]  # 100 <= 400 / 4
    assert informed(cov, 400.0, 5.0).tolist() == [False, False, True]  # 100 > 80
    assert informed(cov, 400.0, 0.0).tolist() == [True, True, True]  # off


def test_restrict_renumbers_the_kept_objects() -> None:
    rows, obj = restrict(np.array([0, 0, 1, 2, 2, 3]), np.array([True, False, True, True]))
    assert rows.tolist() == [0, 1, 3, 4, 5]
    assert obj.tolist() == [0, 0, 1, 1, 2]


def test_share_skips_an_uninformed_member_and_equals_share_velocity_for_the_rest() -> None:
    tracker = GroupTracker(load_params("vo2017"), GroupConfig(share_min_info=4.0))  # threshold 400 / 4 = 100
    mean = np.array([[0.0, 10.0, 0.0, 0.0, 0.0], [5.0, -10.0, 0.0, 0.0, 0.0], [9.0, 0.0, 1.0, 2.0, 0.0]])
    cov = np.stack([_cov(36.0, 36.0), _cov(300.0, 300.0), _cov(49.0, 49.0)])
    shares = Shares(np.array([0, 1, 1, 2]), np.array([1.0, 0.5, 0.5, 1.0]),
                    np.array([[-10.0, 0.0], [10.0, 0.0], [0.0, 0.0], [1.0, 1.0]]), np.stack([9.0 * np.eye(2)] * 4))
    new_mean, new_cov = tracker._share(mean, cov, shares)
    assert np.array_equal(new_mean[1], mean[1]) and np.array_equal(new_cov[1], cov[1])  # std 17.3 > 10
    sub = Shares(np.array([0, 1]), np.array([1.0, 1.0]), shares.mu[[0, 3]], shares.cov[[0, 3]])
    ref_mean, ref_cov = share_velocity(mean[[0, 2]], cov[[0, 2]], sub, tracker.S_share)
    assert np.array_equal(new_mean[[0, 2]], ref_mean) and np.array_equal(new_cov[[0, 2]], ref_cov)
    # object 0: gain 36 / (36 + S_share 9 + 9.5^2 + Cov(theta^-l) 9) on a residual of -20 m/s
    assert np.isclose(new_mean[0, 1], 10.0 - 20.0 * 36.0 / 144.25)
