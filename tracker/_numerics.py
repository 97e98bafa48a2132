r"""Numerical helpers shared by the trackers: the one JIT switch and the one log-sum-exp.

* :func:`jit` compiles a kernel with numba (``cache=True, nogil=True``) unless numba is
  missing or ``BNPTRACK_NO_JIT=1``: then the same Python function runs interpreted.
  :data:`JIT` says which.
* :func:`logsumexp` is :math:`\log \sum_i e^{a_i}` computed as
  :math:`t + \log \sum_i e^{a_i - t}`, :math:`t = \max_i a_i` (an all ``-inf`` input gives
  ``-inf``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import TypeVar

import numpy as np

try:  # a prebuilt wheel; the kernels also run interpreted (BNPTRACK_NO_JIT=1)
    from numba import njit as _njit
except ImportError:  # pragma: no cover
    _njit = None

F = TypeVar("F", bound=Callable)

#: The kernels are compiled (numba present and ``BNPTRACK_NO_JIT`` is not ``1``).
JIT: bool = _njit is not None and os.environ.get("BNPTRACK_NO_JIT") != "1"


def jit(fn: F, inline: bool = False) -> F:
    """``fn`` compiled with numba (``cache=True, nogil=True``; ``inline="always"`` when
    ``inline``) if :data:`JIT`, else ``fn`` itself (the same code, interpreted)."""
    if not JIT:
        return fn
    if inline:
        return _njit(cache=True, nogil=True, inline="always")(fn)
    return _njit(cache=True, nogil=True)(fn)


def logsumexp(a: np.ndarray, axis: int | None = None):
    """:math:`\\log \\sum \\exp(a)` over ``axis`` (an array), or over every entry when
    ``axis`` is ``None`` (a float).  Plain numpy: scipy's has a large per-call overhead on
    small arrays."""
    if axis is None:
        top = float(np.max(a))
        return top + math.log(float(np.sum(np.exp(a - top)))) if math.isfinite(top) else top
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(top, axis=axis) + np.log(np.sum(np.exp(a - top), axis=axis))
