r"""The JPDA* assignment (Blom & Bloem 2000): each cluster's detection probability moved onto
the measurement it takes in the most probable one-to-one assignment, solved per connected
component of the gated pairs."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.bnp import _update_kernels as _k
from bnptrack.tracker.filtering import SCIPY_PAIRS

_FORBIDDEN = 1e6  # assignment cost of an impossible pair

#: Cost-matrix entries (clusters x (measurements + missed)) above which a block is solved on its
#: edges alone (:func:`_sparse_assignment`) rather than as a dense matrix: the dense scenes of
#: ``benchmarks/scale.py --mode dense`` reach one block of 2,741 x 5,626 entries, 123 MB.
SPARSE_ENTRIES = 1 << 20


def best_permutation(p_lm: np.ndarray) -> np.ndarray:
    r"""Dense form of :func:`best_permutation_pairs`: ``(N, M)`` marginals in, ``(N, M)`` out."""
    N, M = p_lm.shape
    ti, mi = np.nonzero(p_lm > 0.0)
    t, m, p = best_permutation_pairs(N, ti, mi, p_lm[ti, mi])
    out = np.zeros_like(p_lm)
    out[t, m] = p
    return out


def best_permutation_pairs(n: int, ti: np.ndarray, mi: np.ndarray, p: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Move each cluster's detection probability onto one measurement: the one it takes in the
    most probable one-to-one assignment of the marginals (JPDA*, Blom & Bloem 2000).

    ``p[j] = Pr(c_{mi_j} = ti_j)`` for the gated pairs (``n`` clusters).  The assignment
    maximises :math:`\sum_l \log p_{l, m(l)}` with "missed" (cost
    :math:`-\log(1 - \sum_m p_{lm})`) as every cluster's private alternative; a cluster the
    assignment leaves missed keeps its mass on its most likely measurement.  Row sums
    (detection probabilities) are unchanged.  A pair whose cost exceeds its cluster's
    "missed" cost is in no optimum; without those the problem separates over the connected
    components of the pairs graph: a component with one cluster needs no solver (either
    way its mass goes to its most likely measurement), the others are solved one by one
    (``linear_sum_assignment``), so the cost follows the size of the groups, not N x M.
    Returns one pair per cluster that has any mass, sorted by cluster.
    """
    clusters, choice, p_det, lt, lm, lp, conflict, small, args = _k.jpda_select(
        int(n), np.asarray(ti, dtype=np.int64), np.asarray(mi, dtype=np.int64), np.asarray(p, dtype=float), SCIPY_PAIRS)
    if conflict and small:  # one assignment over every live cluster
        choice = _k.jpda_solve(np.log(args), clusters, choice, lt, lm, _FORBIDDEN)
    elif conflict:
        _solve_components(n, lt, lm, lp, p_det, clusters, choice)
    return clusters, choice, p_det[clusters]




def _solve_components(n, ti, mi, p, p_det, clusters, choice) -> None:
    """Per connected component with two clusters preferring one measurement, the JPDA*
    assignment (updates ``choice``, aligned with the sorted ``clusters``)."""
    from bnptrack.tracker.numerics import scipy_extension  # scipy.optimize's solver, not its slow import
    linear_sum_assignment = scipy_extension("optimize", "_lsap").linear_sum_assignment
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    M = int(mi.max()) + 1
    # an edge costlier than its cluster's "missed" column is in no optimum (moving that
    # cluster to missed frees the column and costs less): dropped, the components shrink
    useful = np.minimum(-np.log(p), _FORBIDDEN) <= -np.log(np.maximum(1.0 - p_det[ti], 1e-300))
    ti, mi, p = ti[useful], mi[useful], p[useful]
    if ti.size == 0:
        return
    graph = coo_matrix((np.ones(ti.size), (ti, n + mi)), shape=(n + M, n + M))
    _, comp = connected_components(graph, directed=False)
    # a component whose clusters' most likely measurements are all different is solved by
    # them (a lower bound every cluster attains; a missed cluster keeps that measurement too)
    key = comp[clusters] * M + choice
    uniq, count = np.unique(key, return_counts=True)
    conflict = np.zeros(comp.max() + 1, dtype=bool)
    conflict[uniq[count > 1] // M] = True
    shared = conflict[comp[ti]]
    if not shared.any():
        return
    ts, ms, ps = ti[shared], mi[shared], p[shared]
    cs = comp[ts]
    order = np.lexsort((ts, cs))
    ts, ms, ps, cs = ts[order], ms[order], ps[order], cs[order]
    starts = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
    row = _local_rank(cs * n + ts, starts, cs[starts] * n)  # 0.. within each component
    col = _local_rank(cs * M + ms, starts, cs[starts] * M)
    pos = np.searchsorted(clusters, ts)  # where each edge's cluster sits in ``clusters``
    pd_edge = p_det[ts]
    for a, b in zip(starts.tolist(), np.r_[starts[1:], ts.size].tolist()):
        _solve_block(row[a:b], col[a:b], pos[a:b], ms[a:b], ps[a:b], pd_edge[a:b], choice, linear_sum_assignment)


def _solve_block(r_idx, c_idx, pos, meas, p, p_det, choice, lsa) -> None:
    """One JPDA* assignment over a block of edges (local row/column indices ``r_idx``,
    ``c_idx``; ``pos`` the edge's place in ``choice``, ``meas`` its measurement, ``p_det`` its
    cluster's detection probability): "missed" is each cluster's private column.  A block of
    more than :data:`SPARSE_ENTRIES` matrix entries is solved on its edges
    (:func:`_sparse_assignment`)."""
    L, C = int(r_idx.max()) + 1, int(c_idx.max()) + 1
    rows = np.zeros(L, dtype=np.int64)
    rows[r_idx] = pos
    cols = np.zeros(C, dtype=np.int64)
    cols[c_idx] = meas
    miss = np.zeros(L)
    miss[r_idx] = -np.log(np.maximum(1.0 - p_det, 1e-300))
    edge = np.minimum(-np.log(p), _FORBIDDEN)
    if L * (C + L) > SPARSE_ENTRIES:
        rr, cc = _sparse_assignment(r_idx, c_idx, edge, miss, C)
    else:
        cost = np.full((L, C + L), _FORBIDDEN)
        cost[r_idx, c_idx] = edge
        cost[np.arange(L), C + np.arange(L)] = miss
        rr, cc = lsa(cost)
    hit = cc < C  # missed: keeps its most likely measurement (already in choice)
    choice[rows[rr[hit]]] = cols[cc[hit]]


def _sparse_assignment(r_idx, c_idx, edge, miss, C) -> tuple[np.ndarray, np.ndarray]:
    """The assignment :func:`_solve_block`'s dense matrix gives, on the edges alone (scipy's
    ``min_weight_full_bipartite_matching``, LAPJVsp): the block's edges plus each cluster's
    "missed" column ``C + row``.  An absent entry of the dense matrix costs ``_FORBIDDEN``,
    more than any missed column (at most ``-log 1e-300``), so no optimum uses one; every cost
    is raised by 1 (the solver drops zero-weight edges), which adds ``L`` to every full
    matching and leaves the optimum where it is.  Returns ``(rows, columns)`` matched."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import min_weight_full_bipartite_matching

    L = miss.size
    own = np.arange(L)
    graph = csr_matrix((np.r_[edge, miss] + 1.0, (np.r_[r_idx, own], np.r_[c_idx, C + own])), shape=(L, C + L))
    return min_weight_full_bipartite_matching(graph)


def _local_rank(key: np.ndarray, starts: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Dense rank of ``key`` within each group (the groups are the runs beginning at
    ``starts``; a group's keys all lie in ``[base, next group's base)``)."""
    uniq, inv = np.unique(key, return_inverse=True)
    first = np.searchsorted(uniq, base)  # rank of each group's smallest key
    grp = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, key.size]))
    return inv - first[grp]
