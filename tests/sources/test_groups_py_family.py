"""The ``groups-py`` family (sources/scene_families.py): a Pitman-Yor partition of 100-300
objects whose groups overlap in space and velocity."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.scene_families import FAMILIES, scene_config
from bnptrack.tracker.config import ConfigError


def _velocities(sc) -> tuple[np.ndarray, np.ndarray]:
    """Each group's (velocity, turn rate) and every group's members' spread of them."""
    S = sc.states()
    index = {t.id: i for i, t in enumerate(sc.targets)}
    vel, spread = [], []
    for g in sc.groups:
        rows = [index[i] for i in g]
        first = np.array([S[np.flatnonzero(~np.isnan(S[:, r, 0]))[0], r] for r in rows])
        vel.append(first[0, [1, 3, 4]])
        spread.append(np.ptp(first[:, [1, 3, 4]], axis=0).max())
    return np.array(vel), np.array(spread)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_groups_py_counts_and_overlapping_velocities(seed):
    fam = FAMILIES["groups-py"]
    sc = get_scenario("groups-py", seed)
    n = len(sc.targets) - 1  # one free object besides the partition
    assert fam.py_objects <= n <= fam.py_objects_max and sc.K == 50
    assert sum(len(g) for g in sc.groups) <= n
    vel, spread = _velocities(sc)
    assert np.all(spread < 1e-9)  # members share velocity and turn rate
    assert np.all(vel[:, 2] == 0.0)  # straight
    # about one scene velocity: per axis the groups' spread is that of N(0, 5^2)
    if len(vel) >= 5:
        assert 2.0 < vel[:, :2].std(axis=0, ddof=1).mean() < 9.0


def test_pitman_yor_sizes_draw_as_the_generators_choice_draws():
    """The urn's draws equal ``rng.choice(K + 1, p=w / w.sum())`` draw for draw, so the
    generated scenes are those of numpy's own weighted choice."""
    from bnptrack.sources.scene_families import pitman_yor_sizes

    def by_choice(rng, n, alpha, d):
        sizes: list[int] = []
        for _ in range(n):
            w = np.array([s - d for s in sizes] + [alpha + d * len(sizes)])
            j = int(rng.choice(w.size, p=w / w.sum()))
            sizes[j:j + 1] = [sizes[j] + 1] if j < len(sizes) else [1]
        return sizes

    for seed, n, alpha, d in [(1, 300, 1.0, 0.6), (2, 300, 5.0, 0.0), (3, 40, 0.3, 0.9)]:
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        assert pitman_yor_sizes(a, n, alpha, d) == by_choice(b, n, alpha, d)
        assert a.random() == b.random()  # the same draws consumed


def test_groups_py_discount_zero_has_fewer_singletons():
    def singles(d):
        out = []
        for seed in range(1, 4):  # seeds 1-3: 22.3 singletons on average against 0.7
            sc = get_scenario("groups-py", seed, (f"py_discount={d}",))
            out.append(len(sc.targets) - 1 - sum(len(g) for g in sc.groups))
        return np.mean(out)

    # Pitman-Yor with alpha 1: expected singletons grow as n^d; d = 0 keeps about alpha of them
    assert singles(0.6) > 3 * singles(0.0)


def test_groups_py_centres_share_a_region():
    sc = get_scenario("groups-py", 4, ("py_discount=0.6",))
    S = sc.states()
    index = {t.id: i for i, t in enumerate(sc.targets)}
    # at scan 30 the groups present lie about one moving point: within region + spread + drift
    k = 29
    members = [index[i] for g in sc.groups for i in g if not np.isnan(S[k, index[i], 0])]
    pos = S[k, members][:, [0, 2]]
    assert np.linalg.norm(pos - pos.mean(axis=0), axis=1).max() < 400 + 15 * np.sqrt(300) + 2 * 5.0 * 3 * 50


def test_groups_py_settings_are_checked():
    with pytest.raises(ConfigError, match="py_objects_max"):
        scene_config("groups-py", ["py_objects_max=50"])
    with pytest.raises(ConfigError, match="group_region"):
        scene_config("groups-py", ["group_region=-1"])
