"""The GLMB's compiled starts and children (tracker/glmb/starts.py, children.py) against the numpy
reference: candidate sets, optimal starts by connected groups, distinct children and their
weights, bit for bit; and brute force on small problems."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bnptrack.tracker.glmb import candidate_sets, gibbs_chains, split_chains, start_optimal
from bnptrack.tracker.glmb.children import _np_sum, children, distinct_children
from bnptrack.tracker.glmb.gibbs import allocate_samples, sample_chains
from bnptrack.tracker.glmb.hypotheses import _DET, assignment_log_eta, merge_children, unique_rows
from bnptrack.tracker.glmb.row_sort import _sort_rows
from bnptrack.tracker.glmb.starts import starts


def _problem(rng: np.random.Generator, n_rows: int, M: int, p_gate: float, H: int, width: int):
    """A random eta matrix (gated pairs -inf, some candidates ungated) and parents."""
    E = np.log(rng.uniform(0.01, 1.0, size=(n_rows, M + 2)))
    E[:, _DET:][rng.uniform(size=(n_rows, M)) > p_gate] = -np.inf
    n_surv = n_rows - 2
    hyp = np.full((H, width), -1, dtype=np.int64)
    for h in range(H):
        k = rng.integers(0, min(width, n_surv) + 1)
        hyp[h, :k] = np.sort(rng.choice(n_surv, size=k, replace=False))
    return E, hyp, n_surv


def _reference_children(E, cand, start, log_w, chain_parent, length, samples):
    owner = chain_parent[sample_chains(length)]
    uniq, _ = unique_rows(np.column_stack([owner, samples]))
    p_idx, gamma = uniq[:, 0], uniq[:, 1:]
    lw = log_w[p_idx] + assignment_log_eta(E, cand[p_idx], gamma)
    return merge_children(cand[p_idx], gamma, lw, E.shape[1] - _DET)


@pytest.mark.parametrize("seed", range(12))
def test_starts_and_children_equal_the_numpy_reference(seed):
    """Dense and sparse gating, many clashes: candidate sets, starts and feasibility equal
    candidate_sets + start_optimal; the children (keys, weights, sample count) equal
    unique_rows + assignment_log_eta + merge_children to the last bit."""
    rng = np.random.default_rng(seed)
    n_rows, M = int(rng.integers(4, 14)), int(rng.integers(1, 9))
    E, hyp, n_surv = _problem(rng, n_rows, M, p_gate=[0.2, 0.5, 0.9][seed % 3], H=30, width=6)
    if seed % 4 == 0:
        E[0, :_DET] = -np.inf  # a candidate that must be detected: infeasible parents
        E[0, _DET] = np.log(2.0)
    cand_ref = candidate_sets(hyp, n_surv, 2)
    start_ref, ok_ref = start_optimal(E, cand_ref)
    cand, start, ok = starts(E, hyp, n_surv, 2)
    np.testing.assert_array_equal(cand, cand_ref)
    np.testing.assert_array_equal(ok, ok_ref)
    np.testing.assert_array_equal(start[ok], start_ref[ok])
    parents = np.flatnonzero(ok)
    if parents.size == 0:
        return
    log_w = np.log(rng.dirichlet(np.ones(parents.size)))
    chain_parent, length = split_chains(rng.integers(1, 25, size=parents.size), 4)
    samples = gibbs_chains(rng, E, cand[parents][chain_parent], start[parents][chain_parent], length)
    ref = _reference_children(E, cand[parents], start[parents], log_w, chain_parent, length, samples)
    got = distinct_children(E, samples, chain_parent, length, cand[parents], log_w)
    np.testing.assert_array_equal(got.keys, ref.keys)
    assert got.log_w.tobytes() == ref.log_w.tobytes()
    assert got.n_samples == ref.n_samples
    # the whole pipeline (allocation, chains, uniforms from the rng, sweeps, children)
    log_w_all = np.full(ok.size, -np.inf)
    log_w_all[parents] = log_w
    chain_parent, length = split_chains(allocate_samples(log_w, 40), 3)
    r1, r2 = np.random.default_rng(seed + 50), np.random.default_rng(seed + 50)
    samples = gibbs_chains(r1, E, cand[parents][chain_parent], start[parents][chain_parent], length)
    ref = _reference_children(E, cand[parents], start[parents], log_w, chain_parent, length, samples)
    got = children(r2, E, cand, start, ok, log_w_all, 40, 3)
    np.testing.assert_array_equal(got.keys, ref.keys)
    assert got.log_w.tobytes() == ref.log_w.tobytes()
    assert got.n_samples == ref.n_samples
    assert r1.random() == r2.random()  # the same number of uniforms drawn


def test_starts_are_the_brute_force_optimum_with_independent_groups():
    """Two groups of candidates competing for disjoint measurements plus an ungated one:
    the start is the exhaustive optimum over assignments with distinct measurements."""
    E = np.full((6, 2 + 4), -np.inf)
    E[:, 0] = np.log([0.1, 0.2, 0.05, 0.1, 0.3, 0.4])
    E[:, 1] = np.log([0.05, 0.1, 0.1, 0.02, 0.2, 0.1])
    E[0, 2:4] = np.log([5.0, 4.0])  # rows 0, 1 want z0; row 0 can take z1
    E[1, 2] = np.log(6.0)
    E[2, 4:6] = np.log([3.0, 2.9])  # rows 2, 3 want z2; row 3 can take z3
    E[3, 4:6] = np.log([3.1, 1.0])
    hyp = np.array([[0, 1, 2, 3, 4], [0, 2, -1, -1, -1]])
    cand, start, ok = starts(E, hyp, 5, 1)
    assert ok.all()
    for h in range(2):
        rows = cand[h][cand[h] >= 0]
        best = max((g for g in itertools.product(range(6), repeat=rows.size)
                    if len([j for j in g if j >= 2]) == len({j for j in g if j >= 2})),
                   key=lambda g: sum(E[r, j] for r, j in zip(rows, g)))
        assert tuple(start[h, : rows.size]) == best
    assert tuple(start[0, :6]) == (3, 2, 5, 4, 0, 0)  # hand: 0->z1, 1->z0, 2->z3, 3->z2, 4 dies, birth dies


def test_numpy_order_sum_and_row_sort():
    """_np_sum reproduces np.sum bit for bit (plain, 8-way unrolled and pairwise ranges);
    _sort_rows is np.lexsort's stable order."""
    rng = np.random.default_rng(5)
    for n in (0, 1, 7, 8, 9, 15, 16, 17, 127, 128, 129, 300, 1000):
        a = rng.normal(size=n) * 10.0 ** rng.integers(-8, 8, size=n)
        assert _np_sum(a, n) == np.sum(a)
    A = rng.integers(0, 3, size=(200, 4))
    np.testing.assert_array_equal(_sort_rows(A), np.lexsort(A.T[::-1]))
