r"""A cluster's :math:`\theta` in the two-level tracker: conjugate Gaussian algebra on 2-vectors
(closed-form 2x2 inverses), :math:`H_2`'s parts in information form, the clusters' posteriors
carried to the next frame (:func:`theta_sums`, :func:`_transition_kernel`) and the centroid
moments of :math:`H_2` over a sensor's field of view (:func:`fov_moments`)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from bnptrack.tracker.numerics import jit

__all__ = ["fov_moments", "inv2", "inv2_const", "prior_information", "theta_posterior", "theta_sums"]


#: H_2's velocity mean (read only).
_ZERO2 = np.zeros(2)
_ZERO2.flags.writeable = False

#: Information (1/m^2 s^-2) of the flat prior on a shared theta (kappa_0 = 0): an option with no
#: other member gives a pseudo-measurement of covariance ~1e10, i.e. no sharing.
_FLAT_INFORMATION = 1e-10


# -- conjugate Gaussian algebra on 2-vectors (closed-form 2x2) --------------------------------
def inv2(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of ``(..., 2, 2)`` matrices."""
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    inv = np.empty_like(A)
    inv[..., 0, 0], inv[..., 1, 1] = A[..., 1, 1], A[..., 0, 0]
    inv[..., 0, 1], inv[..., 1, 0] = -A[..., 0, 1], -A[..., 1, 0]
    return inv / det[..., None, None], det


@lru_cache(maxsize=32)
def _inv2_of_bytes(raw: bytes) -> np.ndarray:
    return inv2(np.frombuffer(raw).reshape(2, 2))[0]


def inv2_const(A: np.ndarray) -> np.ndarray:
    """:func:`inv2`'s inverse of one 2x2 matrix that repeats from frame to frame (a prior's
    covariance), remembered by its bytes: the same numbers without recomputing them."""
    return _inv2_of_bytes(np.ascontiguousarray(A, dtype=float).tobytes()).copy()


@lru_cache(maxsize=32)
def _information_of_bytes(cov_raw: bytes | None, mean_raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    h_lam = _FLAT_INFORMATION * np.eye(2) if cov_raw is None else _inv2_of_bytes(cov_raw).copy()
    return h_lam, h_lam @ np.frombuffer(mean_raw).copy()


def prior_information(h_cov: np.ndarray | None, h_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H_2's part in information form, ``(h_lam, h_lam @ h_mean)`` with ``h_lam`` =
    :func:`inv2_const` of ``h_cov`` (``None``: the flat prior's ``_FLAT_INFORMATION * I``);
    remembered by the bytes (the same priors every frame).  The arrays are shared: read only."""
    cov_raw = None if h_cov is None else np.ascontiguousarray(h_cov, dtype=float).tobytes()
    return _information_of_bytes(cov_raw, np.ascontiguousarray(h_mean, dtype=float).tobytes())


def theta_posterior(m0: np.ndarray, C0: np.ndarray, v: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Posterior of :math:`\theta` given prior :math:`\mathcal N(m_0, C_0)` and members
    :math:`v_j \sim \mathcal N(\theta, R_j)` (``v`` (n, 2), ``R`` (n, 2, 2)):
    :math:`\Lambda = C_0^{-1} + \sum_j R_j^{-1}`, mean :math:`\Lambda^{-1}(C_0^{-1} m_0 + \sum_j R_j^{-1} v_j)`."""
    C0i, _ = inv2(C0)
    Ri, _ = inv2(R)
    lam = C0i + Ri.sum(axis=0)
    eta = C0i @ m0 + np.einsum("nij,nj->i", Ri, v)
    cov, _ = inv2(lam)
    return cov @ eta, cov


def theta_sums(R: np.ndarray, v: np.ndarray, slot: np.ndarray, n_used: int, h_lam: np.ndarray,
               h_eta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Posterior mean ``(n_used, 2)`` and covariance ``(n_used, 2, 2)`` of each used cluster's
    block of theta: ``lam = h_lam + sum R_l^-1``, ``eta = h_eta + sum R_l^-1 v_l`` over the
    members ``l`` of the cluster ``slot[l]`` (in member order), ``cov = lam^-1``, ``mean = cov eta``.
    The 2x2 inverses as :func:`tracker.bnp.group_theta.inv2` (entries over the determinant), the
    products as ``np.einsum`` (from 0.0, in index order)."""
    lam = np.empty((n_used, 2, 2))
    eta = np.empty((n_used, 2))
    for g in range(n_used):  # entry by entry: a slice assignment compiles numba's string code
        for i in range(2):
            eta[g, i] = h_eta[i]
            for j in range(2):
                lam[g, i, j] = h_lam[i, j]
    for l in range(R.shape[0]):
        a, b, c, d = R[l, 0, 0], R[l, 0, 1], R[l, 1, 0], R[l, 1, 1]
        det = a * d - b * c
        i00, i01, i10, i11 = d / det, -b / det, -c / det, a / det
        g = slot[l]
        lam[g, 0, 0] += i00
        lam[g, 0, 1] += i01
        lam[g, 1, 0] += i10
        lam[g, 1, 1] += i11
        eta[g, 0] += 0.0 + i00 * v[l, 0] + i01 * v[l, 1]
        eta[g, 1] += 0.0 + i10 * v[l, 0] + i11 * v[l, 1]
    cov = np.empty((n_used, 2, 2))
    mean = np.empty((n_used, 2))
    for g in range(n_used):
        a, b, c, d = lam[g, 0, 0], lam[g, 0, 1], lam[g, 1, 0], lam[g, 1, 1]
        det = a * d - b * c
        cov[g, 0, 0], cov[g, 0, 1], cov[g, 1, 0], cov[g, 1, 1] = d / det, -b / det, -c / det, a / det
        mean[g, 0] = 0.0 + cov[g, 0, 0] * eta[g, 0] + cov[g, 0, 1] * eta[g, 1]
        mean[g, 1] = 0.0 + cov[g, 1, 0] * eta[g, 0] + cov[g, 1, 1] * eta[g, 1]
    return mean, cov


theta_sums = jit(theta_sums, kernels_only=True)


def _transition_kernel(z, ids, v0, R0, hl0, he0, v1, R1, hl1, he1, n_blocks):  # pragma: no cover - compiled
    """:meth:`tracker.bnp.groups.GroupTracker._transition_out` compiled: the tables used by ``z`` in increasing order
    (``np.unique``), their ids ``ids[used]`` and member counts (float), and each block's theta
    posterior (:func:`theta_sums`; zeros for an absent second block)."""
    n_tab = 0
    for l in range(z.size):
        n_tab = max(n_tab, z[l] + 1)
    count_of = np.zeros(n_tab, dtype=np.int64)
    for l in range(z.size):
        count_of[z[l]] += 1
    pos = np.full(n_tab, -1, dtype=np.int64)
    n_used = np.int64(0)  # not 0: a literal start compiles theta_sums once more for n_used = Literal[int](0)
    for t in range(n_tab):
        if count_of[t] > 0:
            pos[t] = n_used
            n_used += 1
    g_ids, count = np.empty(n_used, dtype=np.int64), np.empty(n_used)
    for t in range(n_tab):
        if count_of[t] > 0:
            g_ids[pos[t]], count[pos[t]] = ids[t], count_of[t]
    slot = np.empty(z.size, dtype=np.int64)
    for l in range(z.size):
        slot[l] = pos[z[l]]
    m0, c0 = theta_sums(R0, v0, slot, n_used, hl0, he0)
    if n_blocks == 1:
        return g_ids, count, m0, c0, np.zeros((n_used, 2)), np.zeros((n_used, 2, 2))
    m1, c1 = theta_sums(R1, v1, slot, n_used, hl1, he1)
    return g_ids, count, m0, c0, m1, c1


_transition_kernel = jit(_transition_kernel)


def fov_moments(detection, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance (2, 2) of the uniform distribution over ``detection``'s field of
    view (:meth:`tracker.models.clutter.Detection.visible`), on an ``n`` x ``n`` grid of cell
    centres over the square of half-side ``range_max`` about the sensor.  A pure function of a
    frozen ``detection``: remembered (:func:`_fov_moments`; every run of an experiment builds a
    tracker, and the grid costs some 8 ms), copies returned."""
    mean, cov = _fov_moments(detection, n)
    return mean.copy(), cov.copy()


@lru_cache(maxsize=16)
def _fov_moments(detection, n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fov_moments` computed (the arrays are shared: callers copy)."""
    r = detection.range_max
    g = (np.arange(n) + 0.5) / n * 2.0 * r - r
    X, Y = np.meshgrid(detection.sensor_x + g, detection.sensor_y + g, indexing="ij")
    x = np.zeros((X.size, 4))
    x[:, 0], x[:, 2] = X.ravel(), Y.ravel()
    inside = detection.visible(x)
    pts = x[inside][:, [0, 2]]
    return pts.mean(axis=0), np.cov(pts.T, bias=True)
