"""The GLMB's optimal starts of a frame in compiled passes (:func:`starts`):
:func:`~tracker.glmb.hypotheses.candidate_sets` and :func:`~tracker.glmb.gibbs.start_optimal`,
each row's best option once per frame; a parent whose best options clash is split into the
connected groups of its gating graph (candidates linked by a shared gated measurement) and only
the clashing groups are solved by the shortest augmenting path assignment of
:mod:`tracker.glmb.assignment`, each on its own small matrix.  The same results as the numpy
reference, bit for bit (test: ``tests/tracker/test_glmb_children.py``)."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.glmb.assignment import _lsap_batch
from bnptrack.tracker.glmb.hypotheses import _DET, _DIE, _MISS


def _row_options(E: np.ndarray):  # pragma: no cover - compiled
    """Per candidate row: its best option (``np.argmax``), its best of dies/missed (missed on
    a tie, as the assignment's dummy column) and its gated measurements (CSR ``ptr``,
    ``cols``, increasing)."""
    N, K = E.shape
    best = np.empty(N, dtype=np.int64)
    nd = np.empty(N, dtype=np.int64)
    ptr = np.zeros(N + 1, dtype=np.int64)
    for r in range(N):
        b = 0
        for j in range(1, K):
            if E[r, j] > E[r, b]:
                b = j
        best[r] = b
        nd[r] = _MISS if E[r, _MISS] >= E[r, _DIE] else _DIE
        ptr[r + 1] = ptr[r]
        for j in range(_DET, K):
            if np.isfinite(E[r, j]):
                ptr[r + 1] += 1
    cols = np.empty(ptr[N], dtype=np.int64)
    for r in range(N):
        t = ptr[r]
        for j in range(_DET, K):
            if np.isfinite(E[r, j]):
                cols[t] = j - _DET
                t += 1
    return best, nd, ptr, cols


_row_options = jit(_row_options)


def _find(uf: np.ndarray, i: int) -> int:  # pragma: no cover - compiled
    while uf[i] != i:
        uf[i] = uf[uf[i]]
        i = uf[i]
    return i


_find = jit(_find)


def _solve_group(E: np.ndarray, c: np.ndarray, members: np.ndarray, nm: int, best: np.ndarray, nd: np.ndarray,
                 ptr: np.ndarray, cols: np.ndarray, mark: np.ndarray, out: np.ndarray) -> bool:  # pragma: no cover
    """Options of one connected group of gated candidates ``members[:nm]`` (candidates linked
    by shared gated measurements): their best options if no two share a measurement, else the
    shortest augmenting path assignment (:func:`~tracker.glmb.assignment._lsap_kernel`) on the
    group's measurements plus one "not detected" column per member.  Returns feasibility."""
    clash = False
    for a in range(nm):
        b = best[c[members[a]]]
        out[members[a]] = b if b >= _DET else nd[c[members[a]]]
        if b >= _DET:
            if mark[b - _DET] == 1:
                clash = True
            mark[b - _DET] = 1
    for a in range(nm):
        b = best[c[members[a]]]
        if b >= _DET:
            mark[b - _DET] = 0
    if not clash:
        return True
    n_col = 0
    for a in range(nm):  # the group's measurements, increasing
        r = c[members[a]]
        for t in range(ptr[r], ptr[r + 1]):
            if mark[cols[t]] == 0:
                mark[cols[t]] = 1
                n_col += 1
    meas = np.empty(n_col, dtype=np.int64)
    q = 0
    for m in range(mark.size):
        if mark[m] == 1:
            meas[q] = m
            q += 1
            mark[m] = 0
    cost = np.full((1, nm, n_col + nm), np.inf)
    for a in range(nm):
        r = c[members[a]]
        for q in range(n_col):
            cost[0, a, q] = -E[r, _DET + meas[q]]
        cost[0, a, n_col + a] = -E[r, nd[r]]
    col = np.full((1, nm), n_col, dtype=np.int64)
    solved = np.zeros(1, dtype=np.bool_)
    _lsap_batch(cost, col, solved)
    if not solved[0]:
        return False
    ok = True
    for a in range(nm):
        if not np.isfinite(cost[0, a, col[0, a]]):
            ok = False
        out[members[a]] = _DET + meas[col[0, a]] if col[0, a] < n_col else nd[c[members[a]]]
    return ok


_solve_group = jit(_solve_group)


def _start_one(E: np.ndarray, c: np.ndarray, n: int, out: np.ndarray, best: np.ndarray, nd: np.ndarray,
               ptr: np.ndarray, cols: np.ndarray, owner: np.ndarray, mark: np.ndarray) -> bool:  # pragma: no cover
    """:func:`~tracker.glmb.gibbs.start_optimal` of one parent with candidates ``c[:n]``:
    writes its options to ``out[:n]``, returns feasibility.  Where two best options clash,
    the association problem is split into the connected groups of the gating graph
    (candidates linked by a shared gated measurement; union-find) and only the groups with a
    clash are solved by linear assignment (:func:`_solve_group`): the groups are independent,
    so the optimum is the union of the groups' optima.  ``owner`` (M,) all -1 and ``mark``
    (M,) all 0: work space, left as found."""
    clash = False
    ok = True
    for i in range(n):
        b = best[c[i]]
        out[i] = b
        if not np.isfinite(E[c[i], b]):
            ok = False
        if b >= _DET:
            if mark[b - _DET] == 1:
                clash = True
            mark[b - _DET] = 1
    for i in range(n):
        if out[i] >= _DET:
            mark[out[i] - _DET] = 0
    if ok and not clash:
        return True
    ok = True
    uf = np.arange(n)
    for i in range(n):
        r = c[i]
        out[i] = nd[r]
        if ptr[r] == ptr[r + 1]:
            if not np.isfinite(E[r, nd[r]]):
                ok = False
            continue
        for t in range(ptr[r], ptr[r + 1]):
            m = cols[t]
            if owner[m] < 0:
                owner[m] = i
            else:
                uf[_find(uf, i)] = _find(uf, owner[m])
    for i in range(n):
        r = c[i]
        for t in range(ptr[r], ptr[r + 1]):
            owner[cols[t]] = -1
    members = np.empty(n, dtype=np.int64)
    for root in range(n):
        if ptr[c[root]] == ptr[c[root] + 1] or _find(uf, root) != root:
            continue
        nm = np.int64(0)  # not 0: a literal start compiles _solve_group again for Literal[int](0)
        for i in range(n):
            if ptr[c[i]] < ptr[c[i] + 1] and _find(uf, i) == root:
                members[nm] = i
                nm += 1
        if not _solve_group(E, c, members, nm, best, nd, ptr, cols, mark, out):
            ok = False
    return ok


_start_one = jit(_start_one)


def _starts_kernel(E: np.ndarray, hyp: np.ndarray, n_surv: int, n_births: int, cand: np.ndarray,
                   start: np.ndarray, ok: np.ndarray) -> None:  # pragma: no cover - compiled
    """Candidate sets (survivors of each parent, then every birth; -1 padded) and optimal
    starts of all parents."""
    H, w = hyp.shape
    best, nd, ptr, cols = _row_options(E)
    M = E.shape[1] - _DET
    owner = np.full(M, -1, dtype=np.int64)
    mark = np.zeros(M, dtype=np.int64)
    for h in range(H):
        n = np.int64(0)  # not 0: a literal start compiles _start_one again for Literal[int](0)
        for i in range(w):
            if hyp[h, i] >= 0:
                cand[h, n] = hyp[h, i]
                n += 1
        for b in range(n_births):
            cand[h, n] = n_surv + b
            n += 1
        for i in range(n, cand.shape[1]):
            cand[h, i] = -1
            start[h, i] = -1
        ok[h] = _start_one(E, cand[h], n, start[h], best, nd, ptr, cols, owner, mark)


_starts_kernel = jit(_starts_kernel)


def starts(E: np.ndarray, hyp_tracks: np.ndarray, n_survivors: int, n_births: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(cand, start, ok)``: :func:`~tracker.glmb.hypotheses.candidate_sets` and
    :func:`~tracker.glmb.gibbs.start_optimal` of every parent, compiled."""
    H, w = hyp_tracks.shape
    cand = np.empty((H, w + n_births), dtype=np.int64)
    start = np.empty((H, w + n_births), dtype=np.int64)
    ok = np.empty(H, dtype=np.bool_)
    _starts_kernel(np.ascontiguousarray(E, dtype=np.float64), np.ascontiguousarray(hyp_tracks, dtype=np.int64),
                   n_survivors, n_births, cand, start, ok)
    return cand, start, ok
