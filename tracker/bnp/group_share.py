r"""Which members receive the velocity sharing (session 9, helper "cross";
``GroupConfig.share_min_info``).

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
"Session 9: cross").

:func:`informed` keeps the sharing to members whose own velocity information exceeds the
birth prior's by the factor ``f`` = ``share_min_info``:
:math:`\lambda_{\min}(P_{v,\ell}^{-1}) \ge f / \sigma_{v,H}^2`, i.e. the largest velocity std
at most :math:`\sigma_{v,H} / \sqrt f`; the others keep their own estimate this frame (they
stay in the partition and still inform the others' :math:`\theta`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["informed", "restrict"]


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
