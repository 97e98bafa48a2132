"""Compiled pass of the births (:mod:`tracker.bnp.base_measure`): the moments of each
measurement's posterior mixture (:func:`birth_moments`), bit for bit the numpy code's
(:mod:`tracker.bnp._kernels` says how)."""

from __future__ import annotations

import numpy as np

from bnptrack.tracker.numerics import jit


def birth_moments(w, mu_b, P_upd, pos, pcov, var_v, var_turn):  # pragma: no cover - compiled
    """``BaseDistribution.posterior``'s moment match of each measurement's mixture: components
    ``b < B`` (updated means ``mu_b[b, m]``, covariance ``P_upd[b]``) and the uniform part (last
    row of ``w``: position ``pos[m]`` with covariance ``pcov[m]``, velocity variance ``var_v``
    per axis, turn-rate variance ``var_turn``), with weights ``w (B + 1, M)`` summed over ``b``
    in order as ``np.einsum`` does; ``w`` with no rows: the uniform part alone."""
    B, M = mu_b.shape[0], pos.shape[0]
    mean_u = np.zeros((M, 5))
    cov_u = np.zeros((M, 5, 5))
    for m in range(M):
        mean_u[m, 0], mean_u[m, 2] = pos[m, 0], pos[m, 1]
        cov_u[m, 0, 0], cov_u[m, 0, 2] = pcov[m, 0, 0], pcov[m, 0, 1]
        cov_u[m, 2, 0], cov_u[m, 2, 2] = pcov[m, 1, 0], pcov[m, 1, 1]
        cov_u[m, 1, 1] = var_v
        cov_u[m, 3, 3] = var_v
        cov_u[m, 4, 4] = var_turn
    if w.shape[0] == 0:
        return mean_u, cov_u
    mean = np.zeros((M, 5))
    for b in range(B + 1):
        for m in range(M):
            for i in range(5):
                mean[m, i] += w[b, m] * (mu_b[b, m, i] if b < B else mean_u[m, i])
    cov_w = np.zeros((M, 5, 5))
    cov_d = np.zeros((M, 5, 5))
    dev = np.empty(5)
    for b in range(B + 1):
        for m in range(M):
            for i in range(5):
                dev[i] = (mu_b[b, m, i] if b < B else mean_u[m, i]) - mean[m, i]
            for i in range(5):
                for j in range(5):
                    cov_w[m, i, j] += w[b, m] * (P_upd[b, i, j] if b < B else cov_u[m, i, j])
                    cov_d[m, i, j] += w[b, m] * dev[i] * dev[j]
    out = np.empty((M, 5, 5))
    for m in range(M):
        for i in range(5):
            for j in range(5):
                out[m, i, j] = 0.5 * ((cov_w[m, i, j] + cov_d[m, i, j]) + (cov_w[m, j, i] + cov_d[m, j, i]))
    return mean, out


birth_moments = jit(birth_moments)
