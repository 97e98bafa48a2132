"""The Gibbs sampler's exchange moves (:func:`tracker.bnp.gibbs.run_gibbs`): the pass
(:func:`swap_pass`, and :func:`swap_scan`, the same pass visiting every pair), each
measurement's own factor of the joint (:func:`own_weight`), the exchange list
(:func:`exchange_pairs`) and what the pass reads to skip the proposals it would reject
(:func:`exchange_tables`: :func:`exchange_lists`, :func:`gates_by_cluster`; :func:`gate_bits`
for the scan).

An exchange of the assignments of measurements ``a`` and ``b`` (``c_a``, ``c_b``) is possible
only when ``c_b`` is in ``a``'s gate and ``c_a`` in ``b``'s (or is clutter / new).  In a dense
scene most proposed exchanges are not: the exchange list holds every pair of measurements that
share a gated cluster (about 20 per measurement at 1,000 objects in vo2017's field, 116 at
3,000), while each measurement's own assignment is in few of its partners' gates.  While
``a`` holds cluster ``l``, only the partners ``b`` whose gate holds ``l`` can take it: the pass
walks those alone, from a list per gated pair ``(a, l)`` (:func:`exchange_lists`; at 3,000
objects about 42,000 of the 340,000 pairs a pass), and finds ``a``'s factor for ``c_b`` in a
cluster-indexed copy of ``a``'s gate.  Every proposal the full scan scores is scored, in the
same order, with the current assignments' factors kept per measurement (``own``), so every
draw, acceptance and tally is the same.  Above :data:`PREDRAWN_PAIRS` pairs (or
:data:`MAX_BYTES` of lists) no list is built: the pass walks cluster ``l``'s gate itself, its
measurements ascending, which are the same partners in the same order (a gate of at most
:data:`PAIR_MEMBERS` pairs all its measurements; in a larger one each partner is looked up in
``a``'s pairs).  At 3,000 objects the lists would hold 3.4 million rows (40 MB, 65 ms to build
a frame) and the walk reads the gates, about 100,000 entries.

A pass draws one uniform per pair of the list as it starts; above :data:`PREDRAWN_PAIRS` pairs
(8,192: more than ten times the paper's scenes, hundreds; a few hundred objects in one radar's
field) it draws one per scored proposal instead (:func:`pass_uniforms`): the same Markov kernel
on another random stream, which saves drawing about ten uniforms per scored proposal at 1,000
and 3,000 objects in one radar's field.

The exchange list (:func:`exchange_pairs`) pairs the measurements of each cluster's gate.  A
gate that holds a large share of the frame (a track lost near the sensor, a new cluster's
broad prior) would give O(M^2) pairs alone (one gate of 2,920 measurements gave 4.26 million
at 3,000 objects in vo2017's field), so a cluster pairs at most :data:`PAIR_MEMBERS` of its measurements, those
of highest ``log_first`` (the likeliest to take it); the others still reach it by single-site
moves.  Below the bound the list is every pair sharing a cluster, unchanged.
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import argsort_stable, jit

#: The sampler's assignment codes besides a cluster's index (:mod:`tracker.bnp.gibbs` exports them).
CLUTTER = -1
NEW = -2

#: Largest exchange lists built (bytes); larger ones are not built and the pass walks the gates
#: (the same moves).
MAX_BYTES = 64 << 20

#: Most measurements of one cluster's gate that pair up through it (its most likely ones).
PAIR_MEMBERS = 256

#: Exchange lists up to this many pairs draw one uniform per pair as each pass starts; longer
#: ones draw one per scored proposal (:func:`pass_uniforms`).
PREDRAWN_PAIRS = 1 << 13


def pass_uniforms(rng, n_pairs):
    """The uniforms of one exchange pass: one per pair (``n_pairs <= PREDRAWN_PAIRS``), or none,
    and the pass draws one from ``rng`` for each proposal it scores.  Either way each scored
    proposal meets a fresh uniform, so the pass is the same Markov kernel; only the stream
    differs.  A list of 340,000 pairs (3,000 objects in one radar's field) scores about one
    proposal in ten."""
    if n_pairs <= PREDRAWN_PAIRS:
        return rng.random(n_pairs)
    return np.zeros(0)


def _members(ptr, idx, log_first, N, max_members):
    """Each cluster's members, CSR by cluster (``meas_of[first[l]:end[l]]``, ascending): its
    gate's measurements, or, when the gate holds more than ``max_members``, the
    ``max_members`` of highest ``log_first`` (ties: the lower index); ``member[j]`` whether
    pair ``j`` is one."""
    first, meas_of, pos_of = gates_by_cluster(ptr, idx, N)  # measurements ascending within each cluster
    end = first[1:].copy()
    member = np.ones(idx.shape[0], dtype=np.bool_)
    for l in range(N):
        size = first[l + 1] - first[l]
        if size > max_members:
            lo = first[l]
            order = argsort_stable(-log_first[pos_of[lo:lo + size]])
            for i in range(max_members, size):
                member[pos_of[lo + order[i]]] = False
            kept = meas_of[lo + order[:max_members]]
            ascending = argsort_stable(kept)
            for i in range(max_members):
                meas_of[lo + i] = kept[ascending[i]]
            end[l] = lo + max_members
    return first, end, meas_of, member


def exchange_pairs(ptr, idx, log_first, N, max_members):
    """The exchange list: every pair ``a < b`` of measurements that are both members
    (:func:`_members`) of one cluster, sorted by ``(a, b)``.

    Measurement by measurement: ``a``'s partners are the later members of each cluster it is a
    member of (``cursor[l]`` is ``a``'s place in cluster ``l``), marked once (``stamp``) and
    sorted; one pass counts, the second fills."""
    M = ptr.shape[0] - 1
    first, end, meas_of, member = _members(ptr, idx, log_first, N, max_members)
    stamp = np.full(M, -1, dtype=np.int64)
    row = np.empty(M, dtype=np.int64)
    pair_a, pair_b = np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    for fill_pass in range(2):
        cursor = first[:N].copy()
        stamp[:] = -1
        out = np.int64(0)
        for a in range(M):
            n = 0
            for j in range(ptr[a], ptr[a + 1]):
                if not member[j]:
                    continue
                l = idx[j]
                cursor[l] += 1  # now past a
                for q in range(cursor[l], end[l]):
                    b = meas_of[q]
                    if stamp[b] != a:
                        stamp[b] = a
                        row[n] = b
                        n += 1
            if fill_pass == 1:
                part = argsort_stable(row[:n])
                for i in range(n):
                    pair_a[out + i] = a
                    pair_b[out + i] = row[part[i]]
            out += n
        if fill_pass == 0:
            pair_a, pair_b = np.empty(out, dtype=np.int64), np.empty(out, dtype=np.int64)
    return pair_a, pair_b


def gate_bits(ptr, idx, N, max_bytes):
    """``(M, ceil(N / 8))`` uint8: bit ``l % 8`` of byte ``[m, l // 8]`` is set when cluster ``l``
    is in measurement ``m``'s gate (the CSR pairs ``ptr``, ``idx``); ``(0, 0)`` when that
    would exceed ``max_bytes`` or there is no cluster."""
    M = ptr.shape[0] - 1
    W = (N + 7) // 8
    if N == 0 or M * W > max_bytes:
        return np.zeros((0, 0), dtype=np.uint8)
    bits = np.zeros((M, W), dtype=np.uint8)
    for m in range(M):
        for j in range(ptr[m], ptr[m + 1]):
            l = idx[j]
            bits[m, l >> 3] |= np.uint8(1 << (l & 7))
    return bits


def gated(bits, m, l):
    """Whether cluster ``l >= 0`` is in measurement ``m``'s gate (:func:`gate_bits`' table)."""
    return (bits[m, l >> 3] >> (l & 7)) & 1 != 0


def own_weight(m, ch, w_clutter, w_newbase, ptr, idx, w_first):
    """Measurement ``m``'s own factor of the joint for value ``ch`` (scaled like the sweeps):
    clutter ``lambda_c kappa``, new ``u_H`` (the urn factors of a swap cancel), or the D2/P2
    weight of a cluster holding only ``m`` (0 when gated out)."""
    if ch == CLUTTER:
        return w_clutter[m]
    if ch == NEW:
        return w_newbase[m]
    for j in range(ptr[m], ptr[m + 1]):
        if idx[j] == ch:
            return w_first[j]
    return 0.0


def gates_by_cluster(ptr, idx, N):
    """Every cluster's full gate, CSR by cluster: the measurements ``meas_of[first[l]:first[l +
    1]]`` (ascending) that gate cluster ``l``, with the places ``pos_of`` of those pairs in the
    CSR gates ``ptr``, ``idx``."""
    M = ptr.shape[0] - 1
    first = np.zeros(N + 1, dtype=np.int64)
    for j in range(idx.shape[0]):
        first[idx[j] + 1] += 1
    for l in range(N):
        first[l + 1] += first[l]
    meas_of = np.empty(idx.shape[0], dtype=np.int64)
    pos_of = np.empty(idx.shape[0], dtype=np.int64)
    end = first[:N].copy()
    for m in range(M):
        for j in range(ptr[m], ptr[m + 1]):
            meas_of[end[idx[j]]] = m
            pos_of[end[idx[j]]] = j
            end[idx[j]] += 1
    return first, meas_of, pos_of


def _pair_rows(M, pair_a):
    """Where each measurement's pairs begin in the exchange list (``(M + 1,)``)."""
    row = np.zeros(M + 1, dtype=np.int64)
    for p in range(pair_a.shape[0]):
        row[pair_a[p] + 1] += 1
    for m in range(M):
        row[m + 1] += row[m]
    return row


def exchange_lists(ptr, idx, N, pair_a, pair_b, max_entries):
    """Each gated pair's exchange partners, for :func:`swap_pass`: for pair ``j`` of the CSR
    gates (measurement ``a``, cluster ``l``), the rows ``ent[lptr[j]:lptr[j + 1]]`` are the
    pairs ``(a, b)`` of the exchange list whose ``b > a`` holds ``l`` in its gate, ``b``
    ascending: ``[place in the exchange list, b, place of (b, l) in the CSR gates]`` (int32:
    the lists are read once per pass and proposal, so their size is their cost); ``row`` is
    where each measurement's pairs begin in the list (``(M + 1,)``).  ``lptr`` is empty when
    the lists would hold more than ``max_entries`` rows."""
    M = ptr.shape[0] - 1
    row = _pair_rows(M, pair_a)
    first, meas_of, pos_of = gates_by_cluster(ptr, idx, N)
    stamp = np.full(M, -1, dtype=np.int64)
    place = np.zeros(M, dtype=np.int64)
    lptr = np.zeros(idx.shape[0] + 1, dtype=np.int64)
    ent = np.empty((0, 3), dtype=np.int32)
    for fill_pass in range(2):
        cursor = first[:N].copy()
        out = np.int64(0)
        for a in range(M):
            for p in range(row[a], row[a + 1]):
                stamp[pair_b[p]] = a
                place[pair_b[p]] = p
            for j in range(ptr[a], ptr[a + 1]):
                l = idx[j]
                cursor[l] += 1  # now past a
                for q in range(cursor[l], first[l + 1]):
                    b = meas_of[q]
                    if stamp[b] == a:
                        if fill_pass == 1:
                            ent[out, 0] = place[b]
                            ent[out, 1] = b
                            ent[out, 2] = pos_of[q]
                        out += 1
                if fill_pass == 0:
                    lptr[j + 1] = out
            if fill_pass == 0 and out > max_entries:
                return row, np.zeros(0, dtype=np.int64), ent
        if fill_pass == 0:
            ent = np.empty((out, 3), dtype=np.int32)
    return row, lptr, ent


def exchange_tables(ptr, idx, N, pair_a, pair_b, w_first, max_bytes, max_members):
    """What :func:`swap_pass` reads besides the weights: ``(row, lptr, ent, lw, first, meas_of,
    gw, capped, gpos, pos_of)``.  Up to :data:`PREDRAWN_PAIRS` pairs, :func:`exchange_lists` (at most
    ``max_bytes``) with each row's ``w_first`` of ``(b, l)`` (``lw``); else (or above
    ``max_bytes``) ``lptr`` is empty and the pass walks the gates by cluster
    (:func:`gates_by_cluster`; ``gw``: each gated pair's ``w_first`` in that order, read
    in sequence by the walk) instead.  ``capped[l]``: cluster ``l``'s gate holds more than
    ``max_members`` measurements, so two of them may be no pair of the list (``pair_a``,
    ``pair_b`` must hold every pair ``a < b`` that gates a cluster of ``max_members`` or fewer:
    :func:`exchange_pairs` with the same bound; 0 makes no such assumption).  ``pos_of[q]``:
    the CSR place of the gates by cluster's entry ``q``, ``gpos`` its inverse (where each
    gated pair sits in its cluster's gate)."""
    M = ptr.shape[0] - 1
    none, nil = np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int32)
    first, meas_of, pos_of = gates_by_cluster(ptr, idx, N)
    capped = np.empty(N, dtype=np.bool_)
    for l in range(N):
        capped[l] = first[l + 1] - first[l] > max_members
    gw = np.empty(idx.shape[0])
    gpos = np.empty(idx.shape[0], dtype=np.int64)
    for q in range(idx.shape[0]):
        gw[q] = w_first[pos_of[q]]
        gpos[pos_of[q]] = q
    if pair_a.shape[0] == 0 or pair_a.shape[0] > PREDRAWN_PAIRS:
        return _pair_rows(M, pair_a), none, nil, np.zeros(0), first, meas_of, gw, capped, gpos, pos_of
    row, lptr, ent = exchange_lists(ptr, idx, N, pair_a, pair_b, max_bytes // 20)
    lw = np.empty(ent.shape[0])
    for q in range(ent.shape[0]):
        lw[q] = w_first[ent[q, 2]]
    return row, lptr, ent, lw, first, meas_of, gw, capped, gpos, pos_of


def _exchange(p, a, b, ca, cb, wa, wb, c, own, u_row, rng):
    """Proposal ``p``: exchange ``c[a] = ca`` and ``c[b] = cb`` when ``u_row[p]`` (or, when
    ``u_row`` is empty, a uniform drawn from ``rng``) accepts it (``wa``, ``wb``: the two
    measurements' factors after it; 0 rejects).  Whether accepted."""
    new = wa * wb
    if new <= 0.0:
        return False
    u = u_row[p] if u_row.shape[0] > 0 else rng.random()
    if u * (own[a] * own[b]) < new:
        c[a] = cb
        c[b] = ca
        own[a] = wa
        own[b] = wb
        return True
    return False


def swap_scan(c, cnt, extended, pair_a, pair_b, w_clutter, w_newbase, ptr, idx, w_first, u_row, bits, own, rng):
    r"""Metropolis-Hastings exchange of two measurements' assignments, for every pair that
    shares a candidate cluster (a fixed list; each exchange is its own inverse, so the
    proposal is symmetric).  An exchange keeps every count (:math:`M_o`, :math:`K_\text{new}`,
    cluster sizes), so the joint ratio is the product of the two measurements' own factors.
    In extended mode clusters holding several measurements are left alone.  ``bits``
    (:func:`gate_bits`, or empty) rejects an exchange that would put a
    measurement on a cluster outside its gate before it is scored; ``own`` holds each
    measurement's factor at its current value (kept up to date).  Returns the number of
    accepted exchanges.  ``u_row``: one uniform per pair, or empty (:func:`pass_uniforms`:
    ``rng`` gives each scored proposal one).  Every pair is visited: :func:`swap_pass` is the
    same pass visiting fewer."""
    use_bits = bits.shape[0] == c.shape[0]
    accepted = 0
    for p in range(pair_a.shape[0]):
        a = pair_a[p]
        b = pair_b[p]
        ca = c[a]
        cb = c[b]
        if ca == cb:
            continue
        if extended and ((ca >= 0 and cnt[ca] > 1) or (cb >= 0 and cnt[cb] > 1)):
            continue
        if use_bits and ((cb >= 0 and not gated(bits, a, cb)) or (ca >= 0 and not gated(bits, b, ca))):
            continue  # new would be 0: rejected as the scan would
        wa = own_weight(a, cb, w_clutter, w_newbase, ptr, idx, w_first)
        wb = own_weight(b, ca, w_clutter, w_newbase, ptr, idx, w_first)
        if _exchange(p, a, b, ca, cb, wa, wb, c, own, u_row, rng):
            accepted += 1
    return accepted


def _own_place(a, ca, ptr, idx):
    """The place of pair ``(a, ca)`` in the CSR gates, or -1."""
    for j in range(ptr[a], ptr[a + 1]):
        if idx[j] == ca:
            return j
    return -1


def _first_at(ent, lo, hi, cursor):
    """The first ``q`` in ``[lo, hi)`` with ``ent[q, 0] >= cursor`` (ascending there), or ``hi``."""
    while lo < hi:
        mid = (lo + hi) // 2
        if ent[mid, 0] < cursor:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _first_above(v, lo, hi, x):
    """The first ``i`` in ``[lo, hi)`` with ``v[i] > x`` (``v`` ascending there), or ``hi``."""
    while lo < hi:
        mid = (lo + hi) // 2
        if v[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


def swap_pass(c, cnt, extended, pair_a, pair_b, w_clutter, w_newbase, ptr, idx, w_first, u_row, tables, own, rng):
    """:func:`swap_scan`'s pass, move for move, visiting only the proposals that can be accepted
    (``tables``: :func:`exchange_tables`).  The exchange list is sorted by ``(a, b)``; while
    ``a`` holds a cluster ``l``, an exchange with ``b`` needs ``l`` in ``b``'s gate, so only the
    partners ``b`` of ``a`` that gate ``l`` are visited, ascending: from ``a``'s list entry for
    ``l`` (:func:`exchange_lists`), or, without lists, from cluster ``l``'s gate; after an
    accepted exchange ``a``'s value changed and its partners after that ``b`` are visited anew.
    While ``a`` is clutter or new, each of its pairs is visited.

    ``a``'s weights and CSR places sit in cluster-indexed tables while its pairs are visited
    (the gate test and the weight in one load); each measurement's CSR place for its value is
    kept (``jown``), so a gate walk starts next to ``a`` (or the partner it just exchanged
    with) in the gate, not from a search.  One kernel, no helper taking arrays: numba counts a
    reference per array passed, which cost a third of the pass."""
    row, lptr, ent, lw, first, meas_of, gw, capped, gpos, pos_of = tables
    lists, predrawn, M = lptr.shape[0] > 0, u_row.shape[0] > 0, c.shape[0]
    jown = np.empty(M, dtype=np.int64)
    for m in range(M):
        jown[m] = _own_place(m, c[m], ptr, idx) if c[m] >= 0 else -1
    wmap, jmap = np.zeros(cnt.shape[0]), np.zeros(cnt.shape[0], dtype=np.int64)
    accepted = 0
    for a in range(M):
        lo, stop = row[a], row[a + 1]
        if lo == stop:
            continue
        for j in range(ptr[a + 1] - 1, ptr[a] - 1, -1):  # backwards: the first of a repeated cluster wins
            wmap[idx[j]], jmap[idx[j]] = w_first[j], j
        after, after_q = a, -1  # a's partners after ``after`` are visited; after_q: its place in the gate, or -1
        while True:
            ca, j, hit, p, wb, jb = c[a], jown[a], -1, -1, 0.0, -1
            if j < 0 or lists:  # clutter, new or a value off the gate (every pair), or the lists
                cursor = lo if after == a else _first_above(pair_b, lo, stop, after)
                n_visit = stop - cursor if j < 0 else lptr[j + 1] - _first_at(ent, lptr[j], lptr[j + 1], cursor)
                q0 = cursor if j < 0 else lptr[j + 1] - n_visit
            else:  # walk ca's gate from after's place on (found from jown when known)
                q0 = gpos[j] if after == a else after_q
                if q0 < 0:
                    q0 = _first_above(meas_of, first[ca], first[ca + 1], after)
                while q0 < first[ca + 1] and meas_of[q0] <= after:
                    q0 += 1
                n_visit = first[ca + 1] - q0
                lo_p = lo if after == a or not (capped[ca] or predrawn) else _first_above(pair_b, lo, stop, after)
            for q in range(q0, q0 + n_visit):
                b = pair_b[q] if j < 0 else (ent[q, 1] if lists else meas_of[q])
                cb = c[b]
                if cb == ca or (extended and ((ca >= 0 and cnt[ca] > 1) or (cb >= 0 and cnt[cb] > 1))):
                    continue
                wa = wmap[cb] if cb >= 0 else (w_clutter[a] if cb == CLUTTER else w_newbase[a])
                if wa <= 0.0:
                    continue
                if j < 0:
                    p, wb = q, own_weight(b, ca, w_clutter, w_newbase, ptr, idx, w_first)
                    jb = _own_place(b, ca, ptr, idx) if ca >= 0 else -1
                elif lists:
                    p, wb, jb = ent[q, 0], lw[q], ent[q, 2]
                else:
                    wb, jb = gw[q], pos_of[q]
                    if capped[ca] or predrawn:  # (a, b)'s place in the list (none: a capped gate's non-pair)
                        lo_p = _first_above(pair_b, lo_p, stop, b - 1)
                        if lo_p == stop or pair_b[lo_p] != b:
                            continue
                        p = lo_p
                new = wa * wb
                if new <= 0.0:
                    continue
                u = u_row[p] if predrawn else rng.random()
                if u * (own[a] * own[b]) < new:
                    after_q = gpos[jown[b]] if cb >= 0 and jown[b] >= 0 else -1
                    c[a], c[b], own[a], own[b] = cb, ca, wa, wb
                    jown[a], jown[b] = (jmap[cb] if cb >= 0 else -1), jb
                    hit = b
                    break
            if hit < 0:
                break
            accepted += 1
            after = hit
        for j in range(ptr[a], ptr[a + 1]):
            wmap[idx[j]] = 0.0
    return accepted


_members = jit(_members, kernels_only=True)
exchange_pairs = jit(exchange_pairs, kernels_only=True)  # noqa: F811
gate_bits = jit(gate_bits)  # noqa: F811
gated = jit(gated, inline=True)  # noqa: F811
own_weight = jit(own_weight, kernels_only=True)  # noqa: F811
_exchange = jit(_exchange, inline=True)
_own_place = jit(_own_place, inline=True)
pass_uniforms = jit(pass_uniforms, kernels_only=True)  # noqa: F811
_first_at = jit(_first_at, inline=True)
_first_above = jit(_first_above, inline=True)
swap_scan = jit(swap_scan)  # noqa: F811
gates_by_cluster = jit(gates_by_cluster, kernels_only=True)  # noqa: F811
_pair_rows = jit(_pair_rows, kernels_only=True)
exchange_lists = jit(exchange_lists, kernels_only=True)  # noqa: F811
exchange_tables = jit(exchange_tables, kernels_only=True)  # noqa: F811
swap_pass = jit(swap_pass, kernels_only=True)  # noqa: F811
