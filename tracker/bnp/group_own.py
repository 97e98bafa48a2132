r"""An object's own track in the object -> cluster membership (session 9, helper "cross";
``GroupConfig.own_track``).

The partition's collapsed Gibbs (eqs. (13)-(14) [posttheta, Gibbs]) scores object
:math:`\ell`'s option "table :math:`t`" by the conjugate predictive
:math:`\mathcal N(\hat v_\ell;\ \hat\theta_t,\ \Sigma_t + P_{v,\ell} + S_w)`, treating the
object's velocity *estimate* :math:`\hat v_\ell` as data independent of the table's
:math:`\theta`.  That holds for another object's table.  It does not hold for the object's
**own singleton table** (the cluster it alone occupied at :math:`k-1`): that table's
:math:`\theta` is the object's own previous estimate (:math:`\Sigma_t \approx P_{v,\ell,k-1} + S_w + D`),
and the two estimates share most of their error (one track).  Counting both errors makes the
object's own past fit no better than a passing neighbour's: with the vo2017 process noise
(:math:`\sigma_a` = 5 m/s^2) a tracked object's velocity std is 6-10 m/s per axis, so
:math:`\Sigma_t + P_{v,\ell} + S_w \approx` (15 m/s)^2 per axis, and two crossing objects 20 m/s
apart join one cluster with probability 0.3-0.6, after which the sharing pulls their
velocities together and the object level swaps them (docs/trackers.md, "Session 9: cross").

The model's own statement for that option (eq. (2) [state1], the singleton's :math:`\theta`
moved by :math:`\varphi`, eq. (8) [HH]): :math:`v_{\ell,k} - v_{\ell,k-1} = \delta + \epsilon_k - \epsilon_{k-1}`
with :math:`\delta \sim \mathcal N(0, D)` (``theta_drift_std``), :math:`\epsilon \sim \mathcal N(0, S_w)`;
and the *estimates'* change over one scan has the covariance of the Kalman correction,
:math:`P_{k|k-1} - P_{k|k}` (velocity block; :math:`P_{k|k-1} \approx P_{k-1|k-1} + Q_{vv}`,
:math:`Q_{vv} = \sigma_a^2 \Delta t^2 I`, the paper's :math:`Q_u`).  So the option's predictive is

.. math::

   \mathcal N\big(\hat v_{\ell,k};\ \hat v_{\ell,k-1},\ [P_{v,k-1} + Q_{vv} - P_{v,k}]_+ + 2 S_w + D\big),

:math:`[\cdot]_+` the matrix with negative eigenvalues set to 0.  Used only while no other
object sits at that table in the sweep (then its :math:`\theta` holds only the object's past).
The mean is the previous estimate itself (the table's :math:`\hat\theta_t` is that estimate
shrunk towards :math:`H_2`'s mean 0, which is the object's own information counted as a prior).
"""

from __future__ import annotations

import numpy as np

__all__ = ["own_track_predictive"]


def own_track_predictive(prev_labels: tuple[str, ...], prev_mean: np.ndarray, prev_cov: np.ndarray,
                         labels: list[str], cov_now: np.ndarray, init: np.ndarray, count: np.ndarray,
                         q: np.ndarray, extra: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""``(table, mu, A)`` for :func:`tracker.bnp.groups.sample_partition`'s ``own``.

    ``labels`` (L,) / ``cov_now`` (L, 5, 5): the members and their updated covariances;
    ``init`` (L,): each member's table at ``k-1`` (-1: none); ``count`` (G,): the tables'
    ``v*``; ``prev_*``: the previous state's labels, means (N, 5), covariances (N, 5, 5);
    ``q`` (2, 2) = :math:`Q_{vv}`; ``extra`` (2, 2) = :math:`2 S_w + D`.  ``table[l]`` = ``init[l]`` when that table
    had ``l`` alone (``v* = 1``), else -1."""
    L = len(labels)
    table = np.full(L, -1, dtype=np.int64)
    mu, A = np.zeros((L, 2)), np.zeros((L, 2, 2))
    row = {lab: i for i, lab in enumerate(prev_labels)}
    for l, lab in enumerate(labels):
        t = int(init[l])
        if t < 0 or count[t] != 1 or lab not in row:
            continue
        i = row[lab]
        table[l] = t
        mu[l] = prev_mean[i, 1:4:2]
        change = prev_cov[i, 1:4:2, 1:4:2] + q - cov_now[l, 1:4:2, 1:4:2]
        w, V = np.linalg.eigh(0.5 * (change + change.T))
        A[l] = (V * np.maximum(w, 0.0)) @ V.T + extra
    return table, mu, A
