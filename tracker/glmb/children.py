r"""The GLMB's hypothesis arithmetic of a frame in compiled passes.

In numpy, :meth:`GlmbTracker._children <tracker.glmb.filter.GlmbTracker._children>` would chain
about sixty calls per frame (candidate sets, the greedy start and its clash test, the dense
assignment cost tensor of the hard parents, chain split, per-chain copies, two lexicographic
``unique_rows``, the pair keys and a grouped log-sum-exp).  Here the same arithmetic runs in
numba kernels over plain arrays, one parent (or one sample) at a time, with the same results
bit for bit:

* :func:`starts` -- :func:`~tracker.glmb.hypotheses.candidate_sets` and
  :func:`~tracker.glmb.gibbs.start_optimal`: each row's best option once per frame; a parent
  whose best options clash is split into the connected groups of its gating graph (candidates
  linked by a shared gated measurement) and only the clashing groups are solved by the
  shortest augmenting path assignment of :mod:`tracker.glmb.assignment`, each on its own
  small matrix;
* :func:`children` -- the chains of :func:`~tracker.glmb.gibbs.split_chains`, the sweeps of
  :func:`~tracker.glmb.gibbs.gibbs_chains` on the same uniforms, then the distinct
  ``(parent, assignment)`` samples, their weight :math:`w_h \prod_i \eta_i(\gamma_i)`, their
  sorted pair keys and the merge of identical key sets
  (:func:`~tracker.glmb.hypotheses.merge_children`); :func:`distinct_children` is its second
  half on given samples;
* :func:`pair_table` -- the new track table's pair keys and the hypotheses as its rows.

Sums are taken in numpy's order (:func:`_np_sum`: numpy's pairwise summation; group sums in
``np.bincount``'s order) and ``exp``/``log`` stay in numpy (numba's differ in the last bit),
so the weights equal the numpy reference's to the last bit (test:
``tests/tracker/test_glmb_children.py``).
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.glmb.assignment import _lsap_batch
from bnptrack.tracker.glmb.gibbs import _gibbs_sweeps
from bnptrack.tracker.glmb.hypotheses import _DET, _DIE, _MISS, _Children


def _np_sum(a: np.ndarray, n: int) -> float:  # pragma: no cover - compiled
    """``np.sum(a[:n])`` in numpy's order: a plain loop below 8 terms, eight interleaved
    partial sums up to 128 terms, halves (at a multiple of 8) above (numpy's
    ``pairwise_sum``)."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i]
        return res
    if n <= 128:
        r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
        i = 8
        while i < n - (n % 8):
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _np_sum(a, n2) + _np_sum(a[n2:], n - n2)


_np_sum = jit(_np_sum)


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


def _row_less(A: np.ndarray, a: int, b: int) -> bool:  # pragma: no cover - compiled
    """Row ``a`` of ``A`` before row ``b`` in lexicographic order."""
    for k in range(A.shape[1]):
        if A[a, k] != A[b, k]:
            return A[a, k] < A[b, k]
    return False


_row_less = jit(_row_less)


def _sort_rows(A: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Stable lexicographic order of the rows of ``A`` (bottom-up merge sort; as
    ``np.lexsort(A.T[::-1])``)."""
    n = A.shape[0]
    idx = np.arange(n)
    tmp = np.empty(n, dtype=np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid = min(lo + width, n)
            hi = min(lo + 2 * width, n)
            i, j, k = lo, mid, lo
            while i < mid and j < hi:
                if _row_less(A, idx[j], idx[i]):
                    tmp[k] = idx[j]
                    j += 1
                else:
                    tmp[k] = idx[i]
                    i += 1
                k += 1
            while i < mid:
                tmp[k] = idx[i]
                i += 1
                k += 1
            while j < hi:
                tmp[k] = idx[j]
                j += 1
                k += 1
        idx, tmp = tmp, idx
        width *= 2
    return idx


_sort_rows = jit(_sort_rows)


def _sort_rows_bucketed(A: np.ndarray, n_first: int) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`_sort_rows` for rows whose first entry is in ``0..n_first-1`` and mostly
    distinct (the parent of a sample): a counting sort on it, then an insertion sort of each
    bucket (a parent's few samples)."""
    n = A.shape[0]
    start = np.zeros(n_first + 1, dtype=np.int64)
    for a in range(n):
        start[A[a, 0] + 1] += 1
    for p in range(n_first):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    idx = np.empty(n, dtype=np.int64)
    for a in range(n):
        idx[fill[A[a, 0]]] = a
        fill[A[a, 0]] += 1
    for p in range(n_first):
        for x in range(start[p] + 1, start[p + 1]):
            cur = idx[x]
            y = x - 1
            while y >= start[p] and _row_less(A, cur, idx[y]):
                idx[y + 1] = idx[y]
                y -= 1
            idx[y + 1] = cur
    return idx


_sort_rows_bucketed = jit(_sort_rows_bucketed)


def _distinct_rows(A: np.ndarray, order: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """For rows in sorted ``order``: 1 where a row differs from the one before (``unique_rows``'
    ``new`` mask), as int64."""
    n = order.size
    new = np.zeros(n, dtype=np.int64)
    for t in range(n):
        if t == 0:
            new[t] = 1
            continue
        for k in range(A.shape[1]):
            if A[order[t], k] != A[order[t - 1], k]:
                new[t] = 1
                break
    return new


_distinct_rows = jit(_distinct_rows)


def _sample_rows(samples: np.ndarray, chain_parent: np.ndarray, length: np.ndarray) -> np.ndarray:  # pragma: no cover
    """``[owner | assignment]`` of every Gibbs output row (all starts, then the active prefix
    after each sweep; :func:`~tracker.glmb.gibbs.sample_chains`)."""
    S, width = samples.shape
    A = np.empty((S, width + 1), dtype=np.int64)
    row = 0
    C = chain_parent.size
    s = 0
    while row < S:
        k = C if row < C else 0
        if row >= C:
            for c in range(C):
                if length[c] > s:
                    k += 1
            s += 1
        for c in range(k):
            A[row, 0] = chain_parent[c]
            for i in range(width):
                A[row, 1 + i] = samples[row, i]
            row += 1
    return A


_sample_rows = jit(_sample_rows)


def _weigh_kernel(E: np.ndarray, A: np.ndarray, order: np.ndarray, new: np.ndarray, cand: np.ndarray,
                  cand_rows: np.ndarray, log_w: np.ndarray, n_meas: int):  # pragma: no cover - compiled
    """The distinct ``(parent, assignment)`` rows (``A`` sorted by ``order``, first of each run
    of equal rows): their log weight :math:`\\log w_h + \\sum_i \\log\\eta_i(\\gamma_i)` (numpy's
    summation order) and the sorted pair keys of their existing labels (-1 padded, only the
    rows of finite weight); parent ``p`` has the candidates ``cand[cand_rows[p]]``.  Returns
    ``(keys, finite log weights, number of distinct rows)``."""
    width = cand.shape[1]
    n_u = 0
    for t in range(order.size):
        n_u += new[t]
    lw = np.empty(n_u)
    keys = np.full((n_u, width), -1, dtype=np.int64)
    terms = np.zeros(width)
    n_f = 0
    kw = 0
    for t in range(order.size):
        if new[t] == 0:
            continue
        a = order[t]
        p = A[a, 0]
        cp = cand_rows[p]
        for i in range(width):
            r = cand[cp, i]
            terms[i] = E[r, A[a, 1 + i]] if r >= 0 else 0.0
        v = log_w[p] + _np_sum(terms, width)
        if not np.isfinite(v):
            continue
        lw[n_f] = v
        n = 0
        for i in range(width):
            r = cand[cp, i]
            g = A[a, 1 + i]
            if r >= 0 and g >= _MISS:
                keys[n_f, n] = r * (n_meas + 1) + (g - 1)
                n += 1
        for x in range(1, n):  # insertion sort of the few keys
            key = keys[n_f, x]
            y = x - 1
            while y >= 0 and keys[n_f, y] > key:
                keys[n_f, y + 1] = keys[n_f, y]
                y -= 1
            keys[n_f, y + 1] = key
        kw = max(kw, n)
        n_f += 1
    return keys[:n_f, :kw].copy(), lw[:n_f].copy(), n_u


_weigh_kernel = jit(_weigh_kernel)


def _group_kernel(keys: np.ndarray, order: np.ndarray, new: np.ndarray):  # pragma: no cover - compiled
    """Distinct key rows (lexicographic) and the group of every input row (``unique_rows``)."""
    n = order.size
    inv = np.empty(n, dtype=np.int64)
    g = -1
    for t in range(n):
        g += new[t]
        inv[order[t]] = g
    uniq = np.empty((g + 1, keys.shape[1]), dtype=np.int64)
    for t in range(n):
        if new[t]:
            uniq[inv[order[t]]] = keys[order[t]]
    return uniq, inv


_group_kernel = jit(_group_kernel)


def _split_kernel(n_req: np.ndarray, chain_length: int, cand: np.ndarray, parents: np.ndarray):  # pragma: no cover
    """:func:`~tracker.glmb.gibbs.split_chains` (same chains, same order: a stable sort by
    non-increasing length) and the number of uniforms the sweeps will draw."""
    n_chains = np.empty(n_req.size, dtype=np.int64)
    for p in range(n_req.size):
        n_chains[p] = max(1, -(-(n_req[p] - 1) // chain_length))
    total = 0
    for p in range(n_req.size):
        total += n_chains[p]
    parent = np.empty(total, dtype=np.int64)
    length = np.empty(total, dtype=np.int64)
    k = 0
    max_len = 0
    for p in range(n_req.size):
        sweeps = n_req[p] - 1
        for q in range(n_chains[p]):
            parent[k] = p
            length[k] = sweeps // n_chains[p] + (1 if q < sweeps % n_chains[p] else 0)
            max_len = max(max_len, length[k])
            k += 1
    chain_parent = np.empty(total, dtype=np.int64)
    chain_len = np.empty(total, dtype=np.int64)
    k = 0
    n_draws = 0
    for ln in range(max_len, -1, -1):
        for c in range(total):
            if length[c] == ln:
                chain_parent[k] = parent[c]
                chain_len[k] = ln
                k += 1
                n_valid = 0
                for i in range(cand.shape[1]):
                    if cand[parents[parent[c]], i] >= 0:
                        n_valid += 1
                n_draws += ln * n_valid
    return chain_parent, chain_len, n_draws


_split_kernel = jit(_split_kernel)


def _children_kernel(E: np.ndarray, P: np.ndarray, cand: np.ndarray, start: np.ndarray, parents: np.ndarray,
                     chain_parent: np.ndarray, length: np.ndarray, u: np.ndarray, log_w: np.ndarray):  # pragma: no cover
    """The Gibbs sweeps of every chain (:func:`~tracker.glmb.gibbs._gibbs_kernel`), then the
    distinct ``(parent, assignment)`` samples, their weights and pair keys, and the groups of
    identical key sets (see :func:`children`)."""
    C = length.size
    S = C
    for c in range(C):
        S += length[c]
    samples = np.empty((S, cand.shape[1]), dtype=np.int64)
    chain_rows = np.empty(C, dtype=np.int64)
    for c in range(C):
        chain_rows[c] = parents[chain_parent[c]]
    _gibbs_sweeps(P, cand, start, length, u, samples, chain_rows)
    A = _sample_rows(samples, chain_parent, length)
    order = _sort_rows_bucketed(A, parents.size)
    keys, lw, n_u = _weigh_kernel(E, A, order, _distinct_rows(A, order), cand, parents, log_w, E.shape[1] - _DET)
    if keys.shape[1] == 0:
        return keys[: min(1, keys.shape[0])].copy(), np.zeros(keys.shape[0], dtype=np.int64), lw, n_u
    k_order = _sort_rows(keys)
    uniq, inv = _group_kernel(keys, k_order, _distinct_rows(keys, k_order))
    return uniq, inv, lw, n_u


_children_kernel = jit(_children_kernel)


def children(rng: np.random.Generator, E: np.ndarray, cand: np.ndarray, start: np.ndarray, ok: np.ndarray,
             log_w: np.ndarray, max_hypotheses: int, chain_length: int) -> _Children:
    """The distinct children of every feasible parent (``ok``) of :meth:`GlmbTracker._children`:
    :func:`~tracker.glmb.gibbs.allocate_samples` (numpy: its rounding), the chains of
    :func:`~tracker.glmb.gibbs.split_chains`, the sweeps of
    :func:`~tracker.glmb.gibbs.gibbs_chains` on uniforms drawn from ``rng`` in the same order,
    the distinct samples weighted by :math:`w_h \\prod_i \\eta_i(\\gamma_i)`, zero weights
    dropped, identical pair-key sets merged (weights summed; numpy's ``exp``/``log``).  Same
    output as ``unique_rows`` + ``assignment_log_eta`` +
    :func:`~tracker.glmb.hypotheses.merge_children` on those samples."""
    from bnptrack.tracker.glmb.gibbs import allocate_samples
    from bnptrack.tracker.glmb.hypotheses import group_logsumexp

    parents = np.flatnonzero(ok)
    if parents.size == 0:
        raise RuntimeError("GLMB: no parent hypothesis has a feasible assignment")
    log_w = log_w[parents]
    chain_parent, length, n_draws = _split_kernel(allocate_samples(log_w, max_hypotheses), chain_length,
                                                  cand, parents)
    P = np.exp(E - np.max(E, axis=1, keepdims=True)) if E.size else np.ones_like(E)
    u = rng.random(n_draws)
    uniq, inv, lw, n_u = _children_kernel(E, P, np.ascontiguousarray(cand, dtype=np.int64),
                                          np.ascontiguousarray(start, dtype=np.int64), parents, chain_parent, length, u, log_w)
    return _Children(uniq, group_logsumexp(lw, inv, uniq.shape[0]), n_u)


def distinct_children(E: np.ndarray, samples: np.ndarray, chain_parent: np.ndarray, length: np.ndarray,
                      cand: np.ndarray, log_w: np.ndarray) -> _Children:
    """The children of given Gibbs samples (``samples``, ``chain_parent``, ``length`` as
    :func:`~tracker.glmb.gibbs.gibbs_chains` and :func:`~tracker.glmb.gibbs.split_chains`
    give them; ``cand`` and ``log_w`` of the parents): the second half of :func:`children`."""
    from bnptrack.tracker.glmb.hypotheses import group_logsumexp

    if samples.shape[0] == 0:
        return _Children(np.zeros((0, 0), dtype=np.int64), np.zeros(0), 0)
    A = _sample_rows(samples, chain_parent, length)
    order = _sort_rows_bucketed(A, cand.shape[0])
    keys, lw, n_u = _weigh_kernel(E, A, order, _distinct_rows(A, order), cand, np.arange(cand.shape[0]),
                                  log_w, E.shape[1] - _DET)
    if keys.shape[1] == 0:
        uniq, inv = keys[:1], np.zeros(keys.shape[0], dtype=np.int64)
    else:
        k_order = _sort_rows(keys)
        uniq, inv = _group_kernel(keys, k_order, _distinct_rows(keys, k_order))
    return _Children(uniq, group_logsumexp(lw, inv, uniq.shape[0]), n_u)


def _pair_table_kernel(keys: np.ndarray, n_pairs: int):  # pragma: no cover - compiled
    """Distinct pair keys (increasing) and the hypotheses as indices into them."""
    index = np.full(n_pairs, -1, dtype=np.int64)
    width = 0
    for h in range(keys.shape[0]):
        n = 0
        for i in range(keys.shape[1]):
            if keys[h, i] >= 0:
                index[keys[h, i]] = 0
                n += 1
        width = max(width, n)
    n_used = 0
    for k in range(n_pairs):
        if index[k] == 0:
            index[k] = n_used
            n_used += 1
    used = np.empty(n_used, dtype=np.int64)
    for k in range(n_pairs):
        if index[k] >= 0:
            used[index[k]] = k
    hyp = np.full((keys.shape[0], width), -1, dtype=np.int64)
    for h in range(keys.shape[0]):
        for i in range(width):
            if keys[h, i] >= 0:
                hyp[h, i] = index[keys[h, i]]
    return used, hyp


_pair_table_kernel = jit(_pair_table_kernel)


def pair_table(keys: np.ndarray, n_pairs: int) -> tuple[np.ndarray, np.ndarray]:
    """The kept children's distinct pair keys ``used`` (increasing: the new track table) and
    their hypotheses as rows of it (``np.searchsorted(used, keys)``, -1 padded, trailing
    all-padding columns dropped); keys are ``< n_pairs``."""
    return _pair_table_kernel(np.ascontiguousarray(keys, dtype=np.int64), n_pairs)
