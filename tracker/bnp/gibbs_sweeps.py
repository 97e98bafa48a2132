"""The assignment sampler's sweeps (:func:`tracker.bnp.gibbs.run_gibbs`), compiled with numba:
one systematic-scan pass of single-site full-conditional draws with its Rao-Blackwellised
tallies (:func:`_site_pass`), and one chain's sweeps, each a site pass followed by the exchange
pass of :mod:`tracker.bnp.swap_moves` (:func:`_sweep_kernel`)."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp.swap_moves import CLUTTER, NEW
from bnptrack.tracker.bnp.swap_moves import own_weight as _own_weight
from bnptrack.tracker.bnp.swap_moves import pass_uniforms as _pass_uniforms
from bnptrack.tracker.bnp.swap_moves import swap_pass as _swap_pass


def _site_pass(c, cnt, st, par, extended, w_clutter, w_newbase, ptr, idx, w_first, w_lik, pop, u_row,
               keep, half, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, own):
    """One systematic-scan sweep of single-site full-conditional draws (mutates ``c``, ``cnt``,
    ``st = [K_new, M_o]`` and, when ``keep``, the Rao-Blackwellised tallies: each visit adds
    its full conditional to ``tally_pair`` (by pair)/``tally_cn``, and to the split-half sums
    ``hs[half]``/``hss[half]`` (squares) used by the R-hat diagnostic when ``half >= 0``) and
    ``own`` (each measurement's :func:`tracker.bnp.swap_moves.own_weight` at its value, for the
    exchange pass)."""
    total_mass, alpha, d, d_bar, use_g = par[0], par[1], par[2], par[3], par[4] > 0.0
    M = c.shape[0]
    nnz = idx.shape[0]
    for m in range(M):
        cur = c[m]
        if cur >= 0:
            cnt[cur] -= 1
        if cur != CLUTTER:
            st[1] -= 1
        if cur == NEW:
            st[0] -= 1
        g = total_mass / (total_mass + st[1]) if use_g else 1.0
        wc = w_clutter[m]
        wn = g * w_newbase[m] * (alpha + d * (d_bar + st[0]))
        total = wc + wn
        n_opt = 0
        for j in range(ptr[m], ptr[m + 1]):
            l = idx[j]
            n = cnt[l]
            if n == 0:
                w = g * w_first[j]
            elif extended:
                w = g * w_lik[j] * (n + pop[l] - d)
            else:
                continue
            if w > 0.0:
                opt_l[n_opt] = l
                opt_w[n_opt] = w
                opt_j[n_opt] = j
                n_opt += 1
                total += w
        x = u_row[m] * total
        if x < wc:
            choice = CLUTTER
            own[m] = wc
        elif x < wc + wn:
            choice = NEW
            own[m] = w_newbase[m]
        else:
            x -= wc + wn
            pick = n_opt - 1  # round-off guard (no option: new)
            for i in range(n_opt):
                if x < opt_w[i]:
                    pick = i
                    break
                x -= opt_w[i]
            if pick >= 0:
                choice = opt_l[pick]
                own[m] = w_first[opt_j[pick]]
            else:
                choice = NEW
                own[m] = w_newbase[m]
        if keep:
            inv = 1.0 / total
            tally_cn[0, m] += wc * inv
            tally_cn[1, m] += wn * inv
            for i in range(n_opt):
                tally_pair[opt_j[i]] += opt_w[i] * inv
            if half >= 0:
                _half_add(hs, hss, half, nnz + m, wc * inv)
                _half_add(hs, hss, half, nnz + M + m, wn * inv)
                for i in range(n_opt):
                    _half_add(hs, hss, half, opt_j[i], opt_w[i] * inv)
        c[m] = choice
        if choice >= 0:
            cnt[choice] += 1
        if choice != CLUTTER:
            st[1] += 1
        if choice == NEW:
            st[0] += 1


def _half_add(hs, hss, h, k, v):
    hs[h, k] += v
    hss[h, k] += v * v


def _sweep_kernel(c, cnt, st, par, extended, w_clutter, w_newbase, ptr, idx, w_first, w_lik, pop, u, rng,
                  pair_a, pair_b, burn_in, h0, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, tables):
    """All sweeps of one chain: a single-site pass on ``u[s]``, then the exchange pass (when
    pairs are given) on one uniform per pair drawn from ``rng`` as the pass starts (so the
    uniforms of one pass are in memory at a time, not those of every sweep; above
    :data:`tracker.bnp.swap_moves.PREDRAWN_PAIRS` pairs one per scored proposal,
    :func:`tracker.bnp.swap_moves.pass_uniforms`).  ``tables``:
    :func:`tracker.bnp.swap_moves.exchange_tables`.

    Sweep ``s >= burn_in`` is kept; the kept sweeps' first and last ``n // 2`` are the
    split-chain halves ``h0`` and ``h0 + 1`` of the R-hat sums (the middle one is dropped when
    ``n`` is odd)."""
    sweeps = u.shape[0]
    kept = sweeps - burn_in
    half_len = kept // 2
    accepted = 0
    own = np.empty(c.shape[0])
    for m in range(c.shape[0]):
        own[m] = _own_weight(m, c[m], w_clutter, w_newbase, ptr, idx, w_first)
    for s in range(sweeps):
        i = s - burn_in
        half = h0 if 0 <= i < half_len else (h0 + 1 if i >= kept - half_len else -1)
        _site_pass(c, cnt, st, par, extended, w_clutter, w_newbase, ptr, idx, w_first, w_lik, pop, u[s],
                   i >= 0, half, tally_pair, tally_cn, hs, hss, opt_l, opt_w, opt_j, own)
        if pair_a.shape[0] > 0:
            accepted += _swap_pass(c, cnt, extended, pair_a, pair_b, w_clutter, w_newbase, ptr, idx, w_first,
                                   _pass_uniforms(rng, pair_a.shape[0]), tables, own, rng)
    return accepted


# the helpers are replaced by their compiled versions, which the compiled driver calls
_half_add = jit(_half_add, inline=True)
_site_pass = jit(_site_pass, kernels_only=True)
_sweeps = jit(_sweep_kernel)
