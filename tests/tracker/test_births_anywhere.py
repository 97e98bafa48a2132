"""Accuracy of births anywhere: the point-object weights without the urn normaliser
(``BnpConfig.urn_normaliser``) and the OSPA decomposition of ``benchmarks/births.py``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from benchmarks.births import PARTS, ospa_parts
from bnptrack.sinks.metrics import ospa
from tests.tracker.test_urn_gibbs import enumerate_posterior, toy_problem
from bnptrack.tracker.bnp.gibbs import CLUTTER, NEW, log_joint, run_gibbs
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, Truth


def _toy(urn: bool):
    prob = toy_problem([0.30, 0.34, 0.62, 0.9], prior_first=[3.0, 0.8], mu=[0.31, 0.6], sigma=0.05, alpha=0.6,
                       d=0.0, lam_c=2.0)
    return dataclasses.replace(prob, urn_normaliser=urn)


def test_log_joint_without_the_urn_normaliser_hand_value():
    """c = (cluster 0, new, clutter, cluster 1): without g the joint is the product of the
    measurements' own factors (Poisson birth, Bernoulli objects, Poisson clutter); with g it
    also carries (alpha+V)/(alpha+V) * (alpha+V)/(alpha+V+1) * (alpha+V)/(alpha+V+2)."""
    z = [0.30, 0.34, 0.62, 0.9]
    c = np.array([0, NEW, CLUTTER, 1])
    ll0 = -0.5 * math.log(2 * math.pi * 0.05**2) - 0.5 * ((0.30 - 0.31) / 0.05) ** 2
    ll1 = -0.5 * math.log(2 * math.pi * 0.05**2) - 0.5 * ((0.9 - 0.6) / 0.05) ** 2
    own = math.log(3.0) + ll0 + math.log(0.6) + 0.0 + math.log(2.0) + math.log(0.8) + ll1
    assert z[0] == 0.30
    assert log_joint(_toy(False), c) == pytest.approx(own, rel=1e-12)
    s = 0.6 + 1.7  # alpha + V
    urn = math.log(s / (s + 1)) + math.log(s / (s + 2))
    assert log_joint(_toy(True), c) == pytest.approx(own + urn, rel=1e-12)


def test_gibbs_without_the_urn_normaliser_matches_exact_enumeration():
    prob = _toy(False)
    configs, p = enumerate_posterior(prob)
    N, M = prob.shape
    exact_new = np.zeros(M)
    exact_cluster = np.zeros((N, M))
    for c, pc in zip(configs, p):
        for m, ch in enumerate(c):
            if ch == NEW:
                exact_new[m] += pc
            elif ch >= 0:
                exact_cluster[ch, m] += pc
    res = run_gibbs(prob, np.random.default_rng(5), sweeps=20000, burn_in=100, chains=2)
    np.testing.assert_allclose(res.p_new, exact_new, atol=0.015)
    np.testing.assert_allclose(res.p_cluster, exact_cluster, atol=0.015)
    # and it differs from the paper's weights where g matters (the new-cluster option)
    with_g = run_gibbs(_toy(True), np.random.default_rng(5), sweeps=20000, burn_in=100, chains=2)
    assert res.p_new[3] > with_g.p_new[3] + 0.05


def _frame(k, ids, pos):
    pos = np.asarray(pos, float).reshape(-1, 2)
    x = np.zeros((len(ids), 5))
    x[:, 0], x[:, 2] = pos[:, 0], pos[:, 1]
    return Frame(frame=k, stamp_ns=k * 10**9, sensor="self", kind="bearing_range", z=np.zeros((0, 2)),
                 truth=Truth(tuple(ids), x))


def _est(k, labels, pos):
    tracks = []
    for lab, (px, py) in zip(labels, pos):
        tracks.append(TrackEstimate(lab, np.array([px, 0.0, py, 0.0, 0.0]), np.eye(5), 0.9))
    return Estimate(k, k * 10**9, tuple(tracks), (), ())


def test_ospa_parts_add_up_to_ospa_and_name_the_error():
    """Scan 10: A (born at 2) tracked 30 m off, B (born at 9, so new) missed, C (born at 1)
    tracked 10 m off.  Scan 11: A has died; its track "a" lingers (false dead) and a
    clutter track "x" appears (false other); only C is left, tracked 10 m off."""
    births = {"A": 2, "B": 9, "C": 1}
    owner: dict = {}
    f10 = _frame(10, ["A", "B", "C"], [[0, 0], [1000, 1000], [-1000, 0]])
    e10 = _est(10, ["a", "c"], [[30, 0], [-1010, 0]])
    p = ospa_parts(f10, e10, births, owner, 100.0)
    assert set(p) == set(PARTS)
    assert p["loc"] == pytest.approx(40 / 3) and p["far"] == 0.0
    assert p["missed new"] == pytest.approx(100 / 3) and p["missed old"] == 0.0
    assert sum(p.values()) == pytest.approx(ospa(f10.truth.positions, e10.positions, c=100.0, p=1.0).total)
    assert owner == {"a": "A", "c": "C"}
    f11 = _frame(11, ["C"], [[-1000, 0]])
    e11 = _est(11, ["a", "x", "c"], [[30, 0], [500, 500], [-1010, 0]])
    p = ospa_parts(f11, e11, births, owner, 100.0)
    assert p["loc"] == pytest.approx(10 / 3)
    assert p["false dead"] == pytest.approx(100 / 3) and p["false other"] == pytest.approx(100 / 3)
    assert sum(p.values()) == pytest.approx(ospa(f11.truth.positions, e11.positions, c=100.0, p=1.0).total)


def test_ospa_parts_far_pair():
    """One object, one track 150 m away: the pair is assigned at the cut-off (far = c)."""
    f = _frame(5, ["A"], [[0, 0]])
    p = ospa_parts(f, _est(5, ["a"], [[150, 0]]), {"A": 1}, {}, 100.0)
    assert p == {**dict.fromkeys(PARTS, 0.0), "far": 100.0}
