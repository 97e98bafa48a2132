r"""The object -> cluster Gibbs kernel of the two-level tracker with O(candidate tables) moves
(:func:`gated_kernel`).

It draws exactly what the full scan (:func:`tracker.bnp.group_scan._partition_kernel` followed by
:func:`tracker.bnp.group_scan._collect_shares`) draws, bit for bit, with three changes to the work
per move (object :math:`\ell` leaves its table, then joins one drawn from its conditional, eq.
(14) [Gibbs]):

* **Urn state kept incrementally.**  The number :math:`K` of occupied tables (the new table's
  weight :math:`\alpha + dK`, eqs. (5), (19)) changes only for the two tables a move touches; the
  one "new table" option is the lowest free slot, kept in a min-heap of the free slots.  The
  full scan recounted both over all T = G + L slots per move.
* **Gate by a bound (a spatial index).**  The conditional of table :math:`t` is
  :math:`\log w_t = \log u_t + \sum_p \log \mathcal N(v_{p\ell}; \hat\theta_{pt}, C_{pt} + R_{p\ell})`
  (urn weight :math:`u_t`, blocks :math:`p`: velocity, centroid).  With :math:`C_{pt} \succeq 0`,
  :math:`\det(C + R) \ge \det R` and :math:`r'(C + R)^{-1} r \ge |r|^2 / (\lambda_{\max}(C) + \lambda_{\max}(R))`,
  so on the indexed block q (the centroid when present, else the velocity)

  .. math:: \log w_t \le U + c_\ell - \tfrac12 |v_{q\ell} - \hat\theta_{qt}|^2 / (\Lambda + \rho_\ell),

  :math:`U` an upper bound of every urn weight's log,
  :math:`c_\ell = \sum_p (-\tfrac12 \log\det R_{p\ell} - \log 2\pi)`,
  :math:`\rho_\ell = \lambda_{\max}(R_{q\ell})`, :math:`\Lambda \ge \lambda_{\max}(C_{qt})` for every
  table in the grid (tables above it are "wide" and always scored).  A table whose bound is more
  than :data:`MARGIN` = 50 nats below an option already scored (the new table, the table the
  object left) weighs less than :math:`e^{-50} \approx 2 \cdot 10^{-22}` of that option, and
  the T tables skipped in a move less than :math:`T \cdot 2 \cdot 10^{-22}` of the move's total
  (:math:`10^{-18}` at T = 5,000), under a hundredth of a double's rounding unit: a skip can
  move a sum's last bit only in the rare sum that lies that close to a rounding boundary, and a
  draw only when its uniform does.  (A 760-nat margin, where ``exp`` underflows to exactly 0.0,
  changes no bit, but in a dense scene it spans the whole field: at 1,000 objects in vo2017's
  2 km field it scored 153 of 323 tables per move, against 16 at 50 nats.)  The tables within the bound's radius are found in a uniform grid
  over the tables' current :math:`\hat\theta_q` (cell lists; a table moves cell when a move changes
  its members).  Each table the grid returns is then tested once more before it is scored, with the exact
  quadratic form of block q in place of its eigenvalue bound
  (:math:`\log w_t \le u_t + c_\ell - \tfrac12 r'(C_{qt} + R_{q\ell})^{-1} r`, :func:`_score_candidates`;
  one division, no logarithm) against the best option scored so far (a third of
  the tables the grid returns at 1,000 objects, whose full score costs two logarithms).
* **Sparse records.**  The last sweep keeps only the options with conditional above ``min_p``
  (what :func:`~tracker.bnp.group_scan._collect_shares` keeps of the dense (L, T) arrays), in the
  same order, normalised the same way: O(L x few) memory instead of O(L x T).

The candidates are scored and summed in table order, as the full scan sums them.  ``gate``
False scores every occupied table (the urn part alone, for the ablation).
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp.group_bundles import Candidates, Gate, Grid, Members, Records, Sums, Tables
from bnptrack.tracker.bnp.group_fma import fma, gemv2, sum2
from bnptrack.tracker.bnp.group_grid import (CAP_FACTOR, MARGIN, _cell_ij, _grid_geometry, _heap_pop, _heap_push,
                                           _place, _unplace, median)


def _inv_into(A, out) -> float:
    """2x2 inverse of ``A`` into ``out``; returns det(A)."""
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    out[0, 0], out[1, 1] = A[1, 1] / det, A[0, 0] / det
    out[0, 1], out[1, 0] = -A[0, 1] / det, -A[1, 0] / det
    return det


def _move(lam, eta, n, lam0, eta0, Ri, Riv, t, l, sign) -> None:
    n[t] += sign
    for p in range(lam.shape[0]):  # entry by entry: array (slice) assignments compile numba's string code
        for i in range(2):
            if n[t] == 0:  # exact reset: no round-off drift
                eta[p, t, i] = eta0[p, t, i]
                for j in range(2):
                    lam[p, t, i, j] = lam0[p, t, i, j]
            else:
                eta[p, t, i] += sign * Riv[p, l, i]
                for j in range(2):
                    lam[p, t, i, j] += sign * Ri[p, l, i, j]


def lmax2(A) -> float:
    """Largest eigenvalue of the symmetric 2x2 ``A`` (of its symmetric part)."""
    h = 0.5 * (A[0, 0] - A[1, 1])
    b = 0.5 * (A[0, 1] + A[1, 0])
    return 0.5 * (A[0, 0] + A[1, 1]) + np.sqrt(h * h + b * b)




def _refresh(lam, eta, t, t_mu, t_cov, cov, t_lm) -> None:
    """Table ``t``'s theta posterior per block (``cov = lam^-1``, ``mu = cov eta``), as the full scan
    computes it; ``t_lm[t]``: the largest eigenvalue of the last block's covariance."""
    for p in range(lam.shape[0]):
        _inv_into(lam[p, t], cov)
        gemv2(cov, eta[p, t], t_mu[p, t])  # = cov @ eta, into place
        for i in range(2):  # not t_cov[p, t] = cov: a slice assignment compiles numba's string code
            for j in range(2):
                t_cov[p, t, i, j] = cov[i, j]
    t_lm[t] = lmax2(cov)


def _urn_of(t, n, v_star, urn) -> float:
    """Log urn weight of the occupied table ``t`` (:func:`~tracker.bnp.group_sample.urn_log_weights`;
    ``urn``: :class:`~tracker.bnp.group_bundles.Urn`); it changes only when ``n[t]`` does."""
    return np.log(v_star[t]) if urn.occupied and n[t] == 0 else np.log(n[t] + v_star[t] - urn.d)


def _block_term(r0, r1, a, b, e, f, log2pi) -> float:
    """One block's term of a score: ``-r' A^-1 r / 2 - log det(A) / 2 - log 2 pi`` for
    ``A = [[a, b], [e, f]]`` (``C + R``) and ``r = (r0, r1)`` (``v - mu``), with the operations of
    :func:`_inv_into`, :func:`~tracker.bnp.group_fma.gemv2` and :func:`~tracker.bnp.group_fma.dot2`
    in their order, on scalars: the same double, and no array passed (a compiled helper taking
    arrays costs a reference count per array and call)."""
    det = a * f - b * e
    s00, s01, s10, s11 = f / det, -b / det, -e / det, a / det
    y0 = fma(s00, r0, s01 * r1) + 0.0
    y1 = fma(s10, r0, s11 * r1) + 0.0
    return -0.5 * sum2(r0, y0, r1, y1) - 0.5 * np.log(det) - log2pi


def _score(t, l, urn, mem, tab, log2pi) -> float:
    """Log weight of object ``l`` at table ``t`` given its log urn weight ``urn``: plus each block's
    predictive (:func:`_block_term`), as the full scan adds them (``log2pi`` = ``np.log(2.0 * np.pi)``;
    ``mem``, ``tab``: :class:`~tracker.bnp.group_bundles.Members`, :class:`~tracker.bnp.group_bundles.Tables`)."""
    v, R, t_mu, t_cov = mem.v, mem.R, tab.mu, tab.cov
    out = urn
    for p in range(v.shape[0]):
        out += _block_term(v[p, l, 0] - t_mu[p, t, 0], v[p, l, 1] - t_mu[p, t, 1], t_cov[p, t, 0, 0] + R[p, l, 0, 0],
                           t_cov[p, t, 0, 1] + R[p, l, 0, 1], t_cov[p, t, 1, 0] + R[p, l, 1, 0],
                           t_cov[p, t, 1, 1] + R[p, l, 1, 1], log2pi)
    return out


def _score_candidates(l, m0, m, top, mem, tab, cands, gate) -> int:
    r"""Score the gathered tables ``cands.cand[m0:m]`` in order (:func:`_score`), except (``gate.on``)
    those excluded by the exact quadratic form of the indexed block ``q``: with the other terms bounded
    (module docstring: :math:`\det(C + R) \ge \det R`, the other blocks' quadratic forms >= 0),
    :math:`\log w_t \le u_t + c_\ell - \tfrac12 r'(C_{qt} + R_{q\ell})^{-1} r`; a table whose bound
    is more than :data:`MARGIN` below the best option scored so far (``top`` to start with) weighs
    exactly 0.0 after the draw's ``exp``, as for the grid's gate.  One division and no logarithm per
    test; a non-positive or non-finite determinant never excludes.  The scored tables are kept in
    ``cand[m0:]`` in order; returns their new end."""
    q, v, R, c, t_mu, t_cov, urn = gate.q, mem.v, mem.R, mem.c[l], tab.mu, tab.cov, tab.urn
    cand, logw = cands.cand, cands.logw
    kept = m0
    for k in range(m0, m):
        t = cand[k]
        if gate.on:
            r0, r1 = v[q, l, 0] - t_mu[q, t, 0], v[q, l, 1] - t_mu[q, t, 1]
            a, b = t_cov[q, t, 0, 0] + R[q, l, 0, 0], t_cov[q, t, 0, 1] + R[q, l, 0, 1]
            e, f = t_cov[q, t, 1, 0] + R[q, l, 1, 0], t_cov[q, t, 1, 1] + R[q, l, 1, 1]
            det = a * f - b * e
            if det > 0.0 and urn[t] + c - 0.5 * (f * r0 * r0 - (b + e) * r0 * r1 + a * r1 * r1) / det < top - MARGIN:
                continue
        out = urn[t]  # _score's sum, written out: an inlined helper would count references per table
        for p in range(v.shape[0]):
            out += _block_term(v[p, l, 0] - t_mu[p, t, 0], v[p, l, 1] - t_mu[p, t, 1],
                               t_cov[p, t, 0, 0] + R[p, l, 0, 0], t_cov[p, t, 0, 1] + R[p, l, 0, 1],
                               t_cov[p, t, 1, 0] + R[p, l, 1, 0], t_cov[p, t, 1, 1] + R[p, l, 1, 1], gate.log2pi)
        logw[t] = out
        top = max(top, logw[t])
        cand[kept] = t
        kept += 1
    return kept


def _insertion_sort(a, m) -> None:
    for i in range(1, m):
        x = a[i]
        j = i - 1
        while j >= 0 and a[j] > x:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = x


def _draw_list(cand, m, logw, w, u) -> int:
    """:func:`~tracker.bnp.group_scan._draw` over the tables ``cand[:m]`` (increasing): the position in
    ``cand`` of the option of uniform ``u``; ``w[t]`` receives the normalised weights.  The other
    tables' weights are exactly 0.0 and add nothing to the sums."""
    top = logw[cand[0]]
    for k in range(1, m):
        if logw[cand[k]] > top:
            top = logw[cand[k]]
    total = 0.0
    for k in range(m):
        t = cand[k]
        w[t] = np.exp(logw[t] - top)
        total += w[t]
    for k in range(m):
        w[cand[k]] = w[cand[k]] / total
    acc = 0.0
    for k in range(m):
        acc += w[cand[k]]
        if acc > u:
            return k
    return m - 1


def _gather(l, top_lb, m, stamp, mem, tab, grid, cands, gate):
    """Append to ``cands.cand[:m]`` every table not yet marked (``mark[t] == stamp``) that the bound
    cannot exclude: the wide tables and the tables in the grid cells within the gate radius of
    ``v[q, l]`` whose own bound (their covariance's largest eigenvalue ``tab.lm``) does not exclude
    them (all live tables when not ``gate.on`` or the point is not finite).  Returns the new count."""
    q, v, rho, c_l, live, t_mu, t_lm, T = gate.q, mem.v, mem.rho[l], mem.c[l], tab.live, tab.mu, tab.lm, tab.live.size
    cap, geo, head, nxt, wide = grid.cap, grid.geo, grid.head, grid.nxt, grid.wide
    cand, mark = cands.cand, cands.mark
    x, y = v[q, l, 0], v[q, l, 1]
    D = max(2.0 * (gate.U + c_l - top_lb + MARGIN), 0.0)
    rad = np.sqrt(D * (cap + rho))
    if not gate.on or not (np.isfinite(x) and np.isfinite(y) and np.isfinite(rad)):
        for t in range(T):
            if live[t] and mark[t] != stamp:
                mark[t] = stamp
                cand[m] = t
                m += 1
        return m
    i0, j0 = _cell_ij(x - rad, y - rad, geo)
    i1, j1 = _cell_ij(x + rad, y + rad, geo)
    ny = int(geo[4])
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            t = head[i * ny + j]
            while t >= 0:
                dx, dy = x - t_mu[q, t, 0], y - t_mu[q, t, 1]
                if mark[t] != stamp and dx * dx + dy * dy <= D * (t_lm[t] + rho):
                    mark[t] = stamp
                    cand[m] = t
                    m += 1
                t = nxt[t]
    for k in range(grid.n_wide[0]):
        t = wide[k]
        if mark[t] != stamp:
            mark[t] = stamp
            cand[m] = t
            m += 1
    return m


def _record(l, t, wt, sums, h_lam, h_eta, recs, B, e):
    """The option (``l``, ``t``) of weight ``wt`` appended to the records ``recs`` (``recs.count[0]``
    their count, arrays grown by doubling; :class:`~tracker.bnp.group_bundles.Records`): part 0's
    theta given the table's other current members (``sums``: :class:`~tracker.bnp.group_bundles.Sums`)
    and H_2 (``h_lam``, ``h_eta``).  Returns the records (new ones when grown)."""
    k = recs.count[0]
    if k == recs.obj.size:
        cap = 2 * k + 16
        o2, w2, m2, c2 = np.empty(cap, dtype=np.int64), np.empty(cap), np.empty((cap, 2)), np.empty((cap, 2, 2))
        for i in range(k):  # entry by entry: a slice assignment compiles numba's string code
            o2[i], w2[i] = recs.obj[i], recs.w[i]
            for a in range(2):
                m2[i, a] = recs.mu[i, a]
                for b in range(2):
                    c2[i, a, b] = recs.cov[i, a, b]
        recs = Records(recs.count, o2, w2, m2, c2)
    for i in range(2):  # lam - lam0 + h_lam, eta - eta0 + h_eta entry by entry
        e[i] = sums.eta[0, t, i] - sums.eta0[0, t, i] + h_eta[i]
        for j in range(2):
            B[i, j] = sums.lam[0, t, i, j] - sums.lam0[0, t, i, j] + h_lam[i, j]
    _inv_into(B, recs.cov[k])
    gemv2(recs.cov[k], e, recs.mu[k])
    recs.obj[k], recs.w[k] = l, wt
    recs.count[0] = k + 1
    return recs


def _normalise_records(rec_obj, rec_w, count) -> None:
    """Each object's recorded weights over their sum (in record order from 0.0)."""
    first = 0
    while first < count:
        last, total = first, 0.0
        while last < count and rec_obj[last] == rec_obj[first]:
            total += rec_w[last]
            last += 1
        for k in range(first, last):
            rec_w[k] = rec_w[k] / total
        first = last


def _setup(v, R, lam0, eta0, v_star, z):
    """The tables' information sums with the start ``z`` seated, each member's ``R^-1`` and
    ``R^-1 v``, and every table's theta posterior."""
    P, L, T = v.shape[0], v.shape[1], lam0.shape[1]
    n = np.zeros(T)
    lam, eta = lam0.copy(), eta0.copy()
    Ri, Riv = np.empty((P, L, 2, 2)), np.empty((P, L, 2))
    for p in range(P):
        for l in range(L):
            _inv_into(R[p, l], Ri[p, l])
            gemv2(Ri[p, l], v[p, l], Riv[p, l])  # = Ri @ v (BLAS's rounding: group_fma)
    for l in range(L):
        _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, 1.0)
    t_cov, t_mu, cov, t_lm = np.empty((P, T, 2, 2)), np.empty((P, T, 2)), np.empty((2, 2)), np.empty(T)
    for t in range(T):
        _refresh(lam, eta, t, t_mu, t_cov, cov, t_lm)
    return n, lam, eta, Ri, Riv, t_cov, t_mu, t_lm


def _bound_terms(v, R, q):
    """Per object: ``c_l`` = sum over blocks of -log det(R)/2 - log 2 pi, and ``rho_l`` = the
    largest eigenvalue of its indexed block's R."""
    P, L = v.shape[0], v.shape[1]
    c, rho = np.zeros(L), np.empty(L)
    for l in range(L):
        for p in range(P):
            det = R[p, l, 0, 0] * R[p, l, 1, 1] - R[p, l, 0, 1] * R[p, l, 1, 0]
            c[l] += -0.5 * np.log(det) - np.log(2.0 * np.pi)
        rho[l] = lmax2(R[q, l])
    return c, rho


def _cap_of(t_cov, live, rho, q, T):
    """Largest eigenvalue allowed in the grid: the largest of the live tables' and the members'
    (then no table ever leaves the grid: a table's posterior is within each member's R and its
    prior), at most :data:`CAP_FACTOR` times the median of them (larger ones go to the wide list)."""
    arr = np.empty(rho.size + T)
    for i in range(rho.size):  # not arr[:rho.size] = rho: a slice assignment compiles numba's string code
        arr[i] = rho[i]
    k = rho.size
    for t in range(T):
        if live[t]:
            arr[k] = lmax2(t_cov[q, t])
            k += 1
    arr = arr[:k]
    return min(arr.max(), CAP_FACTOR * median(arr)) * (1.0 + 1e-9)


def gated_kernel(sw, urn, gate_on, min_p, stats):
    """Collapsed Gibbs sweeps over ``sw.z`` in place (module docstring); ``sw``, ``urn``
    (:class:`~tracker.bnp.group_bundles.Sweeps`, :class:`~tracker.bnp.group_bundles.Urn`) as
    :func:`~tracker.bnp.group_scan._partition_kernel`'s; ``gate_on`` False scores every live table.
    Returns the last sweep's options with conditional above ``min_p`` as
    :func:`~tracker.bnp.group_scan._collect_shares` does: (obj, w, mu, cov).
    ``stats[0]``, ``stats[1]`` count the moves and the tables scored (added to)."""
    v, R, lam0, eta0, h_lam, h_eta, v_star, z, u = sw
    alpha, d, occupied = urn
    P, L, T = v.shape[0], v.shape[1], lam0.shape[1]
    if L == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2, 2))
    q = P - 1
    n, lam, eta, Ri, Riv, t_cov, t_mu, t_lm = _setup(v, R, lam0, eta0, v_star, z)
    live = (n + v_star) > 0
    heap, counts = np.empty(T, dtype=np.int64), np.zeros(2, dtype=np.int64)  # counts: K, the free slots' heap size
    for t in range(T):
        if live[t]:
            counts[0] += 1 if (n[t] > 0 or not occupied) else 0
        else:
            counts[1] = _heap_push(heap, counts[1], t)
    c_l, rho = _bound_terms(v, R, q)
    cap = _cap_of(t_cov, live, rho, q, T)
    geo = _grid_geometry(v[q], t_mu[q], live, rho, cap, T)
    head = np.full(int(geo[3] * geo[4]), -1, dtype=np.int64)
    cell_of, nxt, prv = np.full(T, -1, dtype=np.int64), np.full(T, -1, dtype=np.int64), np.full(T, -1, dtype=np.int64)
    wide, wide_pos = np.empty(T, dtype=np.int64), np.full(T, -1, dtype=np.int64)
    grid = Grid(geo, cap, head, cell_of, nxt, prv, wide, wide_pos, np.zeros(1, dtype=np.int64))
    mem = Members(v, R, c_l, rho)
    for t in range(T):
        if live[t]:
            _place(t, t_mu[q, t], t_lm[t], grid)
    vmax = 0.0
    for t in range(T):
        vmax = max(vmax, v_star[t])
    gate = Gate(q, gate_on, np.log(L + vmax + alpha + d * T + 1.0), np.log(2.0 * np.pi))
    log_urn = np.zeros(T)
    for t in range(T):
        if live[t]:
            log_urn[t] = _urn_of(t, n, v_star, urn)
    tab = Tables(t_mu, t_cov, t_lm, log_urn, live)
    sums = Sums(n, lam, eta, lam0, eta0)
    cand, mark = np.empty(T, dtype=np.int64), np.full(T, -1, dtype=np.int64)
    logw, w = np.empty(T), np.empty(T)
    cands = Candidates(cand, mark, logw, w)
    cov, B, e = np.empty((2, 2)), np.empty((2, 2)), np.empty(2)
    recs = Records(np.zeros(1, dtype=np.int64), np.empty(4 * L + 16, dtype=np.int64), np.empty(4 * L + 16),
                   np.empty((4 * L + 16, 2)), np.empty((4 * L + 16, 2, 2)))
    S = u.shape[0]
    stamp = 0
    for s in range(S):
        for l in range(L):
            old = z[l]
            _move(lam, eta, n, lam0, eta0, Ri, Riv, old, l, -1.0)
            _refresh(lam, eta, old, t_mu, t_cov, cov, t_lm)
            _unplace(old, grid)
            if n[old] + v_star[old] > 0:
                if occupied and n[old] == 0:
                    counts[0] -= 1
                log_urn[old] = _urn_of(old, n, v_star, urn)
                _place(old, t_mu[q, old], t_lm[old], grid)
            else:
                live[old] = False
                counts[0] -= 1
                counts[1] = _heap_push(heap, counts[1], old)
            stamp += 1
            free = heap[0]
            logw[free] = _score(free, l, np.log(alpha + d * counts[0]), mem, tab, gate.log2pi)
            mark[free], cand[0], m = stamp, free, 1
            top_lb = logw[free]
            if live[old]:
                logw[old] = _score(old, l, log_urn[old], mem, tab, gate.log2pi)
                mark[old], cand[1], m = stamp, old, 2
                top_lb = max(top_lb, logw[old])
            m0 = m
            m = _gather(l, top_lb, m, stamp, mem, tab, grid, cands, gate)
            m = _score_candidates(l, m0, m, top_lb, mem, tab, cands, gate)
            stats[0] += 1
            stats[1] += m
            _insertion_sort(cand, m)
            k = _draw_list(cand, m, logw, w, u[s, l])
            while w[cand[k]] == 0.0:  # never land on an impossible table through round-off
                k -= 1
            new = cand[k]
            if s == S - 1:
                for j in range(m):
                    if w[cand[j]] > min_p:
                        recs = _record(l, cand[j], w[cand[j]], sums, h_lam, h_eta, recs, B, e)
            z[l] = new
            if not live[new]:  # the lowest free slot: a new table
                counts[1] = _heap_pop(heap, counts[1])
                live[new] = True
                counts[0] += 1
            elif occupied and n[new] == 0:
                counts[0] += 1
            _move(lam, eta, n, lam0, eta0, Ri, Riv, new, l, 1.0)
            log_urn[new] = _urn_of(new, n, v_star, urn)
            _refresh(lam, eta, new, t_mu, t_cov, cov, t_lm)
            _unplace(new, grid)
            _place(new, t_mu[q, new], t_lm[new], grid)
    _normalise_records(recs.obj, recs.w, recs.count[0])
    k = recs.count[0]
    return recs.obj[:k].copy(), recs.w[:k].copy(), recs.mu[:k].copy(), recs.cov[:k].copy()


_inv_into = jit(_inv_into, kernels_only=True)
_move = jit(_move, kernels_only=True)
lmax2 = jit(lmax2, inline=True)
_refresh = jit(_refresh, kernels_only=True)
_block_term = jit(_block_term, inline=True)
_score = jit(_score, inline=True)
_urn_of = jit(_urn_of, inline=True)
_insertion_sort = jit(_insertion_sort, inline=True)
_score_candidates = jit(_score_candidates, kernels_only=True)
_draw_list = jit(_draw_list, inline=True)
_gather = jit(_gather, kernels_only=True)
_record = jit(_record, kernels_only=True)
_normalise_records = jit(_normalise_records, kernels_only=True)
_setup = jit(_setup, kernels_only=True)
_bound_terms = jit(_bound_terms, kernels_only=True)
_cap_of = jit(_cap_of, kernels_only=True)
gated_kernel = jit(gated_kernel)
