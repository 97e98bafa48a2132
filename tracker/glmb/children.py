r"""The GLMB's hypothesis arithmetic of a frame in compiled passes.

In numpy, :meth:`GlmbTracker._children <tracker.glmb.filter.GlmbTracker._children>` would chain
about sixty calls per frame (candidate sets, the greedy start and its clash test, the dense
assignment cost tensor of the hard parents, chain split, per-chain copies, two lexicographic
``unique_rows``, the pair keys and a grouped log-sum-exp).  Here the same arithmetic runs in
numba kernels over plain arrays, one parent (or one sample) at a time, with the same results
bit for bit:

* :func:`tracker.glmb.starts.starts` -- :func:`~tracker.glmb.hypotheses.candidate_sets` and
  :func:`~tracker.glmb.gibbs.start_optimal` (in :mod:`tracker.glmb.starts`);
* :func:`children` -- the chains of :func:`~tracker.glmb.gibbs.split_chains`, the sweeps of
  :func:`~tracker.glmb.gibbs.gibbs_chains` on the same uniforms, then the distinct
  ``(parent, assignment)`` samples, their weight :math:`w_h \prod_i \eta_i(\gamma_i)`, their
  sorted pair keys and the merge of identical key sets
  (:func:`~tracker.glmb.hypotheses.merge_children`); :func:`distinct_children` is its second
  half on given samples (the rows sorted by :mod:`tracker.glmb.row_sort`);
* :func:`pair_table` -- the new track table's pair keys and the hypotheses as its rows.

Sums are taken in numpy's order (:func:`_np_sum`: numpy's pairwise summation; group sums in
``np.bincount``'s order) and ``exp``/``log`` stay in numpy (numba's differ in the last bit),
so the weights equal the numpy reference's to the last bit (test:
``tests/tracker/test_glmb_children.py``).
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.glmb.gibbs import _gibbs_sweeps
from bnptrack.tracker.glmb.hypotheses import _DET, _MISS, _Children
from bnptrack.tracker.glmb.row_sort import _distinct_rows, _sort_rows, _sort_rows_bucketed


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
