"""The batched linear assignment solver of the GLMB chain starts: one compiled shortest
augmenting path kernel (:func:`_lsap_kernel`, scipy's algorithm) over all parents."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker._lsap import lsap_into
from bnptrack.tracker.numerics import jit
from bnptrack.tracker.glmb.hypotheses import _DET, _DIE, _MISS


def _assign(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_assign_dense` on the candidates that have a measurement in their gate only:
    the others (e.g. most adaptive births) cannot compete for a measurement, so their best
    option is their best of dies/missed whatever the rest does (same result, smaller
    problems)."""
    valid = cand >= 0
    safe = np.where(valid, cand, 0)
    gated = valid & np.isfinite(E[:, _DET:]).any(axis=1)[safe]
    Ec = E[safe]
    no_det = np.where(Ec[..., _MISS] >= Ec[..., _DIE], _MISS, _DIE)
    best_no = np.take_along_axis(Ec, no_det[..., None], axis=-1)[..., 0]
    out = np.where(valid, no_det, -1)
    ok = np.all(np.isfinite(best_no) | ~valid | gated, axis=1)
    order = np.argsort(~gated, axis=1, kind="stable")
    width = int(gated.sum(axis=1).max(initial=0))
    if width == 0:
        return out, ok
    order = order[:, :width]
    sub = np.where(np.take_along_axis(gated, order, axis=1), np.take_along_axis(cand, order, axis=1), -1)
    sub_out, sub_ok = _assign_dense(E, sub)
    hh, ii = np.nonzero(sub >= 0)
    out[hh, order[hh, ii]] = sub_out[hh, ii]
    return out, ok & sub_ok


def _assign_dense(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best options of each parent by linear assignment on the cost matrix
    ``[-log eta(detections) | diag(-max(log eta(dies), log eta(missed)))]`` (padding rows
    take their own dummy column at no cost), all parents in one call of the compiled
    :func:`_lsap_kernel` (scipy's algorithm).  Returns options ``(H, width)`` and
    feasibility ``(H,)``."""
    H, width = cand.shape
    M = E.shape[1] - _DET
    valid = cand >= 0
    Ec = E[np.where(valid, cand, 0)]  # (H, width, M + 2)
    no_det = np.where(Ec[..., _MISS] >= Ec[..., _DIE], _MISS, _DIE)
    best_no = np.take_along_axis(Ec, no_det[..., None], axis=-1)[..., 0]
    cost = np.full((H, width, M + width), np.inf)
    cost[:, :, :M] = np.where(valid[..., None], -Ec[..., _DET:], np.inf)
    diag = np.arange(width)
    cost[:, diag, M + diag] = np.where(valid, -best_no, 0.0)
    out = np.where(valid, no_det, -1)
    # width <= M + width columns: every row is assigned and the row indices are 0..width-1
    col = np.full((H, width), M, dtype=np.int64)
    solved = np.zeros(H, dtype=bool)
    _lsap_batch(cost, col, solved)
    hh, ii = np.nonzero(solved[:, None] & (col < M))
    out[hh, ii] = _DET + col[hh, ii]
    ok = solved & np.all(np.isfinite(np.take_along_axis(cost, col[..., None], axis=2)[..., 0]), axis=1)
    return out, ok


def _lsap_kernel(cost: np.ndarray, col: np.ndarray, solved: np.ndarray) -> None:  # pragma: no cover
    """Minimum-cost assignment of every row of each ``cost[h]`` (rows <= columns, +inf =
    forbidden): :func:`tracker._lsap.lsap_into` (scipy's ``linear_sum_assignment`` algorithm)
    batched over ``h`` on one set of work arrays.  Writes ``col[h]`` (the column of each row)
    and ``solved[h]`` (False when no finite assignment exists; ``col[h]`` is then left
    unchanged)."""
    H, nr, nc = cost.shape
    u = np.empty(nr)
    v = np.empty(nc)
    spc = np.empty(nc)
    path = np.empty(nc, dtype=np.int64)
    col4row = np.empty(nr, dtype=np.int64)
    row4col = np.empty(nc, dtype=np.int64)
    SR = np.empty(nr, dtype=np.bool_)
    SC = np.empty(nc, dtype=np.bool_)
    remaining = np.empty(nc, dtype=np.int64)
    for h in range(H):
        if lsap_into(cost[h], col4row, u, v, spc, path, row4col, SR, SC, remaining):
            for i in range(nr):
                col[h, i] = col4row[i]
            solved[h] = True


_lsap_batch = jit(_lsap_kernel)
