r"""Which members receive the velocity sharing (``GroupConfig.share_min_info``).

The sharing (:func:`tracker.bnp.groups.share_velocity`) gives member :math:`\ell` a Kalman
pseudo-measurement of its cluster's leave-one-out :math:`\theta`, with gain
:math:`K = P_{v,\ell} (P_{v,\ell} + S + \mathrm{Cov}(\theta^{-\ell}))^{-1}`: the less the object knows
of its own velocity, the more it takes its cluster's.  Its membership, though, was scored by
the predictive :math:`\mathcal N(\hat v_\ell; \hat\theta, \Sigma + P_{v,\ell} + S_w)`: the less it knows, the
weaker that evidence, so an object whose velocity is still about its birth prior
(:math:`H`'s :math:`\mathcal N(0, \sigma_{v,H}^2 I)`, 20 m/s) joins a cluster on **position alone**
and is then given the cluster's velocity almost entirely (gain 0.6-0.8).  A newborn or
unresolved object next to a crossing object takes the crossing object's velocity, and every
later membership test sees a velocity that agrees because it was copied (docs/trackers.md,
"Crossing objects").

:func:`informed` keeps the sharing to members whose own velocity information exceeds the
birth prior's by the factor ``f`` = ``share_min_info``:
:math:`\lambda_{\min}(P_{v,\ell}^{-1}) \ge f / \sigma_{v,H}^2`, i.e. the largest velocity std
at most :math:`\sigma_{v,H} / \sqrt f`; the others keep their own estimate this frame (they
stay in the partition and still inform the others' :math:`\theta`).

:func:`own_update` (``GroupConfig.membership`` / ``share_base``)
keeps a second, sharing-free estimate per object: the object level's measurement update
transplanted, in information form, from the shared state onto the object's own prediction, so
that the membership (eq. (14) [Gibbs]) can read each object's own evidence once.
"""

from __future__ import annotations

import numpy as np

from bnptrack.tracker._numerics import jit

__all__ = ["informed", "own_update", "restrict"]


def informed(cov: np.ndarray, prior_var: float, factor: float) -> np.ndarray:
    """Mask (L,): members whose velocity covariance ``cov[:, (1, 3), (1, 3)]`` has its largest
    eigenvalue at most ``prior_var / factor`` (``factor`` 0: all)."""
    if factor <= 0.0:
        return np.ones(cov.shape[0], dtype=bool)
    P = cov[:, 1:4:2, 1:4:2]
    a, b, c = P[:, 0, 0], P[:, 1, 1], P[:, 0, 1]
    largest = 0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + c * c)
    return largest <= prior_var / factor


def restrict(obj: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a :class:`tracker.bnp.groups.Shares` (object index ``obj``, (P,)) whose object
    is kept (``keep`` (L,) mask) and their objects renumbered among the kept ones: ``(rows, obj)``."""
    new = np.cumsum(keep) - 1
    rows = np.flatnonzero(keep[obj])
    return rows, new[obj[rows]]


def own_update(s_pred: tuple[np.ndarray, np.ndarray], post: tuple[np.ndarray, np.ndarray],
               o_pred: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    r"""Each object's own (sharing-free) posterior: the object level's measurement update,
    taken out of its state in information form and applied to the own estimate's prediction
    (``GroupConfig.membership = "own"``).

    The object level predicted the *shared* state to :math:`(m_s, P_s)` (``s_pred``) and
    updated it to :math:`(m, P)` (``post``: the moment-matched mixture over its measurement
    assignments, eq. (11) [likelihood]).  In information form the update added
    :math:`I_z = P^{-1} - P_s^{-1}` (the measurement's information; here its positive part,
    :math:`[\cdot]_+`: a mixture with a missed-detection branch can widen :math:`P` in a
    direction) and pulled the mean by :math:`g = P^{-1}(m - m_s)` (for a linear(ised) update
    :math:`H^T R^{-1}(z - H m_s)`).  The same information applied to the own prediction
    :math:`(m_o, P_o)` (``o_pred``):

    .. math::

        J = P_o^{-1} + I_z, \qquad
        \mu = m_o + J^{-1}\big(I_z (m_s - m_o) + g\big),

    exact for a linear model (then :math:`I_z = H^T R^{-1} H` whatever the prior), the
    linearisation point's difference otherwise.  Arrays ``(K, n)`` and ``(K, n, n)``.
    """
    c = np.ascontiguousarray
    return _own_update_kernel(c(s_pred[0]), c(s_pred[1]), c(post[0]), c(post[1]), c(o_pred[0]), c(o_pred[1]))


def _own_update_kernel(m_s, P_s, m, P, m_o, P_o):  # pragma: no cover - compiled
    """:func:`own_update` row by row (compiled); the positive part of :math:`I_z` by its
    eigen-decomposition (negative eigenvalues set to 0), the covariance symmetrised."""
    K, n = m.shape
    out_m, out_P = np.empty((K, n)), np.empty((K, n, n))
    for k in range(K):
        J = np.linalg.inv(P[k])
        D = J - np.linalg.inv(P_s[k])
        w, V = np.linalg.eigh(0.5 * (D + D.T))
        I_z = (V * np.maximum(w, 0.0)) @ V.T
        C = np.linalg.inv(np.linalg.inv(P_o[k]) + I_z)
        C = 0.5 * (C + C.T)
        out_P[k] = C
        out_m[k] = m_o[k] + C @ (I_z @ (m_s[k] - m_o[k]) + J @ (m[k] - m_s[k]))
    return out_m, out_P


_own_update_kernel = jit(_own_update_kernel)
