"""Lexicographic order of the rows of integer matrices in compiled passes, for the GLMB's
children (:mod:`tracker.glmb.children`): a sort of all rows (:func:`_sort_rows`), a sort
bucketed by the first column (:func:`_sort_rows_bucketed`) and the first row of each run of
equal rows (:func:`_distinct_rows`), the order and the rows of numpy's ``unique`` on rows."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit


def _row_less(A: np.ndarray, a: int, b: int) -> bool:  # pragma: no cover - compiled
    """Row ``a`` of ``A`` before row ``b`` in lexicographic order."""
    for k in range(A.shape[1]):
        if A[a, k] != A[b, k]:
            return A[a, k] < A[b, k]
    return False


_row_less = jit(_row_less)


def _sort_rows(A: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Stable lexicographic order of the rows of ``A`` (bottom-up merge sort; as
    ``np.lexsort(A.T[::-1])``)."""
    n = A.shape[0]
    idx = np.arange(n)
    tmp = np.empty(n, dtype=np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid = min(lo + width, n)
            hi = min(lo + 2 * width, n)
            i, j, k = lo, mid, lo
            while i < mid and j < hi:
                if _row_less(A, idx[j], idx[i]):
                    tmp[k] = idx[j]
                    j += 1
                else:
                    tmp[k] = idx[i]
                    i += 1
                k += 1
            while i < mid:
                tmp[k] = idx[i]
                i += 1
                k += 1
            while j < hi:
                tmp[k] = idx[j]
                j += 1
                k += 1
        idx, tmp = tmp, idx
        width *= 2
    return idx


_sort_rows = jit(_sort_rows)


def _sort_rows_bucketed(A: np.ndarray, n_first: int) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`_sort_rows` for rows whose first entry is in ``0..n_first-1`` and mostly
    distinct (the parent of a sample): a counting sort on it, then an insertion sort of each
    bucket (a parent's few samples)."""
    n = A.shape[0]
    start = np.zeros(n_first + 1, dtype=np.int64)
    for a in range(n):
        start[A[a, 0] + 1] += 1
    for p in range(n_first):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    idx = np.empty(n, dtype=np.int64)
    for a in range(n):
        idx[fill[A[a, 0]]] = a
        fill[A[a, 0]] += 1
    for p in range(n_first):
        for x in range(start[p] + 1, start[p + 1]):
            cur = idx[x]
            y = x - 1
            while y >= start[p] and _row_less(A, cur, idx[y]):
                idx[y + 1] = idx[y]
                y -= 1
            idx[y + 1] = cur
    return idx


_sort_rows_bucketed = jit(_sort_rows_bucketed)


def _distinct_rows(A: np.ndarray, order: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """For rows in sorted ``order``: 1 where a row differs from the one before (``unique_rows``'
    ``new`` mask), as int64."""
    n = order.size
    new = np.zeros(n, dtype=np.int64)
    for t in range(n):
        if t == 0:
            new[t] = 1
            continue
        for k in range(A.shape[1]):
            if A[order[t], k] != A[order[t - 1], k]:
                new[t] = 1
                break
    return new


_distinct_rows = jit(_distinct_rows)
