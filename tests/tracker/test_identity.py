"""The multi-scan check of crossing tracks' labels (tracker/bnp/identity.py)."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.bnp import identity

# constant-velocity model on the 5-state [x, vx, y, vy, omega] (omega unused), position measured
_R = np.diag([25.0, 25.0])
_H = np.zeros((2, 5))
_H[0, 0] = _H[1, 2] = 1.0


def _F(dt):
    F = np.eye(5)
    F[0, 1] = F[2, 3] = dt
    return F


def _Q(dt, q=1.0):
    Q = np.zeros((5, 5))
    for i in (0, 2):
        Q[i, i], Q[i, i + 1], Q[i + 1, i], Q[i + 1, i + 1] = q * dt**3 / 3, q * dt**2 / 2, q * dt**2 / 2, q * dt
    Q[4, 4] = 1e-6
    return Q


def _predict(m, P, dt):
    F = _F(dt)
    return m @ F.T, F @ P @ F.T + _Q(dt)


def _update(m, P, z):
    S = _H @ P @ _H.T + _R
    K = P @ _H.T @ np.linalg.inv(S)
    return m + K @ (z - _H @ m), P - K @ S @ K.T


def test_information_of_a_linear_update_is_the_measurements():
    """Lambda = H' R^-1 H and eta = H' R^-1 z for a Kalman update of a position measurement."""
    m_s = np.array([[10.0, 1.0, -5.0, 2.0, 0.0]])
    P_s = (np.eye(5) * 100.0)[None]
    z = np.array([13.0, -2.0])
    m, P = _update(m_s[0], P_s[0], z)
    lam, eta = identity.measurement_information(m_s, P_s, m[None], P[None])
    Ri = np.linalg.inv(_R)
    np.testing.assert_allclose(lam[0], _H.T @ Ri @ _H, atol=1e-9)
    np.testing.assert_allclose(eta[0], _H.T @ Ri @ z, atol=1e-9)


def _crossing_ring(exchange_at: int | None, W: int = 6):
    """Two objects crossing at ring scan 2 (A along +x at 20 m/s, B along +y at 20 m/s); each
    track filtered with its own measurements, or with the other's from ``exchange_at`` on."""
    rng = np.random.default_rng(3)
    truth = {"A": lambda t: np.array([-40.0 + 20.0 * t, 0.0]), "B": lambda t: np.array([0.0, -40.0 + 20.0 * t])}
    vel = {"A": np.array([20.0, 0.0]), "B": np.array([0.0, 20.0])}
    z = {k: [f(t) + rng.normal(0, 5.0, 2) for t in range(W)] for k, f in truth.items()}
    ring = identity.empty_ring(W)
    means = {}
    for k in "AB":
        p = truth[k](0)
        means[k] = (np.array([p[0], vel[k][0], p[1], vel[k][1], 0.0]), np.diag([25.0, 16.0, 25.0, 16.0, 1e-4]))
    for t in range(W):
        own, info = [], []
        for k, other in (("A", "B"), ("B", "A")):
            m, P = means[k]
            if t > 0:
                m_s, P_s = _predict(m, P, 1.0)
                src = other if exchange_at is not None and t >= exchange_at else k
                m, P = _update(m_s, P_s, z[src][t])
                info.append(identity.measurement_information(m_s[None], P_s[None], m[None], P[None]))
            else:
                info.append((np.zeros((1, 5, 5)), np.zeros((1, 5))))
            means[k] = (m, P)
            own.append((m, P))
        src = np.arange(2) if t > 0 else np.full(2, -1)
        ring = identity.advance(ring, src, t, t * 10**9, (np.stack([o[0] for o in own]), np.stack([o[1] for o in own])),
                                (np.concatenate([i[0] for i in info]), np.concatenate([i[1] for i in info])),
                                np.full(2, -1))
    return ring


def test_keeping_wins_when_each_track_kept_its_object():
    ring = _crossing_ring(None)
    ev = identity.pair_evidence(ring, [(0, 1)], 2, _predict)[0]
    assert ev[0] > ev[1:].max() + 5.0
    assert identity.crossing_swaps(ring, 3, 13.8, 0.0, _predict) == []


def test_a_swap_after_the_crossing_is_found():
    """The tracks exchanged objects from scan 3 on: the hypothesis swapping from scan 3 wins."""
    ring = _crossing_ring(3)
    ev = identity.pair_evidence(ring, [(0, 1)], 2, _predict)[0]
    assert int(np.argmax(ev)) == 2  # hypotheses: keep, swap from 2, from 3, ...
    assert identity.crossing_swaps(ring, 3, 13.8, 0.0, _predict) == [(0, 1)]
    marked = identity.swapped_ring(ring, [(0, 1)], 5)
    assert identity.crossing_swaps(marked, 3, 13.8, 0.0, _predict) == []  # not exchanged twice


def test_pairs_that_never_meet_are_not_checked():
    ring = _crossing_ring(3)
    far = identity.Ring(ring.frames, ring.stamps, ring.mean.copy(), ring.cov, ring.lam, ring.eta, ring.swapped,
                        ring.cluster)
    far.mean[1, :, 0] += 5000.0  # 5 km away
    assert identity.crossing_swaps(far, 3, 13.8, 0.0, _predict) == []


def test_settled_members_of_one_cluster_throughout_are_not_checked():
    """Two settled tracks in one motion cluster at every scan of the ring move together: no check."""
    ring = _crossing_ring(3)
    convoy = identity.Ring(ring.frames, ring.stamps, ring.mean, ring.cov, ring.lam, ring.eta, ring.swapped,
                           np.full_like(ring.cluster, 7))
    settled = np.ones(2, dtype=bool)
    assert identity.crossing_swaps(convoy, 3, 13.8, 0.0, _predict, settled) == []
    # not settled (together for a few scans only, as two objects that meet): checked
    assert identity.crossing_swaps(convoy, 3, 13.8, 0.0, _predict, np.array([True, False])) == [(0, 1)]
    once = convoy.cluster.copy()
    once[1, 0] = 8  # apart at one scan: checked
    apart = identity.Ring(ring.frames, ring.stamps, ring.mean, ring.cov, ring.lam, ring.eta, ring.swapped, once)
    assert identity.crossing_swaps(apart, 3, 13.8, 0.0, _predict, settled) == [(0, 1)]


def test_pairs_are_scored_alike_alone_and_in_a_batch():
    ring = _crossing_ring(3)
    alone = identity.pair_evidence(ring, [(0, 1)], 2, _predict)
    batch = identity.pair_evidence(ring, [(1, 0), (0, 1)], 2, _predict)
    np.testing.assert_allclose(batch[1], alone[0], rtol=1e-12)
    np.testing.assert_allclose(batch[0], alone[0], rtol=1e-12)  # the evidence is symmetric in the pair


def test_scans_together_count_only_a_cluster_shared_with_another_object():
    from bnptrack.tracker.bnp.group_share import together_scans

    cluster = np.array([5, 5, 6, 7, 7])
    before = np.array([5, -1, 6, 3, 7])  # last scan's clusters (-1: not a member then)
    counts = np.array([2, -1, 4, 0, 1])
    # 5 kept with a partner: 2 + 1; a newcomer to 5: 1; alone in 6: 0; moved to 7 with a partner: 1; stayed in 7: 1 + 1
    assert together_scans(cluster, before, counts).tolist() == [3, 1, 0, 1, 2]
    assert together_scans(cluster, before, None).tolist() == [1, 1, 0, 1, 1]


def _groups_run(config, k: int = 30):
    from bnptrack.sources.scenarios import get_scenario
    from bnptrack.sources.synthetic import simulate_all
    from bnptrack.tracker.bnp.groups import GroupTracker
    from bnptrack.tracker.models.params import load_params
    from bnptrack.tracker.state import run

    sc = get_scenario("groups", 101, scene=("n_objects=2", "group_sizes=[3,3]", "passing_pairs=1", "K=40"))
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, 101)[:k]
    tr = GroupTracker(params, config)
    return tr, frames, list(run(tr, frames, seed=5))


def test_the_paper_preset_has_the_checks_off_and_its_state_stays_empty():
    import msgspec

    from bnptrack.tracker.bnp.groups import GROUP_PRESETS

    cfg = GROUP_PRESETS["ddp-paper"]
    assert cfg.crossing_scans == 0 and cfg.share_after == 0
    # the product default differs from the paper's algorithm by the object level's combined update
    # and sharing after twelve scans together
    assert GROUP_PRESETS["ddp"].share_after == 12 and GROUP_PRESETS["ddp"].crossing_scans == 0
    assert msgspec.structs.replace(GROUP_PRESETS["ddp"], share_after=0, objects=cfg.objects) == cfg
    _, _, out = _groups_run(cfg, k=12)
    state = out[-1][2]
    assert state.together.size == 0 and state.id_frames.size == 0 and state.id_mean.shape[0] == 0
    assert all("crossing_swaps" not in e.diagnostics for _, e, _ in out)


def test_with_the_checks_on_the_ring_follows_the_objects_and_a_snapshot_resumes_it():
    import msgspec

    from bnptrack.tracker.bnp.groups import GROUP_PRESETS, GroupState
    from bnptrack.tracker.state import restore, run, snapshot

    cfg = msgspec.structs.replace(GROUP_PRESETS["ddp"], crossing_scans=3, share_after=4)
    tr, frames, out = _groups_run(cfg)
    W = cfg.crossing_before + 1 + cfg.crossing_scans
    state = out[-1][2]
    N = len(state.labels)
    assert N > 0 and state.id_mean.shape == (N, W, 5) and state.id_cov.shape == (N, W, 5, 5)
    assert state.id_frames.tolist() == list(range(state.frame - W + 1, state.frame + 1))
    assert state.together.shape == (N,) and state.together.max() >= 4  # the groups of three sat together
    assert all("crossing_swaps" in e.diagnostics for _, e, _ in out)
    mid = out[19][2]
    back = restore(snapshot(mid), GroupState)
    resumed = [e for _, e, _ in run(tr, frames[20:], seed=5, state=back)]
    for (_, e, _), r in zip(out[20:], resumed):
        assert [t.label for t in e.tracks] == [t.label for t in r.tracks]
        for a, b in zip(e.tracks, r.tracks):
            np.testing.assert_array_equal(a.state, b.state)
