"""The EKF / UKF prediction (:func:`ekf_predict`, :func:`ukf_predict`) and innovation
(:class:`Innovation`: the per-track predicted measurement, its covariance and the Kalman gain;
:func:`ekf_innovation`, :func:`ukf_innovation`) of :mod:`tracker.filtering`.  The
coordinated-turn prediction and the innovations of the bearing-range, range and xy models run
in compiled kernels (:mod:`tracker.models._kernels`), the other models in numpy."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bnptrack.tracker import numerics
from bnptrack.tracker.gaussian_batch import _c, _sym, _T
from bnptrack.tracker.models import _kernels
from bnptrack.tracker.models.measurement import BearingRange, Cartesian, RangeOnly
from bnptrack.tracker.models.motion import CoordinatedTurn
from bnptrack.tracker.unscented import UnscentedParams, _apply_rows, _weighted_cov, sigma_points, unscented_weights


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

