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

This module is the entry point; the kernels sit by concern in :mod:`tracker.gaussian_batch`
(the batch layout and its check), :mod:`tracker.unscented` (the unscented transform),
:mod:`tracker.kalman` (prediction and innovation) and :mod:`tracker.gating` (likelihoods,
gates and updates of track/measurement pairs).
"""

from __future__ import annotations

from bnptrack.tracker.gaussian_batch import as_gaussian_batch
from bnptrack.tracker.gating import (SCIPY_PAIRS, gate_threshold, gated_log_likelihood, kalman_update,
                                     log_likelihood_matrix, mahalanobis_matrix, update_means, update_pairs)
from bnptrack.tracker.kalman import Innovation, ekf_innovation, ekf_predict, ukf_innovation, ukf_predict
from bnptrack.tracker.unscented import UnscentedParams, sigma_points, unscented_weights

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
    "gated_log_likelihood",
]
