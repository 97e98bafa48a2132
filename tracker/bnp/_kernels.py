r"""Compiled passes of the DDP-EMM / DPY-STP step: the same arithmetic as the numpy
reference code, bit for bit.

The step chained about a hundred numpy calls on arrays of a few dozen entries, so the
interpreter's per-call cost, not the arithmetic, set its time.  Here the bookkeeping runs in a
few numba kernels (``cache=True``; ``BNPTRACK_NO_JIT=1`` runs the same functions interpreted).
Their results equal the numpy reference's to the last bit, which the kernels keep by
construction:

* ``exp`` and ``log`` stay in numpy (its SIMD versions differ from the C library's, which
  numba calls, in the last bit); a kernel takes their values as inputs or returns what numpy
  must transform.  ``math.log`` of the Python code is the C library's, as in numba.
* Sums run in numpy's order: ``np.bincount`` and ``np.add.at`` add in index order from 0.0;
  ``np.sum`` of a contiguous array is numpy's pairwise summation (:func:`np_sum`).
* No fused multiply-add (numba does not contract without ``fastmath``).

This module holds what every kernel shares (:func:`np_sum`, :func:`npmax`, :func:`clip01`,
:func:`divide`); the kernels sit by concern in ``_merge_kernels.py`` (duplicate merging),
``_update_kernels.py`` (the sampler's inputs, the existing clusters' update, JPDA*),
``_birth_kernels.py`` (the births' moments) and ``_estimate_kernels.py`` (the cardinality pmf,
the estimate's assignments).  Each kernel's test (``tests/tracker/test_bnp_kernels.py``)
compares it with the numpy code on seed-pinned random inputs, bit for bit.
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit


def np_sum(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """``np.sum(a[lo:lo + n])`` in numpy's order (``pairwise_sum``): blocks of at most 128
    terms (:func:`_pairwise_block`), and above 128 the sum of the two halves, split at a
    multiple of 8.  The halving runs on an explicit stack, not by recursion: a cached kernel
    that calls a recursive one crashes when it is loaded from numba's cache."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    f_lo = np.empty(64, dtype=np.int64)  # depth <= log2(n / 128) + 1
    f_n = np.empty(64, dtype=np.int64)
    f_left = np.empty(64)
    f_right = np.zeros(64, dtype=np.bool_)  # the left half is summed; its right half is on top
    depth, f_lo[0], f_n[0] = 0, lo, n
    while True:
        cl, cn = f_lo[depth], f_n[depth]
        if cn > 128:  # descend into the left half
            n2 = cn // 2
            n2 -= n2 % 8
            depth += 1
            f_lo[depth], f_n[depth], f_right[depth] = cl, n2, False
            continue
        ret = _pairwise_block(a, cl, cn)
        while True:  # hand the finished sum to the parents
            if depth == 0:
                return ret
            is_right = f_right[depth]
            depth -= 1
            if not is_right:
                f_left[depth] = ret
                pl, pn = f_lo[depth], f_n[depth]
                n2 = pn // 2
                n2 -= n2 % 8
                depth += 1
                f_lo[depth], f_n[depth], f_right[depth] = pl + n2, pn - n2, True
                break
            ret = f_left[depth] + ret


def _pairwise_block(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """numpy's ``pairwise_sum`` of at most 128 terms: a plain loop below 8 terms, else eight
    interleaved partial sums, combined pairwise, then the remainder."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


def divide(a, b):  # pragma: no cover - compiled
    """``a / b`` with numpy's result for ``b == 0`` (nan or +-inf; numba's default raises)."""
    if b != 0.0:
        return a / b
    if a == 0.0 or a != a:
        return np.nan
    return np.inf if (a > 0.0) == (np.copysign(1.0, b) > 0.0) else -np.inf


def npmax(a, b):  # pragma: no cover - compiled
    """``np.maximum`` of two floats: nan if either is."""
    return a if a >= b or a != a else b


def clip01(x):  # pragma: no cover - compiled
    """``np.clip(x, 0.0, 1.0)`` of a float (nan stays nan)."""
    if x < 0.0:
        return 0.0
    return 1.0 if x > 1.0 else x


_pairwise_block = jit(_pairwise_block, kernels_only=True)
np_sum = jit(np_sum, kernels_only=True)
divide = jit(divide, inline=True)
npmax = jit(npmax, inline=True)
clip01 = jit(clip01, inline=True)
