"""The gated partition kernel's index of the tables (:mod:`tracker.bnp.group_partition`): the
free table slots as a binary min-heap, and a uniform grid over the tables' theta means (the
indexed block) with a list of the wide tables that every object scores."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit

__all__ = ["CAP_FACTOR", "CELLS", "MARGIN"]

#: Nats below an option's log weight beyond which a table is not scored: its weight is below
#: e^-50 (2e-22) of that option's (module docstring).
MARGIN = 50.0
#: The grid's cap on a table's covariance (largest eigenvalue) as a multiple of the median of the
#: tables' and members' (tables above it are scored for every object).
CAP_FACTOR = 4.0
#: Grid cells per typical gate radius (the box of a query is about 2 r + 2 r / CELLS wide).
CELLS = 1.0


# -- the free slots: a binary min-heap ------------------------------------------------------------
def _heap_push(heap, size, x) -> int:
    """``x`` into the min-heap ``heap[:size]``; returns the new size."""
    i = size
    heap[i] = x
    while i > 0:
        parent = (i - 1) // 2
        if heap[parent] <= heap[i]:
            break
        heap[parent], heap[i] = heap[i], heap[parent]
        i = parent
    return size + 1


def _heap_pop(heap, size) -> int:
    """The minimum ``heap[0]`` out of ``heap[:size]``; returns the new size."""
    size -= 1
    heap[0] = heap[size]
    i = 0
    while True:
        a, b, k = 2 * i + 1, 2 * i + 2, i
        if a < size and heap[a] < heap[k]:
            k = a
        if b < size and heap[b] < heap[k]:
            k = b
        if k == i:
            return size
        heap[k], heap[i] = heap[i], heap[k]
        i = k


# -- the grid of the tables' indexed block ---------------------------------------------------------
def _cell_ij(x, y, geo):
    """Grid cell (i, j) of a point, clamped to the grid (monotone in x and y)."""
    fi = min(max((x - geo[0]) / geo[2], 0.0), geo[3] - 1.0)
    fj = min(max((y - geo[1]) / geo[2], 0.0), geo[4] - 1.0)
    return int(fi), int(fj)


def _unplace(t, cell_of, head, nxt, prv, wide, wide_pos, meta) -> None:
    """Table ``t`` out of its grid cell's list or the wide list (``meta[0]`` its length)."""
    c = cell_of[t]
    if c >= 0:
        if prv[t] >= 0:
            nxt[prv[t]] = nxt[t]
        else:
            head[c] = nxt[t]
        if nxt[t] >= 0:
            prv[nxt[t]] = prv[t]
        cell_of[t] = -1
    elif wide_pos[t] >= 0:
        k, last = wide_pos[t], wide[meta[0] - 1]
        wide[k], wide_pos[last] = last, k
        wide_pos[t] = -1
        meta[0] -= 1


def _place(t, mu, lm, geo, cap, cell_of, head, nxt, prv, wide, wide_pos, meta) -> None:
    """Table ``t`` (not placed) into the cell of ``mu``, or the wide list when its covariance's
    largest eigenvalue ``lm`` exceeds ``cap`` or ``mu`` is not finite."""
    if lm <= cap and np.isfinite(mu[0]) and np.isfinite(mu[1]):
        i, j = _cell_ij(mu[0], mu[1], geo)
        c = i * int(geo[4]) + j
        nxt[t], prv[t] = head[c], -1
        if head[c] >= 0:
            prv[head[c]] = t
        head[c] = t
        cell_of[t] = c
    else:
        wide[meta[0]] = t
        wide_pos[t] = meta[0]
        meta[0] += 1


def _grid_geometry(v, t_mu, live, rho, cap, T):
    """``geo`` = (x0, y0, cell size, nx, ny): the box of the objects' and the live tables' points,
    cells of 1 / :data:`CELLS` of the typical gate radius (:data:`MARGIN`, the median ``rho``), at
    most 4 T + 16 cells."""
    lo, hi = np.array([np.inf, np.inf]), np.array([-np.inf, -np.inf])
    for l in range(v.shape[0]):
        for i in range(2):
            if np.isfinite(v[l, i]):
                lo[i], hi[i] = min(lo[i], v[l, i]), max(hi[i], v[l, i])
    for t in range(T):
        if live[t]:
            for i in range(2):
                if np.isfinite(t_mu[t, i]):
                    lo[i], hi[i] = min(lo[i], t_mu[t, i]), max(hi[i], t_mu[t, i])
    h = np.sqrt(2.0 * (MARGIN + 20.0) * (cap + np.median(rho))) / CELLS
    if not (np.isfinite(hi[0] - lo[0]) and np.isfinite(hi[1] - lo[1]) and h > 0.0 and np.isfinite(h)):
        return np.array([0.0, 0.0, 1.0, 1.0, 1.0])  # one cell: every table in it
    while True:
        nx = np.floor((hi[0] - lo[0]) / h) + 1.0
        ny = np.floor((hi[1] - lo[1]) / h) + 1.0
        if nx * ny <= 4.0 * T + 16.0:
            break
        h *= 2.0
    return np.array([lo[0], lo[1], h, nx, ny])


_heap_push = jit(_heap_push)
_heap_pop = jit(_heap_pop)
_cell_ij = jit(_cell_ij, inline=True)
_unplace = jit(_unplace, inline=True)
_place = jit(_place, inline=True)
_grid_geometry = jit(_grid_geometry)
