"""The object -> cluster urn's two readings of eqs. (17)-(19) and H_2 from the object level's base
distribution (docs/trackers.md, "Deviations, stated")."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp.group_sample import urn_log_weights
from bnptrack.tracker.bnp.group_scan import _option_logw
from bnptrack.tracker.bnp.group_theta import fov_moments
from bnptrack.tracker.bnp.groups import GROUP_PRESETS, GroupTracker
from bnptrack.tracker.models.params import load_params


def test_occupied_reading_hand_values() -> None:
    # table 0 chosen this frame (n 2, v* 1), table 1 only transitioned (v* 3); alpha 0.5, d 0.2
    n, v_star = np.array([2.0, 0.0]), np.array([1.0, 3.0])
    w = np.exp(urn_log_weights(n, v_star, 0.5, 0.2, occupied=True))
    np.testing.assert_allclose(w, [2.8, 3.0, 0.7])  # P1 2+1-0.2; P2 v* undiscounted; P3 0.5 + 0.2 * 1
    np.testing.assert_allclose(w.sum(), n.sum() + v_star.sum() + 0.5)  # the urn's normaliser
    w_all = np.exp(urn_log_weights(n, v_star, 0.5, 0.2))
    np.testing.assert_allclose(w_all, [2.8, 2.8, 0.9])  # every cluster discounted, K = 2
    np.testing.assert_allclose(w_all.sum(), w.sum())


def test_readings_agree_without_discount() -> None:
    n, v_star = np.array([1.0, 0.0, 0.0]), np.array([0.0, 2.0, 0.0])
    np.testing.assert_allclose(urn_log_weights(n, v_star, 1.5, 0.0, occupied=True), urn_log_weights(n, v_star, 1.5, 0.0))


@pytest.mark.parametrize("occupied", [False, True])
def test_kernel_weights_equal_reference(occupied: bool) -> None:
    n = np.array([2.0, 0.0, 1.0, 0.0, 0.0])
    v_star = np.array([1.0, 3.0, 0.0, 0.0, 0.0])
    logw = np.empty(5)
    _option_logw(n, v_star, 0.7, 0.3, logw, occupied)
    ref = urn_log_weights(n[:3], v_star[:3], 0.7, 0.3, occupied)
    np.testing.assert_allclose(logw[:4], ref)
    assert logw[4] == -np.inf  # one "new" table only


def test_fov_moments_of_a_half_disc() -> None:
    # vo2017: bearing +-90 deg, range 2 km: a half disc of radius r = 2000 above the sensor
    r = 2000.0
    mean, cov = fov_moments(load_params("vo2017").detection())
    ybar = 4.0 * r / (3.0 * np.pi)
    np.testing.assert_allclose(mean, [0.0, ybar], atol=1.0)
    np.testing.assert_allclose(np.diag(cov), [r**2 / 4.0, r**2 / 4.0 - ybar**2], rtol=2e-3)
    assert abs(cov[0, 1]) < 1.0


def test_h2_birth_is_the_object_levels_base_distribution() -> None:
    import msgspec

    params = load_params("vo2017")
    cfg = msgspec.structs.replace(GROUP_PRESETS["ddp"], h2="birth")
    tr = GroupTracker(params, cfg)
    np.testing.assert_allclose(tr.h_cov, cfg.objects.birth_velocity_std**2 * np.eye(2))
    np.testing.assert_allclose(tr.h_pos[0], fov_moments(params.detection())[0])
    vague = GroupTracker(params, msgspec.structs.replace(GROUP_PRESETS["ddp"], h2="vague"))
    np.testing.assert_allclose(vague.h_cov, 30.0**2 * np.eye(2))
    np.testing.assert_allclose(vague.h_pos[1], 2000.0**2 * np.eye(2))
