"""The Gibbs sampler's exchange moves (:func:`tracker.bnp.gibbs.run_gibbs`): the pass
(:func:`swap_pass`), each measurement's own factor of the joint (:func:`own_weight`), and which
clusters each measurement's gate holds, one bit per (measurement, cluster) (:func:`gate_bits`).

An exchange of the assignments of measurements ``a`` and ``b`` (``c_a``, ``c_b``) is possible
only when ``c_b`` is in ``a``'s gate and ``c_a`` in ``b``'s (or is clutter / new).  In a dense
scene most proposed exchanges are not: the exchange list holds every pair of measurements that
share a gated cluster (about 20 per measurement at 1,000 objects in vo2017's field), while
each measurement's own assignment is in few of its partners' gates.  Testing one bit rejects
such a proposal without scanning the two measurements' gated pairs; the proposals that pass
are scored as before, with the current assignments' factors kept per measurement (``own``)
instead of looked up again, so every draw, acceptance and tally is the same.

The exchange list (:func:`exchange_pairs`) pairs the measurements of each cluster's gate.  A
gate that holds a large share of the frame (a track lost near the sensor, a new cluster's
broad prior) would give O(M^2) pairs alone (one gate of 2,920 measurements gave 4.26 million
at 3,000 objects in vo2017's field), so a cluster pairs at most :data:`PAIR_MEMBERS` of its measurements, those
of highest ``log_first`` (the likeliest to take it); the others still reach it by single-site
moves.  Below the bound the list is every pair sharing a cluster, unchanged.

The table has ``M x ceil(N / 8)`` bytes; above :data:`MAX_BYTES` (a scene of tens of thousands
of measurements and objects) none is built and every proposal is scored by the scan.
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit

#: The sampler's assignment codes besides a cluster's index (:mod:`tracker.bnp.gibbs` exports them).
CLUTTER = -1
NEW = -2

#: Largest bit table built (bytes); larger problems score every proposal (the same result).
MAX_BYTES = 64 << 20

#: Most measurements of one cluster's gate that pair up through it (its most likely ones).
PAIR_MEMBERS = 256


def _members(ptr, idx, log_first, N, max_members):
    """Each cluster's members, CSR by cluster (``meas_of[first[l]:end[l]]``, ascending): its
    gate's measurements, or, when the gate holds more than ``max_members``, the
    ``max_members`` of highest ``log_first`` (ties: the lower index); ``member[j]`` whether
    pair ``j`` is one."""
    M = ptr.shape[0] - 1
    size = np.zeros(N, dtype=np.int64)
    for j in range(idx.shape[0]):
        size[idx[j]] += 1
    first = np.zeros(N + 1, dtype=np.int64)
    for l in range(N):
        first[l + 1] = first[l] + size[l]
    meas_of = np.empty(idx.shape[0], dtype=np.int64)
    pos_of = np.empty(idx.shape[0], dtype=np.int64)
    end = first[:N].copy()
    for m in range(M):  # measurements ascending within each cluster
        for j in range(ptr[m], ptr[m + 1]):
            meas_of[end[idx[j]]] = m
            pos_of[end[idx[j]]] = j
            end[idx[j]] += 1
    member = np.ones(idx.shape[0], dtype=np.bool_)
    for l in range(N):
        if size[l] > max_members:
            lo = first[l]
            order = np.argsort(-log_first[pos_of[lo:lo + size[l]]], kind="mergesort")
            for i in range(max_members, size[l]):
                member[pos_of[lo + order[i]]] = False
            kept = np.sort(meas_of[lo + order[:max_members]])
            for i in range(max_members):
                meas_of[lo + i] = kept[i]
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
                part = np.sort(row[:n])
                for i in range(n):
                    pair_a[out + i] = a
                    pair_b[out + i] = part[i]
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


def swap_pass(c, cnt, extended, pair_a, pair_b, w_clutter, w_newbase, ptr, idx, w_first, u_row, bits, own):
    r"""Metropolis-Hastings exchange of two measurements' assignments, for every pair that
    shares a candidate cluster (a fixed list; each exchange is its own inverse, so the
    proposal is symmetric).  An exchange keeps every count (:math:`M_o`, :math:`K_\text{new}`,
    cluster sizes), so the joint ratio is the product of the two measurements' own factors.
    In extended mode clusters holding several measurements are left alone.  ``bits``
    (:func:`gate_bits`, or empty) rejects an exchange that would put a
    measurement on a cluster outside its gate before it is scored; ``own`` holds each
    measurement's factor at its current value (kept up to date).  Returns the number of
    accepted exchanges."""
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
        new = wa * wb
        if new <= 0.0:
            continue
        old = own[a] * own[b]
        if u_row[p] * old < new:
            c[a] = cb
            c[b] = ca
            own[a] = wa
            own[b] = wb
            accepted += 1
    return accepted


_members = jit(_members)
exchange_pairs = jit(exchange_pairs)  # noqa: F811
gate_bits = jit(gate_bits)  # noqa: F811
gated = jit(gated, inline=True)  # noqa: F811
own_weight = jit(own_weight)  # noqa: F811
swap_pass = jit(swap_pass)  # noqa: F811
