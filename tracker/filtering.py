r"""Gaussian filtering kernels shared by every tracker (DDP-EMM, DPY-STP, GLMB).

Everything is batch-first and vectorised over tracks and measurements:

* ``N`` tracks: means ``m`` of shape ``(N, n)`` and covariances ``P`` of shape ``(N, n, n)``;
* ``M`` measurements: ``Z`` of shape ``(M, d)``.

There are no Python loops over tracks or measurements.  The kernels do **no input
validation** (they are called thousands of times per frame, like ``scipy.stats``'s private
``_logpdf`` methods); arrays must already be float arrays of the shapes documented.  Use
:func:`as_gaussian_batch` once, where data enters a tracker, to coerce and check means and
covariances.

Model protocol (see :mod:`tracker.models.motion` and :mod:`tracker.models.measurement`):

* motion: ``f(x) (K, n) -> (K, n)``, ``jacobian(x) (K, n) -> (K, n, n)``, ``Q (n, n)``,
  ``ndim``;
* measurement: ``h(x) (K, n) -> (K, d)``, ``jacobian(x) (K, n) -> (K, d, n)``, ``R (d, d)``,
  ``residual(z, z_pred)`` (broadcasting :math:`z - \hat z`, angles wrapped), ``dim``.

Typical use, one frame of a tracker::

    m_pred, P_pred = ekf_predict(motion, m, P)          # or ukf_predict
    innov = ekf_innovation(meas, m_pred, P_pred)        # or ukf_innovation
    L = log_likelihood_matrix(meas, innov, Z, gate_prob=0.999)   # (N, M)
    m_upd = update_means(meas, innov, m_pred, Z)        # (N, M, n); covariance innov.P_upd

The posterior covariance of a Gaussian-linear(ised) update does not depend on which
measurement is used, so it is computed once per track (``Innovation.P_upd``) and shared by all
``M`` hypotheses.  The :class:`Innovation` arrays are read-only for that reason.
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from functools import lru_cache
from itertools import chain
from statistics import NormalDist
from typing import Any

import numpy as np

from bnptrack.tracker import numerics
from bnptrack.tracker.models import _kernels
from bnptrack.tracker.models.measurement import BearingRange, Cartesian, RangeOnly
from bnptrack.tracker.models.motion import CoordinatedTurn

__all__ = [
    "UnscentedParams",
    "Innovation",
    "as_gaussian_batch",
    "unscented_weights",
    "sigma_points",
    "ekf_predict",
    "ukf_predict",
    "ekf_innovation",
    "ukf_innovation",
    "gate_threshold",
    "mahalanobis_matrix",
    "log_likelihood_matrix",
    "update_means",
    "update_pairs",
    "kalman_update",
    "SCIPY_PAIRS",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


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


# --------------------------------------------------------------------------------------
# Validation (the one checking entry point)
# --------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------
# Unscented transform
# --------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------
# Prediction
# --------------------------------------------------------------------------------------


def ekf_predict(motion, m: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Extended Kalman prediction of ``N`` Gaussians.

    .. math::

        m' = f(m), \qquad P' = F P F^T + Q, \qquad F = \left.\frac{\partial f}{\partial x}
        \right|_{m}

    ``m (N, n)``, ``P (N, n, n)`` -> ``m' (N, n)``, ``P' (N, n, n)`` (exactly symmetric).
    """
    F = motion.jacobian(m)
    return motion.f(m), _sym(F @ P @ _T(F)) + motion.Q


def ukf_predict(motion, m: np.ndarray, P: np.ndarray,
                params: UnscentedParams = UnscentedParams()) -> tuple[np.ndarray, np.ndarray]:
    r"""Unscented Kalman prediction (additive process noise).

    With sigma points :math:`\mathcal X_k` of :math:`(m, P)` (:func:`sigma_points`) and
    :math:`\mathcal Y_k = f(\mathcal X_k)`:

    .. math::

        m' = \sum_k W^{(m)}_k \mathcal Y_k, \qquad
        P' = \sum_k W^{(c)}_k (\mathcal Y_k - m')(\mathcal Y_k - m')^T + Q

    Exact (up to rounding) for linear :math:`f`.  Non-positive-definite ``P`` is tolerated
    (eigen-factor with clipped eigenvalues).  The coordinated-turn model runs in a compiled
    kernel (:func:`tracker.models._kernels.ct_ukf_predict`, same values to rounding); other
    models, and covariances that are not positive definite, in numpy (:func:`_ukf_predict_numpy`).
    """
    if numerics.JIT and type(motion) is CoordinatedTurn and m.shape[-1] == 5 and len(m):
        Wm, Wc, c = unscented_weights(params, 5)
        m_pred, P_pred, ok = _kernels.ct_ukf_predict(_c(m), _c(P), float(motion.T),
                                                     Wm, Wc, math.sqrt(c), motion.Q)
        if ok:
            return m_pred, P_pred
    return _ukf_predict_numpy(motion, m, P, params)


def _ukf_predict_numpy(motion, m: np.ndarray, P: np.ndarray,
                       params: UnscentedParams = UnscentedParams()) -> tuple[np.ndarray, np.ndarray]:
    """The numpy reference of :func:`ukf_predict` (any motion model)."""
    Wm, Wc, _ = unscented_weights(params, m.shape[-1])
    Y = _apply_rows(motion.f, sigma_points(m, P, params))
    m_pred = np.einsum("k,nki->ni", Wm, Y)
    dY = Y - m_pred[:, None, :]
    return m_pred, _sym(_weighted_cov(Wc, dY, dY)) + motion.Q


# --------------------------------------------------------------------------------------
# Innovation (per-track measurement prediction and gain)
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Innovation:
    r"""Per-track predicted measurement statistics and Kalman gain (read-only arrays).

    For ``N`` tracks, state dimension ``n``, measurement dimension ``d``:

    ========== ============= =========================================================
    z_pred     ``(N, d)``    predicted measurement :math:`\hat z` (angles wrapped)
    S          ``(N, d, d)`` innovation covariance
    S_inv      ``(N, d, d)`` :math:`S^{-1}`
    log_det_S  ``(N,)``      :math:`\log\det S`
    gain       ``(N, n, d)`` Kalman gain :math:`K = C S^{-1}`
    P_upd      ``(N, n, n)`` posterior covariance :math:`P - K S K^T` (any measurement)
    cross_cov  ``(N, n, d)`` state/measurement cross-covariance :math:`C` (:math:`P H^T`
                             for the EKF)
    ========== ============= =========================================================
    """

    z_pred: np.ndarray
    S: np.ndarray
    S_inv: np.ndarray
    log_det_S: np.ndarray
    gain: np.ndarray
    P_upd: np.ndarray
    cross_cov: np.ndarray

    def __post_init__(self) -> None:
        for name in ("z_pred", "S", "S_inv", "log_det_S", "gain", "P_upd", "cross_cov"):
            getattr(self, name).setflags(write=False)

    def __len__(self) -> int:
        return self.z_pred.shape[0]

    @property
    def dim(self) -> int:
        """Measurement dimension ``d``."""
        return self.z_pred.shape[1]

    def take(self, idx: Any) -> Innovation:
        """The innovation of a subset of tracks (``idx``: integer index array or mask)."""
        return Innovation(*(np.asarray(getattr(self, f))[idx] for f in (
            "z_pred", "S", "S_inv", "log_det_S", "gain", "P_upd", "cross_cov")))


def _spd_inv_logdet(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Inverse and :math:`\log\det` of a batch of SPD matrices (Cholesky; eigen fallback
    with eigenvalues floored at :math:`10^{-12}\lambda_{max}` for numerically singular ones)."""
    try:
        L = np.linalg.cholesky(S)
        Linv = np.linalg.inv(L)
        S_inv = _sym(_T(Linv) @ Linv)
        log_det = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
        return S_inv, log_det
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(S)
        floor = 1e-12 * np.max(np.abs(vals), axis=-1, keepdims=True)
        vals = np.maximum(vals, np.maximum(floor, np.finfo(float).tiny))
        S_inv = _sym((vecs / vals[:, None, :]) @ _T(vecs))
        return S_inv, np.sum(np.log(vals), axis=-1)


def _finish(z_pred, S, C, P_upd_fn) -> Innovation:
    S = _sym(S)
    S_inv, log_det = _spd_inv_logdet(S)
    K = C @ S_inv
    return Innovation(z_pred=z_pred, S=S, S_inv=S_inv, log_det_S=log_det, gain=K,
                      P_upd=P_upd_fn(K, S), cross_cov=C)


def ekf_innovation(meas, m_pred: np.ndarray, P_pred: np.ndarray) -> Innovation:
    r"""Extended-Kalman innovation: linearise :math:`h` at the predicted mean.

    .. math::

        H = \left.\frac{\partial h}{\partial x}\right|_{m}, \quad \hat z = h(m), \quad
        C = P H^T, \quad S = H P H^T + R, \quad K = C S^{-1}

        P^+ = (I - K H) P (I - K H)^T + K R K^T \quad\text{(Joseph form, symmetrised)}

    ``m_pred (N, n)``, ``P_pred (N, n, n)`` -> :class:`Innovation`.
    """
    H = meas.jacobian(m_pred)
    C = P_pred @ _T(H)
    S = H @ C + meas.R
    R = meas.R

    def p_upd(K, _S):
        A = np.eye(m_pred.shape[-1]) - K @ H
        return _sym(A @ P_pred @ _T(A) + K @ R @ _T(K))

    return _finish(meas.h(m_pred), S, C, p_upd)


def ukf_innovation(meas, m_pred: np.ndarray, P_pred: np.ndarray,
                   params: UnscentedParams = UnscentedParams()) -> Innovation:
    r"""Unscented innovation: sigma points of :math:`(m, P)` through :math:`h`.

    Angles are averaged through residuals about the mean's prediction
    :math:`z_0 = h(m)` (``meas.residual`` wraps them), so sigma points straddling
    :math:`\pm\pi` average correctly:

    .. math::

        \mathcal Z_k = h(\mathcal X_k), \qquad
        \hat z = \operatorname{wrap}\Big(z_0 + \sum_k W^{(m)}_k\, r(\mathcal Z_k, z_0)\Big)

        S = \sum_k W^{(c)}_k\, r(\mathcal Z_k, \hat z)\, r(\mathcal Z_k, \hat z)^T + R, \quad
        C = \sum_k W^{(c)}_k (\mathcal X_k - m)\, r(\mathcal Z_k, \hat z)^T, \quad
        K = C S^{-1}, \quad P^+ = P - K S K^T

    where :math:`r(z, z') =` ``meas.residual(z, z')`` and the final wrap is
    ``meas.residual(., 0)``.  ``P^+`` is symmetrised.  The bearing-range, range and xy models
    run in a compiled kernel (:func:`tracker.models._kernels.ukf_innovation_kernel`, same values
    to rounding); other models, and covariances that are not positive definite, in numpy
    (:func:`_ukf_innovation_numpy`).
    """
    kind = _KERNEL_KINDS.get(type(meas)) if numerics.JIT else None
    if kind is not None and len(m_pred) and m_pred.shape[-1] == 5:
        Wm, Wc, c = unscented_weights(params, 5)
        R = meas.R
        if R.shape[0] == 1:  # the kernel's padding component (see its docstring)
            R = np.array([[R[0, 0], 0.0], [0.0, 1.0]])
        z, S, S_inv, log_det, K, P_upd, C, ok = _kernels.ukf_innovation_kernel(
            _c(m_pred), _c(P_pred), Wm, Wc, math.sqrt(c), kind, float(meas.sensor_x), float(meas.sensor_y),
            float(meas.heading), _c(R))
        if ok and meas.R.shape[0] == 1:
            z, S, S_inv, K, C = (np.ascontiguousarray(a[..., :1]) for a in (z, S[:, :1], S_inv[:, :1], K, C))
        if ok:
            return Innovation(z, S, S_inv, log_det, K, P_upd, C)
    return _ukf_innovation_numpy(meas, m_pred, P_pred, params)


#: Measurement model classes with a compiled innovation (code of :mod:`tracker.models._kernels`).
_KERNEL_KINDS: dict[type, int] = {BearingRange: _kernels.KIND_BEARING_RANGE, RangeOnly: _kernels.KIND_RANGE,
                                  Cartesian: _kernels.KIND_XY}


def _ukf_innovation_numpy(meas, m_pred: np.ndarray, P_pred: np.ndarray,
                          params: UnscentedParams = UnscentedParams()) -> Innovation:
    """The numpy reference of :func:`ukf_innovation` (any measurement model)."""
    Wm, Wc, _ = unscented_weights(params, m_pred.shape[-1])
    X = sigma_points(m_pred, P_pred, params)
    Zs = _apply_rows(meas.h, X)
    z0 = meas.h(m_pred)
    z_pred = z0 + np.einsum("k,nkd->nd", Wm, meas.residual(Zs, z0[:, None, :]))
    z_pred = meas.residual(z_pred, np.zeros_like(z_pred))  # wrap angle components
    dZ = meas.residual(Zs, z_pred[:, None, :])
    dX = X - m_pred[:, None, :]
    S = _weighted_cov(Wc, dZ, dZ) + meas.R
    C = _weighted_cov(Wc, dX, dZ)

    def p_upd(K, S_):
        return _sym(P_pred - K @ S_ @ _T(K))

    return _finish(z_pred, S, C, p_upd)


# --------------------------------------------------------------------------------------
# Likelihoods and updates for all track/measurement pairs
# --------------------------------------------------------------------------------------


@lru_cache(maxsize=64)
def gate_threshold(gate_prob: float, dim: int) -> float:
    r"""Squared-Mahalanobis gate :math:`\chi^2_d{}^{-1}(p_G)` (cached ``chi2.ppf``)."""
    if not 0.0 < gate_prob < 1.0:
        raise ValueError(f"gate_prob must be in (0, 1), got {gate_prob}")
    if dim == 1:  # closed forms of chi2.ppf (no scipy import on the hot path)
        return NormalDist().inv_cdf(0.5 + 0.5 * gate_prob) ** 2
    if dim == 2:
        return -2.0 * math.log1p(-gate_prob)
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(dim / 2.0, gate_prob))


def _residuals(meas, innov: Innovation, Z: np.ndarray) -> np.ndarray:
    """All residuals ``(N, M, d)``: ``meas.residual(Z[m], z_pred[n])``."""
    return meas.residual(Z[None, :, :], innov.z_pred[:, None, :])


def _maha(innov: Innovation, r: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distances of residuals ``(N, M, d)`` -> ``(N, M)``."""
    return np.sum((r @ innov.S_inv) * r, axis=-1)


def mahalanobis_matrix(meas, innov: Innovation, Z: np.ndarray) -> np.ndarray:
    r"""Squared Mahalanobis distances ``(N, M)``:

    .. math:: D^2_{nm} = r_{nm}^T S_n^{-1} r_{nm}, \qquad r_{nm} = z_m \ominus \hat z_n

    (:math:`\ominus` = ``meas.residual``, bearing wrapped).  ``Z`` is ``(M, d)``.
    """
    return _maha(innov, _residuals(meas, innov, Z))


def log_likelihood_matrix(meas, innov: Innovation, Z: np.ndarray,
                          gate_prob: float | None = None) -> np.ndarray:
    r"""Log measurement likelihoods of every track/measurement pair, ``(N, M)``:

    .. math::

        \ell_{nm} = \log \mathcal N(z_m; \hat z_n, S_n)
                  = -\tfrac12\left(d \log 2\pi + \log\det S_n + D^2_{nm}\right)

    with :math:`D^2_{nm}` from :func:`mahalanobis_matrix` (wrapped residuals).  If
    ``gate_prob`` is given, entries with :math:`D^2_{nm} > \chi^2_d{}^{-1}(p_G)` are
    ``-inf``; a NaN distance (non-finite measurement or prediction) is ``-inf`` with or without a
    gate.  (No gate-probability renormalisation is applied; that is the caller's model.)
    """
    d = innov.z_pred.shape[-1]
    kind = _KERNEL_KINDS.get(type(meas)) if numerics.JIT else None
    if kind is not None and len(innov) and Z.shape[0]:  # compiled: the same arithmetic, value by value
        g = math.inf if gate_prob is None else gate_threshold(gate_prob, d)
        return _kernels.loglik_dense(innov.z_pred, innov.S_inv, innov.log_det_S, _c(Z),
                                     kind == _kernels.KIND_BEARING_RANGE, g, _LOG_2PI)
    D2 = mahalanobis_matrix(meas, innov, Z)
    out = -0.5 * (D2 + (d * _LOG_2PI + innov.log_det_S)[:, None])
    if gate_prob is not None:
        out[~(D2 <= gate_threshold(gate_prob, d))] = -np.inf  # a NaN distance is outside the gate
    else:
        out[np.isnan(D2)] = -np.inf
    return out


def update_means(meas, innov: Innovation, m_pred: np.ndarray, Z: np.ndarray) -> np.ndarray:
    r"""Updated means for every pair, ``(N, M, n)``:

    .. math:: m^+_{nm} = m_n + K_n (z_m \ominus \hat z_n)

    The matching covariance is ``innov.P_upd[n]`` for every ``m``.
    """
    return m_pred[:, None, :] + _residuals(meas, innov, Z) @ _T(innov.gain)


def update_pairs(meas, innov: Innovation, m_pred: np.ndarray, Z: np.ndarray,
                 track_idx: np.ndarray, meas_idx: np.ndarray) -> np.ndarray:
    r"""Updated means for selected pairs only, ``(L, n)``:

    .. math:: m^+_l = m_{t_l} + K_{t_l} (z_{j_l} \ominus \hat z_{t_l})

    ``track_idx``, ``meas_idx``: integer arrays of length ``L``.  Covariances are
    ``innov.P_upd[track_idx]``.
    """
    kind = _KERNEL_KINDS.get(type(meas)) if numerics.JIT else None
    if kind is not None and m_pred.shape[0] and Z.shape[0]:
        return _kernels.update_pairs_kernel(_c(m_pred), innov.gain, innov.z_pred, _c(Z),
                                            np.asarray(track_idx, np.int64), np.asarray(meas_idx, np.int64),
                                            kind == _kernels.KIND_BEARING_RANGE)
    r = meas.residual(Z[meas_idx], innov.z_pred[track_idx])
    return m_pred[track_idx] + (innov.gain[track_idx] @ r[:, :, None])[:, :, 0]


def kalman_update(meas, innov: Innovation, m_pred: np.ndarray, z: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    r"""Update each track with its own measurement: ``z (N, d)`` -> ``(m^+ (N, n), P^+
    (N, n, n))``,

    .. math:: m^+_n = m_n + K_n (z_n \ominus \hat z_n), \qquad P^+_n = P_n - K_n S_n K_n^T

    Convenience wrapper; ``z`` may also be a single ``(d,)`` measurement when ``N == 1``.
    ``P^+`` is a writable copy of ``innov.P_upd``.
    """
    z = np.asarray(z, dtype=float).reshape(len(innov), innov.dim)
    r = meas.residual(z, innov.z_pred)
    m_upd = m_pred + (innov.gain @ r[:, :, None])[:, :, 0]
    return m_upd, innov.P_upd.copy()


SCIPY_PAIRS = 20_000
"""Track x measurement pairs of a frame from which the trackers use scipy: above it the gate
is found with a KD-tree (``scipy.spatial``, :func:`gated_log_likelihood`; below, every pair is
evaluated densely: the same values) and the JPDA* assignment is solved per connected component
(``scipy.sparse.csgraph``, :func:`tracker.bnp.assignment.best_permutation_pairs`)."""


def _angle_dims(meas, d: int) -> np.ndarray:
    """Components that ``meas.residual`` wraps (a residual of 2 pi reads as 0 there)."""
    r = meas.residual(np.full((1, d), 2.0 * np.pi), np.zeros((1, d)))[0]
    return np.flatnonzero(np.abs(r) < 1e-9)


def _gate_candidates(meas, innov: Innovation, Z: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Candidate (track, measurement) pairs, a superset of the gate: a KD-tree over the
    measurements scaled per component, queried with each track's ball
    :math:`\\sqrt{g\\,\\lambda_{max}(D^{-1} S_n D^{-1})}` around :math:`\\hat z_n`; wrapped
    components are queried at :math:`\\hat z_n \\pm 2\\pi` too when the ball crosses :math:`\\pm\\pi`."""
    from scipy.spatial import cKDTree  # lazy: only the trackers' hot path needs it

    N, d = innov.z_pred.shape
    ok_z = np.flatnonzero(np.isfinite(Z).all(axis=1))
    ok_t = np.flatnonzero(np.isfinite(innov.z_pred).all(axis=1) & np.isfinite(innov.S).all(axis=(1, 2)))
    if ok_z.size == 0 or ok_t.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    scale = np.sqrt(np.maximum(np.median(np.diagonal(innov.S[ok_t], axis1=1, axis2=2), axis=0), 1e-300))
    Sn = innov.S[ok_t] / (scale[:, None] * scale[None, :])
    radius = np.sqrt(g * np.linalg.eigvalsh(Sn)[:, -1]) * (1.0 + 1e-9) + 1e-12
    centres, owner, radii = [innov.z_pred[ok_t]], [ok_t], [radius]
    for i in _angle_dims(meas, d):
        for shift in (-2.0 * np.pi, 2.0 * np.pi):
            c = innov.z_pred[ok_t].copy()
            c[:, i] += shift
            near = np.abs(c[:, i]) - radius * scale[i] <= np.pi
            centres.append(c[near]), owner.append(ok_t[near]), radii.append(radius[near])
    tree = cKDTree(Z[ok_z] / scale)
    hits = tree.query_ball_point(np.concatenate(centres) / scale, np.concatenate(radii), return_sorted=False)
    lens = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))
    ti = np.repeat(np.concatenate(owner), lens)
    mi = ok_z[np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=int(lens.sum()))]
    return ti, mi


def gated_log_likelihood(meas, innov: Innovation, Z: np.ndarray, gate_prob: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""The finite entries of :func:`log_likelihood_matrix` with a gate, found without
    forming the ``(N, M)`` matrix: ``(track_idx, meas_idx, log_lik)`` sorted by measurement,
    then track (the order of ``np.nonzero`` on the transposed matrix).

    Candidates come from a KD-tree over the measurements (:func:`_gate_candidates`, a
    superset of every gate); each is kept when :math:`D^2_{nm} \le \chi^2_d{}^{-1}(p_G)`, the
    same test as the dense matrix.  Cost ~ (N + M) log M + pairs in gates.
    """
    N, d = innov.z_pred.shape
    kind = _KERNEL_KINDS.get(type(meas)) if numerics.JIT else None
    if kind is not None and N * Z.shape[0] <= SCIPY_PAIRS:  # small frames: every pair, compiled
        return _kernels.loglik_gated(innov.z_pred, innov.S_inv, innov.log_det_S, _c(Z),
                                     kind == _kernels.KIND_BEARING_RANGE, gate_threshold(gate_prob, d), _LOG_2PI)
    if N * Z.shape[0] <= SCIPY_PAIRS:  # small frames: the dense matrix is cheaper than a tree
        dense = log_likelihood_matrix(meas, innov, Z, gate_prob)
        mi, ti = np.nonzero(np.isfinite(dense.T))
        return ti.astype(np.int64), mi.astype(np.int64), dense[ti, mi]
    g = gate_threshold(gate_prob, d)
    ti, mi = _gate_candidates(meas, innov, Z, g)
    if ti.size:
        key = numerics.unique_ints(mi * N + ti)  # sorted by measurement, then track; images deduplicated
        mi, ti = key // N, key % N
    r = meas.residual(Z[mi], innov.z_pred[ti])
    D2 = np.sum((r[:, None, :] @ innov.S_inv[ti])[:, 0, :] * r, axis=-1)
    keep = D2 <= g
    ti, mi = ti[keep], mi[keep]
    ll = -0.5 * (D2[keep] + (d * _LOG_2PI + innov.log_det_S[ti]))  # same rounding as the dense matrix
    return ti.astype(np.int64), mi.astype(np.int64), ll
