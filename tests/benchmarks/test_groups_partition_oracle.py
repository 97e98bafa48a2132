"""benchmarks/groups_partition_oracle.py: the object -> cluster sampler on true states."""

from __future__ import annotations

import numpy as np
import pytest

import benchmarks.groups_partition_oracle as go
from benchmarks.groups import frame_ari
from bnptrack.tracker.bnp.group_sample import Block, sample_partition
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.state import run
from bnptrack.tracker.types import Frame, Truth

#: statistical oracles over many simulated runs: the slow tier (docs/testing.md)
pytestmark = pytest.mark.slow


def _block(v: np.ndarray, r: float, h: float, G: int = 0) -> Block:
    L = v.shape[0]
    return Block(v, np.repeat((r * r * np.eye(2))[None], L, axis=0), np.zeros((G, 2)),
                 np.repeat((h * h * np.eye(2))[None], G, axis=0), np.zeros(2), h * h * np.eye(2))


def test_conditional_of_two_objects_matches_the_hand_computation():
    """Object 0 alone at a new table, object 1 at v = 0 like it; H_2 = N(0, s^2 I), R = r^2 I.
    Joining: urn weight 1 - d ("occupied": n = 1, v* = 0) times N(0; 0, (c + r^2) I) with
    c = s^2 r^2 / (s^2 + r^2); new: alpha + d * 1 times N(0; 0, (s^2 + r^2) I)."""
    s, r, alpha, d = 20.0, 3.0, 0.5, 0.3
    b = _block(np.zeros((2, 2)), r, s)
    p = go.conditional([b], np.zeros(0), alpha, d, np.array([0, 1]), 1, occupied=True)
    c = s * s * r * r / (s * s + r * r)
    join, new = (1 - d) / (c + r * r), (alpha + d) / (s * s + r * r)
    assert p == pytest.approx([join / (join + new), new / (join + new)], rel=1e-12)
    p0 = go.conditional([b], np.zeros(0), alpha, 0.0, np.array([0, 1]), 1, occupied=True)
    assert p0[0] == pytest.approx(1 / (c + r * r) / (1 / (c + r * r) + alpha / (s * s + r * r)), rel=1e-12)


def test_conditional_equals_the_kernels_last_move():
    """The last object's conditional in the kernel's last sweep is given the others' final tables:
    the options above 1e-4 (Shares, renormalised) are the same numbers as :func:`go.conditional`."""
    rng = np.random.default_rng(3)
    v = np.array([[10.0, 0.0], [11.0, 1.0], [-5.0, 3.0], [-4.0, 2.0], [10.5, -0.5]])
    blocks = [_block(v, 3.0, 20.0, G=2)]
    blocks[0] = Block(v, blocks[0].R, np.array([[10.0, 0.0], [-5.0, 2.0]]), blocks[0].prior_cov,
                      np.zeros(2), 400.0 * np.eye(2))
    v_star = np.array([2.0, 1.0])
    z, shares = sample_partition(rng, blocks, v_star, 0.7, 0.4, np.array([0, 0, 1, -1, -1]), 3,
                                 flat_share=True, occupied=True)
    p = go.conditional(blocks, v_star, 0.7, 0.4, z, 4, occupied=True)
    p = p[p > 1e-4]
    assert np.sort(p / p.sum()) == pytest.approx(np.sort(shares.w[shares.obj == 4]), rel=1e-9)


def _frames(n: int) -> list[Frame]:
    """Two pairs 2 km apart, the pairs at 15 m/s east and 15 m/s north, members 10 m apart."""
    x0 = np.array([[0.0, 15.0, 0.0, 0.0, 0.0], [10.0, 15.0, 0.0, 0.0, 0.0],
                   [2000.0, 0.0, 0.0, 15.0, 0.0], [2000.0, 0.0, 10.0, 15.0, 0.0]])
    out = []
    for k in range(n):
        x = x0.copy()
        x[:, 0] += k * x0[:, 1]
        x[:, 2] += k * x0[:, 3]
        out.append(Frame(k, k * 10**9, "s", "xy", np.zeros((0, 2)), Truth(("A", "B", "C", "D"), x)))
    return out


@pytest.mark.parametrize("name", ["ddp", "dpyp"])
def test_two_far_apart_pairs_are_recovered_by_both_priors(name):
    """4 objects in two pairs: the oracle partition is the true one at every frame (ARI 1)."""
    tracker = go.oracle_tracker(name, load_params("vo2017"), go.TruthObjects(*go.COVS["typical"]))
    group_of = {"A": "g0", "B": "g0", "C": "g1", "D": "g1"}
    for f, e, state in run(tracker, _frames(6), 7):
        assert frame_ari(f.truth, e, group_of) == 1.0
        c = dict(zip(state.labels, state.cluster.tolist()))
        assert c["A"] == c["B"] != c["C"] == c["D"]


def test_sensitivity_is_zero_without_a_discount_and_counts_moves():
    tracker_log: list = []
    tracker = go.oracle_tracker("ddp", load_params("vo2017"), go.TruthObjects(*go.COVS["small"]), tracker_log)
    list(run(tracker, _frames(3), 7))
    s = go.sensitivity(tracker_log, occupied=True)
    assert s == dict(moves=12, differ=0, flips=0, tv_sum=0.0)


def test_pair_errors_count_split_and_merged_pairs():
    """A, B one true group in clusters 1, 2 (one split pair); C free, D free, both in A's cluster 1:
    A-C, A-D, C-D merged (three pairs)."""
    from bnptrack.tracker.types import Estimate, TrackEstimate

    x, P = np.zeros(5), np.eye(5)
    tracks = tuple(TrackEstimate(lab, x, P, 1.0, c) for lab, c in (("A", 1), ("B", 2), ("C", 1), ("D", 1)))
    assert go.pair_errors(Estimate(0, 0, tracks), {"A": "g0", "B": "g0"}) == (1, 3)
