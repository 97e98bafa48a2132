"""The compiled passes of the two-level tracker's cluster level (group_merge.py's
``exclusive_candidates``, group_theta.py's ``theta_sums``) and the history memo against the numpy
code they replaced (kept here as the reference), bit for bit, on seed-pinned random inputs."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp.clusters import _POS_VEL, _Clusters, _merge_groups
from bnptrack.tracker.bnp.group_merge import (_candidate_pairs, _distinct, birth_frame, exclusive_candidates,
                                              merge_exclusive)
from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp.group_bundles import Sweeps, Urn
from bnptrack.tracker.bnp.group_partition import _inv_into, _move
from bnptrack.tracker.bnp.group_sample import Block, Shares, _compact, _table_priors
from bnptrack.tracker.bnp.group_scan import _collect_shares, _option_logw, _partition_kernel
from bnptrack.tracker.bnp.group_share import share_turn, share_velocity
from bnptrack.tracker.bnp.group_theta import inv2, inv2_const, theta_sums
from bnptrack.tracker.bnp.groups import GROUP_PRESETS, GroupTracker
from bnptrack.tracker.bnp.group_fma import dot2, gemv2
from bnptrack.tracker.bnp.urn import grid_mean, log_gamma_prior
from bnptrack.tracker.models.params import load_params


def _same(a, b) -> None:
    """Equal bit for bit (nan where nan; signed zeros equal)."""
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b), strict=True)


def _spd(rng: np.random.Generator, n: int, d: int, scale: float) -> np.ndarray:
    A = rng.normal(size=(n, d, d)) * scale
    return A @ np.swapaxes(A, 1, 2) + 0.1 * scale**2 * np.eye(d)


def _clusters(seed: int, n: int) -> tuple[_Clusters, dict[str, int]]:
    """Objects crowded in 200 m with random covariances and existences; labels of a few scans."""
    rng = np.random.default_rng(seed)
    mean = np.column_stack([rng.uniform(0, 200, n), rng.normal(0, 5, n), rng.uniform(0, 200, n),
                            rng.normal(0, 5, n), rng.normal(0, 0.01, n)])
    cov = _spd(rng, n, 5, 8.0)
    labels = tuple(f"{rng.integers(0, 4)}.{m}" for m in range(n))
    taken = {lab: int(rng.integers(0, 6)) for lab in labels if rng.random() < 0.5}
    return _Clusters(labels, mean, cov, rng.uniform(0.02, 0.9, n), np.ones(n)), taken


# -- numpy references (the code before the compiled passes) ------------------------------------

def _candidate_pairs_reference(c: _Clusters, max_d2: float, taken: dict[str, int]):
    r = c.existence
    ii, jj = np.triu_indices(len(c.labels), k=1)
    keep = r[ii] + r[jj] <= 1.0
    ii, jj = ii[keep].astype(np.int64), jj[keep].astype(np.int64)
    if ii.size == 0:
        return ii, jj
    diff = c.mean[ii][:, _POS_VEL] - c.mean[jj][:, _POS_VEL]
    S = (c.cov[ii] + c.cov[jj])[:, _POS_VEL][:, :, _POS_VEL]
    d2 = np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])
    ii, jj = ii[d2 <= max_d2], jj[d2 <= max_d2]
    keep = ~_distinct(c.labels, taken, ii, jj)
    return ii[keep], jj[keep]


def _merge_exclusive_reference(c: _Clusters, max_d2: float, taken: dict[str, int]):
    n = len(c.labels)
    ii, jj = _candidate_pairs_reference(c, max_d2, taken)
    if ii.size == 0:
        return c, {}
    near = np.zeros((n, n), dtype=bool)
    near[ii, jj] = near[jj, ii] = True
    r = c.existence
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(-r, kind="stable")] = np.arange(n)
    free = np.ones(n, dtype=bool)
    groups: list[list[int]] = []
    for i in sorted(set(ii.tolist()) | set(jj.tolist()), key=rank.__getitem__):
        if not free[i]:
            continue
        group, total = [i], r[i]
        for j in sorted(np.flatnonzero(near[i]).tolist(), key=rank.__getitem__):
            if free[j] and total + r[j] <= 1.0 and near[j, group].all():
                group.append(j)
                total += r[j]
        free[group] = False
        if len(group) > 1:
            groups.append(group)
    if not groups:
        return c, {}
    renamed = {}
    for g in groups:
        final = min((c.labels[k] for k in g), key=birth_frame)
        renamed.update({c.labels[k]: final for k in g if c.labels[k] != final})
    return _merge_groups(c, groups), renamed


def _theta_reference(b: Block, slot: np.ndarray, n_used: int):
    Ri, _ = inv2(b.R)
    h_lam, _ = inv2(b.h_cov)
    lam = np.broadcast_to(h_lam, (n_used, 2, 2)).copy()
    eta = np.broadcast_to(h_lam @ b.h_mean, (n_used, 2)).copy()
    np.add.at(lam, slot, Ri)
    np.add.at(eta, slot, np.einsum("lij,lj->li", Ri, b.v))
    cov, _ = inv2(lam)
    return np.einsum("gij,gj->gi", cov, eta), cov


def _partition_reference(v, R, lam0, eta0, h_lam, h_eta, v_star, z, alpha, d, u, rec_p, rec_mu, rec_cov) -> None:
    """The kernel before the per-table cache (main at the start of this work), with its 2x2
    products in group_fma's formula as the kernel's (tests/tracker/test_group_fma.py checks the
    formula; numba's ``@`` calls the CPU's BLAS, whose last bits differ between CPUs)."""
    P, L, T = v.shape[0], v.shape[1], lam0.shape[1]
    n = np.zeros(T)
    lam, eta = lam0.copy(), eta0.copy()
    Ri = np.empty((P, L, 2, 2))
    Riv = np.empty((P, L, 2))
    for p in range(P):
        for l in range(L):
            _inv_into(R[p, l], Ri[p, l])
            gemv2(Ri[p, l], v[p, l], Riv[p, l])
    for l in range(L):
        _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, 1.0)
    logw = np.empty(T)
    cov = np.empty((2, 2))
    Si = np.empty((2, 2))
    S = u.shape[0]
    for s in range(S):
        for l in range(L):
            _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, -1.0)
            _option_logw(n, v_star, alpha, d, logw)
            for t in range(T):
                if logw[t] == -np.inf:
                    continue
                for p in range(P):
                    _inv_into(lam[p, t], cov)
                    mu = np.empty(2)
                    gemv2(cov, eta[p, t], mu)
                    det = _inv_into(cov + R[p, l], Si)
                    r = v[p, l] - mu
                    Sir = np.empty(2)
                    gemv2(Si, r, Sir)
                    logw[t] += -0.5 * dot2(r, Sir) - 0.5 * np.log(det) - np.log(2.0 * np.pi)
                    if p == 0 and s == S - 1:
                        _inv_into(lam[0, t] - lam0[0, t] + h_lam, rec_cov[l, t])
                        gemv2(rec_cov[l, t], eta[0, t] - eta0[0, t] + h_eta, rec_mu[l, t])
            w = np.exp(logw - logw.max())
            w /= w.sum()
            c = np.cumsum(w)
            k = min(int(np.searchsorted(c, u[s, l], side="right")), T - 1)
            while w[k] == 0.0:  # never land on an impossible table through round-off
                k -= 1
            z[l] = k
            if s == S - 1:
                rec_p[l] = w
            _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, 1.0)


_partition_reference = jit(_partition_reference)


# -- the object -> cluster Gibbs kernel -----------------------------------------------------------

def _partition_inputs(seed: int, L: int, G: int):
    rng = np.random.default_rng(seed)
    P, T = 2, G + L
    v = np.ascontiguousarray(np.stack([rng.normal(0, 8, (L, 2)), rng.normal(0, 60, (L, 2))]))
    R = np.ascontiguousarray(np.stack([_spd(rng, L, 2, 4.0), _spd(rng, L, 2, 30.0)]))
    lam0 = np.ascontiguousarray(np.stack([inv2(_spd(rng, T, 2, 10.0))[0], inv2(_spd(rng, T, 2, 100.0))[0]]))
    eta0 = np.ascontiguousarray(np.einsum("ptij,ptj->pti", lam0, rng.normal(0, 10, (P, T, 2))))
    h_lam = 1e-10 * np.eye(2)
    v_star = np.concatenate([rng.integers(1, 4, G).astype(float), np.zeros(L)])
    z = np.where(rng.random(L) < 0.7, rng.integers(0, max(G, 1), L), G + np.arange(L)).astype(np.int64)
    u = rng.random((6, L))
    return v, R, lam0, eta0, h_lam, np.zeros(2), v_star, z, u


@pytest.mark.parametrize("seed,L,G", [(1, 8, 3), (2, 15, 5), (3, 1, 0), (4, 12, 0), (5, 20, 9)])
@pytest.mark.parametrize("alpha,d", [(0.5, 0.0), (2.0, 0.3)])
def test_partition_kernel_equals_reference(seed: int, L: int, G: int, alpha: float, d: float) -> None:
    v, R, lam0, eta0, h_lam, h_eta, v_star, z, u = _partition_inputs(seed, L, G)
    T = G + L
    out = [z.copy(), np.zeros((L, T)), np.zeros((L, T, 2)), np.zeros((L, T, 2, 2))]
    ref = [z.copy(), np.zeros((L, T)), np.zeros((L, T, 2)), np.zeros((L, T, 2, 2))]
    _partition_kernel(Sweeps(v, R, lam0, eta0, h_lam, h_eta, v_star, out[0], u), Urn(alpha, d, False), *out[1:])
    _partition_reference(v, R, lam0, eta0, h_lam, h_eta, v_star, ref[0], alpha, d, u, *ref[1:])
    for a, b in zip(out, ref):
        _same(a, b)
    assert np.unique(out[0]).size > 1 or L == 1  # the sample moves objects between tables


def _prior_information_reference(b: Block) -> tuple[np.ndarray, np.ndarray]:
    """The numpy code ``_table_priors`` replaced (``Block.prior_information``): ``(T, 2, 2)``,
    ``(T, 2)`` information form of each table's prior (G transitioned, L new)."""
    L, G = b.v.shape[0], b.prior_mean.shape[0]
    h_lam, _ = inv2(b.h_cov)
    p_lam, _ = inv2(b.prior_cov)
    lam0 = np.concatenate([p_lam, np.broadcast_to(h_lam, (L, 2, 2))])
    eta0 = np.concatenate([np.einsum("gij,gj->gi", p_lam, b.prior_mean).reshape(G, 2),
                           np.broadcast_to(h_lam @ b.h_mean, (L, 2))])
    return lam0, eta0


@pytest.mark.parametrize("seed,L,G", [(1, 6, 4), (2, 3, 0)])
def test_table_priors_equal_prior_information(seed: int, L: int, G: int) -> None:
    rng = np.random.default_rng(seed)
    b = Block(np.zeros((L, 2)), np.zeros((L, 2, 2)), rng.normal(0, 10, (G, 2)), _spd(rng, G, 2, 5.0),
              rng.normal(0, 1, 2), _spd(rng, 1, 2, 30.0)[0])
    lam0, eta0 = np.empty((G + L, 2, 2)), np.empty((G + L, 2))
    h_lam, _ = inv2(b.h_cov)
    _table_priors(b.prior_cov, b.prior_mean, h_lam, h_lam @ b.h_mean, lam0, eta0)
    r_lam, r_eta = _prior_information_reference(b)
    _same(lam0, r_lam)
    _same(eta0, r_eta)


@pytest.mark.parametrize("seed", [1, 2])
def test_collect_shares_equal_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    L, T = 9, 14
    rec_p = rng.dirichlet(np.full(T, 0.3), L)
    rec_p[rec_p < 1e-3] = 0.0
    rec_mu, rec_cov = rng.normal(size=(L, T, 2)), rng.normal(size=(L, T, 2, 2))
    obj, w, mu, cov = _collect_shares(rec_p, rec_mu, rec_cov, 1e-4)
    ll, tt = np.nonzero(rec_p > 1e-4)
    r_w = rec_p[ll, tt]
    r_w = r_w / np.bincount(ll, weights=r_w, minlength=L)[ll]
    _same(obj, ll.astype(np.int64))
    _same(w, r_w)
    _same(mu, rec_mu[ll, tt])
    _same(cov, rec_cov[ll, tt])


def _share_velocity_reference(mean, cov, shares, S_w):
    o = shares.obj
    m, P = mean[o], cov[o]
    vel = np.array([1, 3])
    PHt = P[:, :, vel]
    Si, _ = inv2(P[:, vel][:, :, vel] + S_w + shares.cov)
    K = PHt @ Si
    mu = m + np.einsum("pij,pj->pi", K, shares.mu - m[:, vel])
    Pu = P - K @ np.swapaxes(PHt, 1, 2)
    w = shares.w
    new_mean = np.zeros_like(mean)
    np.add.at(new_mean, o, w[:, None] * mu)
    dev = mu - new_mean[o]
    new_cov = np.zeros_like(cov)
    np.add.at(new_cov, o, w[:, None, None] * (Pu + dev[:, :, None] * dev[:, None, :]))
    return new_mean, 0.5 * (new_cov + np.swapaxes(new_cov, 1, 2))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_share_velocity_equals_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    L, T = 7, 10
    mean, cov = rng.normal(0, 20, (L, 5)), _spd(rng, L, 5, 3.0)
    rec_p = rng.dirichlet(np.full(T, 0.4), L)
    obj, w, mu, c = _collect_shares(rec_p, rng.normal(0, 10, (L, T, 2)), _spd(rng, L * T, 2, 2.0).reshape(L, T, 2, 2),
                                    1e-4)
    shares = Shares(obj, w, mu, c)
    S_w = 100.0 * np.eye(2)
    new_mean, new_cov = share_velocity(mean, cov, shares, S_w)
    r_mean, r_cov = _share_velocity_reference(mean, cov, shares, S_w)
    _same(new_mean, r_mean)
    _same(new_cov, r_cov)


def _share_turn_reference(mean, cov, omega, var, z, within_var):
    info = 1.0 / var
    tot_i = np.bincount(z, weights=info)[z] - info
    tot_m = np.bincount(z, weights=info * omega)[z] - info * omega
    has = tot_i > 0
    if not has.any():
        return mean, cov
    mean, cov = mean.copy(), cov.copy()
    y = tot_m[has] / tot_i[has]
    r = 1.0 / tot_i[has] + within_var
    P = cov[has]
    K = P[:, :, 4] / (P[:, 4, 4] + r)[:, None]
    mean[has] = mean[has] + K * (y - mean[has, 4])[:, None]
    Pu = P - K[:, :, None] * P[:, 4, None, :]
    cov[has] = 0.5 * (Pu + np.swapaxes(Pu, 1, 2))
    return mean, cov


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_share_turn_equals_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    L = 11
    mean, cov = rng.normal(0, 0.05, (L, 5)), _spd(rng, L, 5, 0.1)
    z = rng.integers(0, 5, L)
    omega, var = mean[:, 4], cov[:, 4, 4]
    new_mean, new_cov = share_turn(mean, cov, omega, var, z, 1e-4)
    r_mean, r_cov = _share_turn_reference(mean, cov, omega, var, z, 1e-4)
    _same(new_mean, r_mean)
    _same(new_cov, r_cov)
    alone = np.arange(3)  # every member alone: nothing shared, the inputs returned
    out = share_turn(mean[:3], cov[:3], omega[:3], var[:3], alone, 1e-4)
    assert out[0] is not None and np.array_equal(out[0], mean[:3])


def test_compact_hand_computed() -> None:
    """Tables 0-2 transitioned; new tables 7 and 4 become 3 and 4 (increasing order)."""
    _same(_compact(np.array([7, 1, 4, 7, 0]), 3, 9), np.array([4, 1, 3, 4, 0]))


# -- the merge's candidate pairs ------------------------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2, 3, 4])
@pytest.mark.parametrize("max_d2", [4.0, 16.0, 100.0])
def test_candidate_pairs_equal_reference(seed: int, max_d2: float) -> None:
    c, taken = _clusters(seed, 40)
    ii, jj = _candidate_pairs(c, max_d2, taken)
    ri, rj = _candidate_pairs_reference(c, max_d2, taken)
    _same(ii, ri)
    _same(jj, rj)


@pytest.mark.parametrize("seed", [5, 6])
def test_candidates_superset_of_exact_pairs(seed: int) -> None:
    """The bound keeps every pair within the distance, in np.triu_indices order, and drops many."""
    c, _ = _clusters(seed, 40)
    ii, jj = exclusive_candidates(c.mean, c.cov, c.existence, 9.0)
    ri, rj = _candidate_pairs_reference(c, 9.0, {})
    kept = set(zip(ii.tolist(), jj.tolist()))
    assert set(zip(ri.tolist(), rj.tolist())) <= kept
    assert ri.size > 0
    order = ii * 40 + jj
    assert np.all(np.diff(order) > 0)
    both = int(np.sum(np.add.outer(c.existence, c.existence)[np.triu_indices(40, 1)] <= 1.0))
    assert ii.size < both  # the bound prunes


def test_candidates_hand_computed() -> None:
    """Two objects 3 m apart in x, unit covariances: |d|^2 = 9, tr S = 8; kept iff 9 <= 8 max_d2."""
    mean = np.array([[0.0, 0, 0, 0, 0], [3.0, 0, 0, 0, 0]])
    cov = np.stack([np.eye(5), np.eye(5)])
    r = np.array([0.5, 0.5])
    assert exclusive_candidates(mean, cov, r, 1.125)[0].tolist() == [0]
    assert exclusive_candidates(mean, cov, r, 1.12)[0].size == 0
    assert exclusive_candidates(mean, cov, np.array([0.5, 0.6]), 100.0)[0].size == 0  # r sum > 1


@pytest.mark.parametrize("seed", [1, 2, 3, 8, 9])
@pytest.mark.parametrize("max_d2", [9.0, 100.0])
def test_merge_exclusive_equals_reference(seed: int, max_d2: float) -> None:
    """The compiled greedy grouping (greedy_groups) merges as the Python loop did, bit for bit."""
    c, taken = _clusters(seed, 40)
    c = _Clusters(c.labels, c.mean, c.cov, c.existence * 0.6, c.popularity)  # more pairs may merge
    merged, renamed = merge_exclusive(c, max_d2, taken)
    ref, r_renamed = _merge_exclusive_reference(c, max_d2, taken)
    assert renamed == r_renamed
    assert merged.labels == ref.labels
    for a, b in [(merged.mean, ref.mean), (merged.cov, ref.cov), (merged.existence, ref.existence),
                 (merged.popularity, ref.popularity)]:
        _same(a, b)
    if max_d2 == 100.0:
        assert renamed  # something merged


def test_inv2_const_equals_inv2() -> None:
    A = np.array([[900.0, 3.0], [3.0, 400.0]])
    _same(inv2_const(A), inv2(A)[0])
    out = inv2_const(A)
    out[0, 0] = 7.0  # a copy: the remembered inverse is untouched
    _same(inv2_const(A), inv2(A)[0])


def test_merge_exclusive_with_many_clusters_uses_the_tree() -> None:
    """Above 200 clusters the KD-tree path (unchanged) gives the reference's pairs too."""
    c, taken = _clusters(7, 210)
    ii, jj = _candidate_pairs(c, 9.0, taken)
    ri, rj = _candidate_pairs_reference(c, 9.0, taken)
    _same(ii, ri)
    _same(jj, rj)
    merged, renamed = merge_exclusive(c, 9.0, taken)
    assert len(merged.labels) == 210 - len(renamed)


# -- theta's posterior per used cluster -----------------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2, 3])
def test_theta_sums_equal_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    L, G = 25, 7
    b = Block(rng.normal(0, 10, (L, 2)), _spd(rng, L, 2, 3.0), np.zeros((0, 2)), np.zeros((0, 2, 2)),
              rng.normal(0, 1, 2), _spd(rng, 1, 2, 30.0)[0])
    slot = rng.integers(0, G, L)
    slot[:G] = np.arange(G)
    h_lam, _ = inv2(b.h_cov)
    mean, cov = theta_sums(b.R, b.v, slot, G, h_lam, h_lam @ b.h_mean)
    r_mean, r_cov = _theta_reference(b, slot, G)
    _same(mean, r_mean)
    _same(cov, r_cov)


def test_theta_sums_one_member_hand_computed() -> None:
    """Flat-ish prior 0, one member v = (1, 2) with R = diag(2, 4): cov = R, mean = v."""
    mean, cov = theta_sums(np.array([[[2.0, 0.0], [0.0, 4.0]]]), np.array([[1.0, 2.0]]), np.array([0]), 1,
                              np.zeros((2, 2)), np.zeros(2))
    _same(cov[0], np.array([[2.0, -0.0], [-0.0, 4.0]]))
    _same(mean[0], np.array([1.0, 2.0]))


def _hyper_reference(tr: GroupTracker, hist: tuple):
    cfg, h = tr.config, tr.hyper
    hyper = h.history_loglik(hist)
    log_post = hyper + (log_gamma_prior(h.alpha_grid, cfg.alpha_shape, cfg.alpha_scale)
                        + np.log(h.alpha_grid))[:, None]
    if cfg.infer_d and cfg.d_prior == "gamma":
        log_post = log_post + log_gamma_prior(np.maximum(h.d_grid, 1e-12), cfg.d_shape, cfg.d_scale)[None, :]
    alpha, d = grid_mean(log_post, h.alpha_grid, h.d_grid)
    return alpha, d, hyper


# -- the history's (alpha_2, d): a repeated history reuses its result -----------------------------

@pytest.mark.parametrize("name", ["ddp", "dpyp"])
def test_history_memo_equals_fresh_computation(name: str) -> None:
    tr = GroupTracker(load_params("vo2017"), GROUP_PRESETS[name], name)
    fresh = GroupTracker(load_params("vo2017"), GROUP_PRESETS[name], name)
    hists = [(None, np.array([3, 1], dtype=np.int64), 0, 0, np.zeros(tr.hyper.d_grid.size)),
             (None, np.array([3, 1], dtype=np.int64), 0, 0, np.zeros(tr.hyper.d_grid.size)),
             (None, np.array([4, 1], dtype=np.int64), 2, 5, np.full(tr.hyper.d_grid.size, -0.5)),
             (None, np.array([3, 1], dtype=np.int64), 0, 0, np.zeros(tr.hyper.d_grid.size))]
    for hist in hists:
        alpha, d, hyper = tr.hyper._history_hyper(hist)
        r_alpha, r_d, r_hyper = _hyper_reference(fresh, hist)
        assert (alpha, d) == (r_alpha, r_d)
        _same(hyper, r_hyper)
    assert tr.hyper._history_memo["last"][0][0] == np.array([3, 1], dtype=np.int64).tobytes()
