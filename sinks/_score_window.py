"""The OSPA(2) window's per-scan terms as one compiled kernel (:class:`sinks.run_scorer.RunScorer`
with ``compiled=True``: the Monte Carlo runner, whose workers have numba loaded by the
trackers anyway).

:func:`window_terms` builds exactly the arrays the numpy path of
``sinks.metrics._TrackWindow.distances`` builds with some twenty small numpy calls per frame:
the ``(m, n, W)`` per-scan terms (``c ** q`` where one of the two tracks exists, the scan's
cut-off distance term where both do, 0 where neither does) and the ``(m, n)`` number of scans
where either exists.  The caller sums and divides them with numpy, so OSPA(2) is the same bit
for bit as the direct computation (tests/sinks/test_score_window.py).
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit


def _window_terms_kernel(ge, cnt_e, gt, cnt_t, terms, n_ids_e, n_ids_t, cq):  # pragma: no cover - compiled
    """``ge`` / ``gt``: every scan's estimated / true labels as run-wide ids (scan after scan,
    ``cnt_e`` / ``cnt_t`` per scan; ids below ``n_ids_e`` / ``n_ids_t``); ``terms``: every
    scan's ``(n_true, n_est)`` terms, raveled, scan after scan.  The window's labels are
    numbered in first-seen order (rows / columns, as ``sinks.metrics._first_seen_ranks``).
    Returns the per-scan terms ``(m, n, W)`` and the union counts ``(m, n)``."""
    re, m = _first_seen(ge, n_ids_e)
    rt, n = _first_seen(gt, n_ids_t)
    W = cnt_e.size
    per_scan = np.zeros((m, n, W))
    count = np.zeros((m, n), dtype=np.int64)
    ex = np.zeros(m, dtype=np.bool_)
    ey = np.zeros(n, dtype=np.bool_)
    oe, ot, op = 0, 0, 0
    for w in range(W):
        ne, nt = cnt_e[w], cnt_t[w]
        ex[:] = False
        ey[:] = False
        for a in range(ne):
            ex[re[oe + a]] = True
        for b in range(nt):
            ey[rt[ot + b]] = True
        for i in range(m):
            for j in range(n):
                if ex[i] or ey[j]:
                    per_scan[i, j, w] = cq
                    count[i, j] += 1
        for b in range(nt):
            for a in range(ne):
                per_scan[re[oe + a], rt[ot + b], w] = terms[op + b * ne + a]
        oe += ne
        ot += nt
        op += ne * nt
    return per_scan, count


def _first_seen_kernel(ids, n_ids):  # pragma: no cover - compiled
    """Each entry of ``ids`` numbered by the first-seen order of its id; the number of ids."""
    rank = np.full(n_ids, -1, dtype=np.int64)
    out = np.empty(ids.size, dtype=np.int64)
    k = 0
    for i in range(ids.size):
        if rank[ids[i]] < 0:
            rank[ids[i]] = k
            k += 1
        out[i] = rank[ids[i]]
    return out, k


_first_seen = jit(_first_seen_kernel)
_window_terms = jit(_window_terms_kernel)


def window_terms(scans, n_ids_e: int, n_ids_t: int, cq: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_window_terms_kernel` of the window's scans ``(ids_e, ids_t, terms)``."""
    return _window_terms(np.concatenate([s[0] for s in scans]), np.array([s[0].size for s in scans], dtype=np.int64),
                         np.concatenate([s[1] for s in scans]), np.array([s[1].size for s in scans], dtype=np.int64),
                         np.concatenate([s[2] for s in scans]), int(n_ids_e), int(n_ids_t), float(cq))
