"""The one compiled linear assignment solver both trackers use.

:func:`lsap_into` is the shortest augmenting path algorithm (Crouse 2016, "On implementing 2D
rectangular assignment algorithms") exactly as ``scipy.optimize.linear_sum_assignment``
implements it, ties included, on caller-provided work arrays, so a batch of problems
(the GLMB's hypotheses, :mod:`tracker.glmb.assignment`) allocates them once.  :func:`lsap`
solves one problem (DDP-EMM's JPDA* choice, :mod:`tracker.bnp._update_kernels`).
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit


def lsap_into(cost, col4row, u, v, spc, path, row4col, SR, SC, remaining):  # pragma: no cover - compiled
    """Minimum-cost assignment of every row of ``cost`` (``(nr, nc)``, rows <= columns,
    ``+inf`` = forbidden) into ``col4row`` (each row's column).  The other arguments are work
    arrays of the shapes :func:`lsap` allocates; their contents on entry do not matter.
    Returns False (``col4row`` then partly written) when no finite assignment exists."""
    nr, nc = cost.shape
    u[:] = 0.0
    v[:] = 0.0
    path[:] = -1
    col4row[:] = -1
    row4col[:] = -1
    for cur in range(nr):
        min_val, i, n_rem, sink = 0.0, cur, nc, -1
        for it in range(nc):
            remaining[it] = nc - it - 1
        SR[:] = False
        SC[:] = False
        spc[:] = np.inf
        while sink == -1:
            index, lowest = -1, np.inf
            SR[i] = True
            for it in range(n_rem):
                j = remaining[it]
                r = min_val + cost[i, j] - u[i] - v[j]
                if r < spc[j]:
                    path[j] = i
                    spc[j] = r
                if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                    lowest = spc[j]
                    index = it
            min_val = lowest
            if min_val == np.inf:
                return False
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                i = row4col[j]
            SC[j] = True
            n_rem -= 1
            remaining[index] = remaining[n_rem]
        u[cur] += min_val
        for i in range(nr):
            if SR[i] and i != cur:
                u[i] += min_val - spc[col4row[i]]
        for j in range(nc):
            if SC[j]:
                v[j] -= min_val - spc[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            tmp = col4row[i]
            col4row[i] = j
            j = tmp
            if i == cur:
                break
    return True


def lsap(cost):  # pragma: no cover - compiled
    """Each row's column in the minimum-cost assignment of ``cost`` (:func:`lsap_into`), or
    all -1 when no finite assignment exists."""
    nr, nc = cost.shape
    col4row = np.empty(nr, dtype=np.int64)
    ok = lsap_into(cost, col4row, np.empty(nr), np.empty(nc), np.empty(nc), np.empty(nc, dtype=np.int64),
                   np.empty(nc, dtype=np.int64), np.empty(nr, dtype=np.bool_), np.empty(nc, dtype=np.bool_),
                   np.empty(nc, dtype=np.int64))
    if not ok:
        col4row[:] = -1
    return col4row


lsap_into = jit(lsap_into)
lsap = jit(lsap)
