"""Posterior draws of the object partition for scoring (tracker/bnp/group_posterior.py): the
tracker's own output is untouched, the draws have their shape and agree with a clean scene's
groups, the posterior of d is a distribution on the grid."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sinks.partitions import adjusted_rand_index, binder_point, similarity_matrix
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.bnp.group_posterior import PosteriorGroupTracker, grid_interval
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.registry import build
from bnptrack.tracker.state import run

CONVOY = ("n_objects=1", "group_sizes=[4,4]", "passing_pairs=0", "K=30")


@pytest.fixture(scope="module")
def convoy():
    sc = get_scenario("groups", seed=3, scene=CONVOY)
    params = sc.adapt_params(load_params("vo2017"))
    return sc, params, simulate_all(sc, params, 3)


@pytest.mark.parametrize("name", ["ddp", "dpyp"])
def test_the_tracker_output_is_the_plain_trackers(convoy, name):
    _, params, frames = convoy
    plain = build(name, params)
    post = PosteriorGroupTracker(plain.params, plain.config, plain.name, burn=3, keep=4, first_frame=5, every=4)
    for (_, a, sa), (_, b, sb) in zip(run(plain, frames, seed=7), run(post, frames, seed=7)):
        assert a.labels == b.labels and [t.cluster for t in a.tracks] == [t.cluster for t in b.tracks]
        for x, y in zip(a.tracks, b.tracks):
            np.testing.assert_array_equal(x.state, y.state)
        assert sa.d2 == sb.d2 and sa.alpha2 == sb.alpha2
    assert len(post.log) == len(frames)
    summarised = [r.frame for r in post.log if r.draws is not None]
    assert summarised and all(f >= 5 and (f - 5) % 4 == 0 for f in summarised)


def test_draws_shape_and_the_summary_finds_the_convoys(convoy):
    sc, params, frames = convoy
    base = build("dpyp", params)
    post = PosteriorGroupTracker(base.params, base.config, base.name, chains=3, burn=5, keep=6, first_frame=25)
    last = list(run(post, frames, seed=7))[-1][1]
    rec = post.log[-1]
    assert rec.draws.shape == (3, 6, len(rec.labels)) and len(rec.labels) >= 6
    draws = rec.draws.reshape(-1, len(rec.labels))
    point = binder_point(similarity_matrix(draws), draws)
    # each member's true group: that of the true object nearest its track at the last frame
    f = frames[-1]
    group_of = {i: k for k, g in enumerate(sc.groups) for i in g}
    pos = {t.label: t.position for t in last.tracks}
    true = [group_of.get(f.truth.ids[np.linalg.norm(f.truth.positions - pos[lab], axis=1).argmin()], lab)
            for lab in rec.labels]
    assert adjusted_rand_index(true, point.tolist()) > 0.5


def test_d_posterior_is_a_distribution_and_ddp_sits_at_zero(convoy):
    _, params, frames = convoy
    for name, fixed in (("ddp", True), ("dpyp", False)):
        base = build(name, params)
        post = PosteriorGroupTracker(base.params, base.config, base.name, first_frame=10**6)
        list(run(post, frames, seed=7))
        rec = post.log[-1]
        assert rec.d_prob.sum() == pytest.approx(1.0) and np.all(rec.d_prob >= 0)
        if fixed:
            assert rec.d_grid.tolist() == [0.0] and grid_interval(rec.d_grid, rec.d_prob) == (0.0, 0.0, 0.0)
        else:
            assert rec.d_grid.size == 20


def test_grid_interval_hand_value():
    grid = np.array([0.0, 0.1, 0.2, 0.3])
    prob = np.array([0.01, 0.5, 0.47, 0.02])
    # cdf 0.01, 0.51, 0.98, 1.0: 2.5 % reached at 0.1, 97.5 % at 0.2; mean 0.05 + 0.094 + 0.006
    assert grid_interval(grid, prob) == pytest.approx((0.15, 0.1, 0.2))


def test_bad_settings_are_refused(convoy):
    _, params, _ = convoy
    base = build("ddp", params)
    with pytest.raises(ValueError, match="keep >= 1"):
        PosteriorGroupTracker(base.params, base.config, base.name, keep=0)
