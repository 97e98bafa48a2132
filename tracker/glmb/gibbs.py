"""The GLMB's Gibbs sampler over assignment vectors: sample allocation, chain starts, the
compiled lockstep sweeps (:func:`_gibbs_kernel`) and their vectorised-numpy reference."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.glmb.assignment import _assign
from bnptrack.tracker.glmb.hypotheses import _DET, _DIE, _MISS


def allocate_samples(log_w: np.ndarray, total: int) -> np.ndarray:
    r"""Requested samples per parent: :math:`\max(1, \mathrm{round}(N \sqrt{w_h} /
    \sum_h \sqrt{w_h}))` (the authors' square-root allocation)."""
    s = np.exp(0.5 * (log_w - np.max(log_w)))
    return np.maximum(1, np.round(total * s / s.sum())).astype(np.int64)


def start_optimal(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Optimal assignment of each parent (max sum of log eta, distinct measurements).

    Returns the options ``(H, width)`` (-1 on padding) and a feasibility mask ``(H,)``; a
    parent without any feasible assignment has zero-weight children only.  Where every
    candidate's individually best option uses a different measurement, that is the optimum;
    the other parents are solved by linear assignment (:func:`_assign`).
    """
    valid = cand >= 0
    best = np.argmax(E, axis=1)
    out = np.where(valid, best[np.where(valid, cand, 0)], -1)
    det = np.where(out >= _DET, out, -1 - np.arange(out.shape[1]))  # distinct fillers
    srt = np.sort(det, axis=1)
    clash = np.any(srt[:, 1:] == srt[:, :-1], axis=1)
    ok = np.all(np.isfinite(E[np.where(valid, cand, 0), np.maximum(out, 0)]) | ~valid, axis=1)
    hard = np.flatnonzero(clash | ~ok)
    if hard.size:
        out[hard], ok[hard] = _assign(E, cand[hard])
    return out, ok


def start_missed(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each candidate at its best of dies/missed (Vo's demo starts all missed)."""
    valid = cand >= 0
    Ec = E[np.where(valid, cand, 0)]
    opt = np.where(Ec[..., _MISS] >= Ec[..., _DIE], _MISS, _DIE)
    best = np.take_along_axis(Ec, opt[..., None], axis=-1)[..., 0]
    ok = np.all(np.isfinite(best) | ~valid, axis=1)
    return np.where(valid, opt, -1), ok


def _draw(rng: np.random.Generator, p: np.ndarray) -> np.ndarray:
    """One categorical draw per row of the unnormalised probabilities ``p`` (rows > 0)."""
    cdf = np.cumsum(p, axis=1)
    u = rng.random(p.shape[0]) * cdf[:, -1]
    idx = np.count_nonzero(cdf <= u[:, None], axis=1)
    over = idx >= p.shape[1]  # u rounded up to the total: take the last positive entry
    if np.any(over):
        idx[over] = p.shape[1] - 1 - np.argmax(p[over, ::-1] > 0, axis=1)
    return idx


def _gibbs_kernel(P: np.ndarray, cand: np.ndarray, start: np.ndarray, length: np.ndarray,
                  u: np.ndarray, out: np.ndarray, chain_rows: np.ndarray) -> None:  # pragma: no cover - compiled
    """Lockstep sweeps of :func:`gibbs_chains` on plain arrays (compiled with numba).

    ``u`` holds the uniforms in the order the vectorised sweep consumed them (sweep, slot,
    chain); ``out`` receives all starts, then the active prefix after each sweep.  Each draw
    is ``count(cdf <= u * cdf[-1])`` over the unblocked row of ``P`` (the last positive entry
    when ``u`` rounds up to the total), exactly as :func:`_draw`, computed over the positive
    entries of the row only (gated measurements, dies, missed: a few of the ``M + 2``; adding
    the zero entries, as the dense cdf does, changes no partial sum).  Chain ``c`` uses the
    candidates and start of row ``chain_rows[c]`` of ``cand`` and ``start``.
    """
    C = length.size
    width = cand.shape[1]
    N, K = P.shape
    # the positive entries of each row of P (the options a draw can take), columns increasing
    ptr = np.zeros(N + 1, dtype=np.int64)
    for r in range(N):
        ptr[r + 1] = ptr[r]
        for j in range(K):
            if P[r, j] > 0:
                ptr[r + 1] += 1
    cols = np.empty(ptr[N], dtype=np.int64)
    for r in range(N):
        t = ptr[r]
        for j in range(K):
            if P[r, j] > 0:
                cols[t] = j
                t += 1
    gamma = np.empty((C, width), dtype=np.int64)
    for c in range(C):
        for i in range(width):
            gamma[c, i] = start[chain_rows[c], i]
    taken = np.zeros((C, K), dtype=np.bool_)
    for c in range(C):
        for i in range(width):
            if gamma[c, i] >= 2:
                taken[c, gamma[c, i]] = True
            out[c, i] = gamma[c, i]
    row = C
    pos = 0
    n_sweeps = 0
    for c in range(C):
        if length[c] > n_sweeps:
            n_sweeps = length[c]
    for s in range(n_sweeps):
        k = 0
        for c in range(C):
            if length[c] > s:
                k += 1
        for i in range(width):
            for c in range(k):
                r = cand[chain_rows[c], i]
                if r < 0:
                    continue
                taken[c, gamma[c, i]] = False
                # the cdf over the unblocked positive entries: adding the zero entries, as
                # the dense cdf does, changes no partial sum
                total = 0.0
                for t in range(ptr[r], ptr[r + 1]):
                    if not taken[c, cols[t]]:
                        total += P[r, cols[t]]
                x = u[pos] * total
                pos += 1
                new = -1
                acc = 0.0
                last = -1
                for t in range(ptr[r], ptr[r + 1]):
                    j = cols[t]
                    if taken[c, j]:
                        continue
                    last = j
                    acc += P[r, j]
                    if acc > x:  # the first entry whose cdf exceeds x: count(cdf <= x)
                        new = j
                        break
                if new < 0:  # u rounded up to the total: take the last positive entry
                    new = last
                if new >= 2:
                    taken[c, new] = True
                gamma[c, i] = new
        for c in range(k):
            for i in range(width):
                out[row, i] = gamma[c, i]
            row += 1


_gibbs_sweeps = jit(_gibbs_kernel)


def gibbs_chains(rng: np.random.Generator, E: np.ndarray, cand: np.ndarray,
                 start: np.ndarray, length: np.ndarray) -> np.ndarray:
    r"""Run Gibbs chains in lockstep; returns every visited state ``(S, width)``.

    Chain ``c`` has candidates ``cand[c]`` (-1 padded), starts at ``start[c]`` and makes
    ``length[c]`` sweeps; ``length`` must be non-increasing (active chains are a prefix).
    The output holds all starts, then the active chains' states after each sweep.  One sweep
    updates each candidate ``i`` in turn from (Algorithm 1)

    .. math:: p(\gamma_i = j \mid \gamma_{\bar i}) \propto \eta_i(j)\,
              \big(1 - 1[j > 0,\ j \in \{\gamma_{1:i-1}, \gamma_{i+1:n}\}]\big)

    (distinct measurements; "dies" and "missed" are never blocked).  The sweeps run in
    :func:`_gibbs_kernel` (numba) on uniforms drawn up front from ``rng`` in the order of
    :func:`gibbs_chains_numpy`, which gives identical samples.
    """
    C, width = cand.shape
    length = np.asarray(length, dtype=np.int64)
    if C == 0:
        return np.zeros((0, width), dtype=np.int64)
    P = np.exp(E - np.max(E, axis=1, keepdims=True)) if E.size else np.ones_like(E)
    n_draws = int(np.dot(length, np.count_nonzero(cand >= 0, axis=1)))
    u = rng.random(n_draws)
    out = np.empty((C + int(length.sum()), width), dtype=np.int64)
    _gibbs_sweeps(np.ascontiguousarray(P, dtype=np.float64), np.ascontiguousarray(cand, dtype=np.int64),
                  np.ascontiguousarray(start, dtype=np.int64), length, u, out, np.arange(C))
    return out


def gibbs_chains_numpy(rng: np.random.Generator, E: np.ndarray, cand: np.ndarray,
                       start: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Vectorised-numpy reference of :func:`gibbs_chains` (same samples, slower)."""
    C, width = cand.shape
    # conditionals only involve one row of eta: scale each row by its maximum once
    P = np.exp(E - np.max(E, axis=1, keepdims=True)) if E.size else np.ones_like(E)
    gamma = start.copy()
    taken = np.zeros((C, E.shape[1]), dtype=bool)
    rc, cc = np.nonzero(gamma >= _DET)
    taken[rc, gamma[rc, cc]] = True
    slot_chains = [np.flatnonzero(cand[:, i] >= 0) for i in range(width)]
    samples = [gamma.copy()]
    for s in range(int(length.max(initial=0))):
        k = int(np.count_nonzero(length > s))
        for i in range(width):
            ch = slot_chains[i]
            ch = ch[: np.searchsorted(ch, k)]
            if ch.size == 0:
                continue
            taken[ch, gamma[ch, i]] = False
            new = _draw(rng, P[cand[ch, i]] * ~taken[ch])
            taken[ch, new] = new >= _DET
            gamma[ch, i] = new
        samples.append(gamma[:k].copy())
    return np.concatenate(samples, axis=0)


def split_chains(n_req: np.ndarray, chain_length: int) -> tuple[np.ndarray, np.ndarray]:
    """Gibbs chains for per-parent requests: parent ``p``'s start is one sample and its other
    ``n_req[p] - 1`` sweeps are split into near-equal chains of at most ``chain_length``
    sweeps.  Returns ``(chain_parent, length)`` sorted by non-increasing length."""
    n_chains = np.maximum(1, -(-(n_req - 1) // chain_length))
    parent = np.repeat(np.arange(n_req.size), n_chains)
    sweeps = np.repeat(n_req - 1, n_chains)
    per = np.repeat(n_chains, n_chains)
    pos = np.arange(parent.size) - np.repeat(np.cumsum(n_chains) - n_chains, n_chains)
    length = sweeps // per + (pos < sweeps % per)
    order = np.argsort(-length, kind="stable")
    return parent[order], length[order]


def sample_chains(length: np.ndarray) -> np.ndarray:
    """Chain index of each row of :func:`gibbs_chains`' output (all starts, then the active
    prefix after each sweep)."""
    sweeps = [np.arange(np.count_nonzero(length > s)) for s in range(int(length.max(initial=0)))]
    return np.concatenate([np.arange(length.size)] + sweeps)
