"""Likelihoods, gates and updates of every track/measurement pair (:mod:`tracker.filtering`):
the gate (:func:`gate_threshold`), the squared Mahalanobis distances and log likelihoods of all
pairs (:func:`mahalanobis_matrix`, :func:`log_likelihood_matrix`) or of the gated ones only,
found through each track's gate ball on large frames (:func:`gated_log_likelihood`), and the updated means
(:func:`update_means`, :func:`update_pairs`, :func:`kalman_update`)."""

from __future__ import annotations

import math
from functools import lru_cache
from itertools import chain
from statistics import NormalDist

import numpy as np

from bnptrack.tracker import numerics
from bnptrack.tracker.gaussian_batch import _c, _T
from bnptrack.tracker.kalman import _KERNEL_KINDS, Innovation
from bnptrack.tracker.models import _kernels

_LOG_2PI = float(np.log(2.0 * np.pi))


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
is found through balls (:func:`gated_log_likelihood`: a compiled grid, or ``scipy.spatial``'s
KD-tree when the kernels are off; below, every pair is evaluated densely: the same values) and the JPDA* assignment is solved per connected component
(``scipy.sparse.csgraph``, :func:`tracker.bnp.assignment.best_permutation_pairs`)."""


def _angle_dims(meas, d: int) -> np.ndarray:
    """Components that ``meas.residual`` wraps (a residual of 2 pi reads as 0 there)."""
    r = meas.residual(np.full((1, d), 2.0 * np.pi), np.zeros((1, d)))[0]
    return np.flatnonzero(np.abs(r) < 1e-9)


def _gate_balls(meas, innov: Innovation, Z: np.ndarray, g: float):
    r"""Balls holding every gate, in the measurements' coordinates scaled per component
    (``scale``): ``(scale, ok_z, centres, owner, radii)``, ball ``k`` of radius
    :math:`\sqrt{g\,\lambda_{max}(D^{-1} S_n D^{-1})}` around :math:`\hat z_n` for track
    ``owner[k]``; wrapped components get balls at :math:`\hat z_n \pm 2\pi` too when the ball
    crosses :math:`\pm\pi`.  ``ok_z``: the finite measurements; ``None`` without a finite
    measurement or track."""
    N, d = innov.z_pred.shape
    ok_z = np.flatnonzero(np.isfinite(Z).all(axis=1))
    ok_t = np.flatnonzero(np.isfinite(innov.z_pred).all(axis=1) & np.isfinite(innov.S).all(axis=(1, 2)))
    if ok_z.size == 0 or ok_t.size == 0:
        return None
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
    return scale, ok_z, np.concatenate(centres) / scale, np.concatenate(owner), np.concatenate(radii)


def _gate_candidates(meas, innov: Innovation, Z: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Candidate (track, measurement) pairs, a superset of the gate: the measurements in
    :func:`_gate_balls`' balls, found with a KD-tree over the scaled measurements."""
    from scipy.spatial import cKDTree  # lazy: only the trackers' hot path needs it

    balls = _gate_balls(meas, innov, Z, g)
    if balls is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    scale, ok_z, centres, owner, radii = balls
    tree = cKDTree(Z[ok_z] / scale)
    hits = tree.query_ball_point(centres, radii, return_sorted=False)
    lens = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))
    ti = np.repeat(owner, lens)
    mi = ok_z[np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=int(lens.sum()))]
    return ti, mi


def gated_log_likelihood(meas, innov: Innovation, Z: np.ndarray, gate_prob: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""The finite entries of :func:`log_likelihood_matrix` with a gate, found without
    forming the ``(N, M)`` matrix: ``(track_idx, meas_idx, log_lik)`` sorted by measurement,
    then track (the order of ``np.nonzero`` on the transposed matrix).

    Candidates are the measurements in each track's ball (:func:`_gate_balls`, a superset of
    its gate): compiled, through a grid over the measurements
    (:func:`tracker.models._kernels.loglik_balls`, which also computes the distances); else
    from a KD-tree (:func:`_gate_candidates`); each is kept when :math:`D^2_{nm} \le \chi^2_d{}^{-1}(p_G)`, the
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
    if kind is not None:  # compiled: the balls' measurements through a grid, the same pairs and values
        balls = _gate_balls(meas, innov, Z, g)
        if balls is None:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        scale, ok_z, centres, owner, radii = balls
        return _kernels.loglik_balls(innov.z_pred, innov.S_inv, innov.log_det_S, _c(Z),
                                     kind == _kernels.KIND_BEARING_RANGE, g, _LOG_2PI, _c(Z[ok_z] / scale), ok_z,
                                     _c(centres), owner.astype(np.int64), radii)
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
