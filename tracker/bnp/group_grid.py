"""The gated partition kernel's index of the tables (:mod:`tracker.bnp.group_partition`): the
free table slots as a binary min-heap, and a uniform grid over the tables' theta means (the
indexed block) with a list of the wide tables that every object scores."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit

__all__ = ["CAP_FACTOR", "CELLS", "MARGIN", "median"]

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


# -- the median: numba's np.median, as kernels of this package ---------------------------------
# numba compiles np.median (a quickselect, numba.np.arraymath: _partition, _select, _select_two,
# _median_inner) afresh for every process and every kernel that calls it, 2-2.5 s of CPU on a first
# run; these are the same steps in the same order (the same value, NaNs included), compiled once
# into the kernel cache.
def _qs_partition(A, low, high) -> int:
    """numba's ``_partition`` (``less_than``: ``a < b``) of ``A[low:high + 1]``: the pivot's index."""
    mid = (low + high) >> 1
    if A[mid] < A[low]:
        A[low], A[mid] = A[mid], A[low]
    if A[high] < A[mid]:
        A[high], A[mid] = A[mid], A[high]
    if A[mid] < A[low]:
        A[low], A[mid] = A[mid], A[low]
    pivot = A[mid]
    A[high], A[mid] = A[mid], A[high]
    i = low
    j = high - 1
    while True:
        while i < high and A[i] < pivot:
            i += 1
        while j >= low and pivot < A[j]:
            j -= 1
        if i >= j:
            break
        A[i], A[j] = A[j], A[i]
        i += 1
        j -= 1
    A[i], A[high] = A[high], A[i]
    return i


def _qs_select(A, k, low, high) -> float:
    """numba's ``_select``: the k'th smallest of ``A[low:high + 1]`` (``A`` partly reordered)."""
    i = _qs_partition(A, low, high)
    while i != k:
        if i < k:
            low = i + 1
            i = _qs_partition(A, low, high)
        else:
            high = i - 1
            i = _qs_partition(A, low, high)
    return A[k]


def median(a) -> float:
    """``np.median`` of the 1-d ``a`` as numba computes it (NaN when empty; ``_median_inner``, with
    ``_select_two`` for an even count)."""
    A = a.copy()
    n = A.shape[0]
    if n == 0:
        return np.nan
    low, high, half = np.int64(0), n - 1, n >> 1  # int64, not a literal 0: one signature per kernel
    if n & 1 == 1:
        return _qs_select(A, half, low, high)
    k = half - 1
    while True:
        i = _qs_partition(A, low, high)
        if i < k:
            low = i + 1
        elif i > k + 1:
            high = i - 1
        elif i == k:
            _qs_select(A, k + 1, i + 1, high)
            break
        else:
            _qs_select(A, k, low, i - 1)
            break
    return (A[k] + A[k + 1]) / 2


# -- the grid of the tables' indexed block ---------------------------------------------------------
def _cell_ij(x, y, geo):
    """Grid cell (i, j) of a point, clamped to the grid (monotone in x and y)."""
    fi = min(max((x - geo[0]) / geo[2], 0.0), geo[3] - 1.0)
    fj = min(max((y - geo[1]) / geo[2], 0.0), geo[4] - 1.0)
    return int(fi), int(fj)


def _unplace(t, grid) -> None:
    """Table ``t`` out of its cell's list or the wide list of ``grid`` (:class:`~tracker.bnp.group_bundles.Grid`)."""
    c = grid.cell_of[t]
    if c >= 0:
        if grid.prv[t] >= 0:
            grid.nxt[grid.prv[t]] = grid.nxt[t]
        else:
            grid.head[c] = grid.nxt[t]
        if grid.nxt[t] >= 0:
            grid.prv[grid.nxt[t]] = grid.prv[t]
        grid.cell_of[t] = -1
    elif grid.wide_pos[t] >= 0:
        k, last = grid.wide_pos[t], grid.wide[grid.n_wide[0] - 1]
        grid.wide[k], grid.wide_pos[last] = last, k
        grid.wide_pos[t] = -1
        grid.n_wide[0] -= 1


def _place(t, mu, lm, grid) -> None:
    """Table ``t`` (not placed) into the cell of ``mu``, or the wide list when its covariance's
    largest eigenvalue ``lm`` exceeds ``grid.cap`` or ``mu`` is not finite."""
    if lm <= grid.cap and np.isfinite(mu[0]) and np.isfinite(mu[1]):
        i, j = _cell_ij(mu[0], mu[1], grid.geo)
        c = i * int(grid.geo[4]) + j
        grid.nxt[t], grid.prv[t] = grid.head[c], -1
        if grid.head[c] >= 0:
            grid.prv[grid.head[c]] = t
        grid.head[c] = t
        grid.cell_of[t] = c
    else:
        grid.wide[grid.n_wide[0]] = t
        grid.wide_pos[t] = grid.n_wide[0]
        grid.n_wide[0] += 1


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
    h = np.sqrt(2.0 * (MARGIN + 20.0) * (cap + median(rho))) / CELLS
    if not (np.isfinite(hi[0] - lo[0]) and np.isfinite(hi[1] - lo[1]) and h > 0.0 and np.isfinite(h)):
        return np.array([0.0, 0.0, 1.0, 1.0, 1.0])  # one cell: every table in it
    while True:
        nx = np.floor((hi[0] - lo[0]) / h) + 1.0
        ny = np.floor((hi[1] - lo[1]) / h) + 1.0
        if nx * ny <= 4.0 * T + 16.0:
            break
        h *= 2.0
    return np.array([lo[0], lo[1], h, nx, ny])


_heap_push = jit(_heap_push, kernels_only=True)
_heap_pop = jit(_heap_pop, kernels_only=True)
_cell_ij = jit(_cell_ij, inline=True)
_unplace = jit(_unplace, kernels_only=True)
_place = jit(_place, kernels_only=True)
_qs_partition = jit(_qs_partition, kernels_only=True)
_qs_select = jit(_qs_select, kernels_only=True)
median = jit(median, kernels_only=True)
_grid_geometry = jit(_grid_geometry, kernels_only=True)
