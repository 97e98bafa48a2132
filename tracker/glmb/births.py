"""The GLMB's labeled multi-Bernoulli births: static regions and measurement-driven
(adaptive) births."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bnptrack.tracker.types import STATE_DIM


@dataclass(frozen=True)
class _Births:
    """Birth Bernoullis of one frame: labels, existence ``r`` (B,), Gaussians."""

    labels: tuple[str, ...]
    r: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    n_adaptive: int = 0


def adaptive_birth_existence(r_u: np.ndarray, rate: float, r_max: float, max_births: int,
                             min_share: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Existence of the adaptive births (Reuter, Vo, Vo & Dietmayer 2014, "The labeled
    multi-Bernoulli filter", adaptive birth procedure):

    .. math:: r_B(z) = \min\Big(r_{B,\max},\ \lambda_B \frac{1 - r_U(z)}{\sum_{z'} (1 - r_U(z'))}\Big)

    for the measurements ``z`` of the previous scan, :math:`r_U(z)` the posterior probability
    that ``z`` was assigned to a track.  Bounded: only the ``max_births`` measurements with
    the largest :math:`r_B` (ties: lower index), and none whose :math:`r_B` is below
    ``min_share`` times the largest (so the set is empty only when every measurement was
    surely assigned).  Returns the kept measurement indices (increasing) and their
    :math:`r_B`.
    """
    unassigned = np.clip(1.0 - np.asarray(r_u, dtype=float), 0.0, 1.0)
    total = float(unassigned.sum())
    if total <= 0.0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    r = np.minimum(r_max, rate * unassigned / total)
    order = np.argsort(-r, kind="stable")[:max_births]
    keep = np.sort(order[(r[order] >= min_share * r[order[0]]) & (r[order] > 0.0)])
    return keep.astype(np.int64), r[keep]


def measurement_state_prior(pos: np.ndarray, pos_cov: np.ndarray, velocity_std: float,
                            turn_std: float) -> tuple[np.ndarray, np.ndarray]:
    """State ``(M, 5)`` and covariance ``(M, 5, 5)`` of objects seen at ``pos`` ``(M, 2)`` with
    covariance ``pos_cov`` ``(M, 2, 2)`` (the sensor's inverse model): zero-mean velocity with
    std ``velocity_std`` per axis and zero-mean turn rate with std ``turn_std``, independent."""
    n = pos.shape[0]
    mean = np.zeros((n, STATE_DIM))
    mean[:, 0], mean[:, 2] = pos[:, 0], pos[:, 1]
    cov = np.zeros((n, STATE_DIM, STATE_DIM))
    ix = np.ix_(np.arange(n), [0, 2], [0, 2])
    cov[ix] = pos_cov
    cov[:, 1, 1] = cov[:, 3, 3] = velocity_std**2
    cov[:, 4, 4] = turn_std**2
    return mean, cov
