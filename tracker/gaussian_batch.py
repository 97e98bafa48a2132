"""The batch layout of the filtering kernels (:mod:`tracker.filtering`): means ``(N, n)`` and
covariances ``(N, n, n)``, checked once where data enters a tracker (:func:`as_gaussian_batch`),
and the array helpers every kernel shares (transpose and symmetrise the last two axes, a
C-contiguous float view for the compiled kernels)."""

from __future__ import annotations

from typing import Any

import numpy as np


def _c(a: np.ndarray) -> np.ndarray:
    """``a`` as a writable C-contiguous float array (a copy only when it is not one): the
    compiled kernels then see one array type (numba compiles one version per layout and per
    read-only flag)."""
    if a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, dtype=np.float64, order="C")


def _T(A: np.ndarray) -> np.ndarray:
    """Transpose the last two axes."""
    return np.swapaxes(A, -1, -2)


def _sym(A: np.ndarray) -> np.ndarray:
    r""":math:`(A + A^T)/2` over the last two axes."""
    return 0.5 * (A + _T(A))


def as_gaussian_batch(
    m: Any, P: Any, ndim: int | None = None, *, sym_tol: float = 1e-8
) -> tuple[np.ndarray, np.ndarray]:
    """Coerce and validate Gaussian means/covariances into the batch layout of the kernels.

    Accepts a single Gaussian (``m (n,)``, ``P (n, n)``) or a batch (``m (N, n)``,
    ``P (N, n, n)``).  Returns C-contiguous float copies ``(N, n)``, ``(N, n, n)`` with ``P``
    exactly symmetrised.

    Raises ``ValueError`` on shape mismatch, a dimension different from ``ndim``, non-finite
    values, or a covariance whose asymmetry exceeds ``sym_tol`` relative to its largest entry.
    Positive definiteness is *not* required (the kernels cope with PSD / slightly indefinite
    matrices, see :func:`sigma_points`).
    """
    m = np.array(m, dtype=float, ndmin=1)
    P = np.array(P, dtype=float)
    if m.ndim == 1:
        m = m[None, :]
    if P.ndim == 2:
        P = P[None, :, :]
    if m.ndim != 2 or P.ndim != 3:
        raise ValueError(f"means must be (N, n) or (n,), covariances (N, n, n) or (n, n); "
                         f"got {m.shape} and {P.shape}")
    N, n = m.shape
    if P.shape != (N, n, n):
        raise ValueError(f"covariance shape {P.shape} does not match means {m.shape}")
    if ndim is not None and n != ndim:
        raise ValueError(f"state dimension {n} != model dimension {ndim}")
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(P))):
        raise ValueError("means/covariances contain non-finite values")
    if N and n:
        scale = np.max(np.abs(P), axis=(1, 2))
        asym = np.max(np.abs(P - _T(P)), axis=(1, 2))
        bad = asym > sym_tol * np.maximum(scale, np.finfo(float).tiny)
        if np.any(bad):
            raise ValueError(f"covariances not symmetric (tracks {np.flatnonzero(bad).tolist()})")
    return np.ascontiguousarray(m), np.ascontiguousarray(_sym(P))

