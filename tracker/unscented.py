"""The scaled unscented transform of the filtering kernels (:mod:`tracker.filtering`): its
parameters (:class:`UnscentedParams`), weights (:func:`unscented_weights`) and sigma points
(:func:`sigma_points`, from a square-root factor that tolerates covariances that are not
positive definite)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bnptrack.tracker.gaussian_batch import _sym, _T


@dataclass(frozen=True)
class UnscentedParams:
    r"""Scaled unscented transform parameters (Julier 2002; Wan & van der Merwe 2000).

    .. math::

        \lambda = \alpha^2 (n + \kappa) - n, \qquad c = n + \lambda = \alpha^2 (n + \kappa)

        \mathcal X_0 = m, \quad
        \mathcal X_{i} = m + \sqrt{c}\, [\sqrt P]_i, \quad
        \mathcal X_{n+i} = m - \sqrt{c}\, [\sqrt P]_i, \quad i = 1..n

        W^{(m)}_0 = \lambda / c, \quad W^{(c)}_0 = \lambda / c + 1 - \alpha^2 + \beta, \quad
        W^{(m)}_i = W^{(c)}_i = 1 / (2c)

    The defaults :math:`\alpha = 1, \beta = 2, \kappa = 2` are those of Vo's GLMB UKF demo
    (for :math:`n = 5`: :math:`c = 7`, all mean weights positive).
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 2.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.alpha) and self.alpha > 0):
            raise ValueError(f"UnscentedParams.alpha must be > 0, got {self.alpha}")
        if not (np.isfinite(self.beta) and np.isfinite(self.kappa)):
            raise ValueError("UnscentedParams.beta and kappa must be finite")


@lru_cache(maxsize=64)
def unscented_weights(params: UnscentedParams, n: int) -> tuple[np.ndarray, np.ndarray, float]:
    r"""Mean weights ``Wm (2n+1,)``, covariance weights ``Wc (2n+1,)`` and the scale :math:`c`.

    See :class:`UnscentedParams` for the formulas.  Cached; the returned arrays are read-only.
    """
    c = params.alpha**2 * (n + params.kappa)
    if not c > 0:
        raise ValueError(f"unscented scale alpha^2 (n + kappa) = {c} must be > 0 (n={n})")
    lam = c - n
    Wm = np.full(2 * n + 1, 0.5 / c)
    Wm[0] = lam / c
    Wc = Wm.copy()
    Wc[0] += 1.0 - params.alpha**2 + params.beta
    Wm.setflags(write=False)
    Wc.setflags(write=False)
    return Wm, Wc, float(c)


def _sqrt_factor(P: np.ndarray) -> np.ndarray:
    r"""Batched square-root factor :math:`A` with :math:`A A^T = P` (``(N, n, n)``).

    Lower Cholesky factor where :math:`P` is positive definite.  For matrices where Cholesky
    fails, the symmetric eigen-factor :math:`A = V \operatorname{diag}(\sqrt{\max(\lambda,
    0)})` (negative eigenvalues clipped) is used instead -- only for those matrices, so a
    track's sigma points do not depend on the other tracks in the batch.
    """
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    vals, vecs = np.linalg.eigh(_sym(P))
    A = vecs * np.sqrt(np.clip(vals, 0.0, None))[:, None, :]
    pd = vals[:, 0] > 0.0
    if np.any(pd):
        try:
            A[pd] = np.linalg.cholesky(P[pd])
        except np.linalg.LinAlgError:  # borderline matrices: keep the eigen-factor for all
            pass
    return A


def sigma_points(m: np.ndarray, P: np.ndarray, params: UnscentedParams = UnscentedParams()
                 ) -> np.ndarray:
    r"""Sigma points ``(N, 2n+1, n)``: :math:`m`, :math:`m + \sqrt c A_{:,i}`,
    :math:`m - \sqrt c A_{:,i}` with :math:`A A^T = P` (see :func:`_sqrt_factor`)."""
    n = m.shape[-1]
    _, _, c = unscented_weights(params, n)
    D = np.sqrt(c) * _T(_sqrt_factor(P))  # rows = scaled columns of A
    mc = m[:, None, :]
    return np.concatenate([mc, mc + D, mc - D], axis=1)


def _apply_rows(fn, X: np.ndarray) -> np.ndarray:
    """Apply a row-wise model function to ``(N, K, n)`` points -> ``(N, K, out)``."""
    N, K, n = X.shape
    Y = fn(X.reshape(N * K, n))
    return Y.reshape(N, K, Y.shape[-1])


def _weighted_cov(Wc: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    r""":math:`\sum_k W_k A_k B_k^T` for ``A (N, K, a)``, ``B (N, K, b)`` -> ``(N, a, b)``."""
    return _T(A * Wc[None, :, None]) @ B

