"""Small Gaussian helpers shared by the models (no validation: internal)."""

from __future__ import annotations

import numpy as np

_LOG_2PI = np.log(2.0 * np.pi)


def gaussian_logpdf(residual: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Log density of zero-mean Gaussian residuals ``(N, d)`` under ``cov`` ``(d, d)``.

    A singular ``cov`` is handled like ``scipy.stats.multivariate_normal(allow_singular=True)``:
    the density is taken on the support (pseudo-determinant, pseudo-inverse).
    """
    residual = np.atleast_2d(residual)
    vals, vecs = np.linalg.eigh(cov)
    tol = vals.max() * max(cov.shape) * np.finfo(float).eps * 1e3
    keep = vals > tol
    proj = residual @ vecs[:, keep]
    maha = np.sum(proj**2 / vals[keep], axis=-1)
    rank = int(keep.sum())
    return -0.5 * (rank * _LOG_2PI + np.sum(np.log(vals[keep])) + maha)
