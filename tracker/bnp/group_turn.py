r"""The turn rate in the object -> cluster membership (session 9, helper "cross";
``GroupConfig.member_turn``).

The two-level tracker shares each cluster's turn rate among its members (:func:`tracker.bnp.groups.share_turn`:
:math:`\omega_\ell \sim \mathcal N(\omega_c, s_\omega^2)`, ``turn_within_std_deg``, part of
:math:`f(x_\ell \mid \theta_c)` in eqs. (2), (4) [state1, state2]) but, before this module, the
membership evidence (the collapsed Gibbs of eqs. (13)-(14) [posttheta, Gibbs]) held only the
velocity and the centroid.  Two objects whose turn rates are confidently different could then
join one cluster on position and velocity alone, and the sharing pulled their turn rates
together (the crossing pairs of the ``random`` scenes: docs/trackers.md, "Session 9: cross").
The model says every part of :math:`\theta` a member shares is evidence of membership, so
:func:`turn_block` adds the turn-rate part to the conjugate predictive:

.. math::

   p(\omega_\ell \mid \text{table } t) = \mathcal N\big(\hat\omega_\ell;\ \hat\omega_t^{-\ell},\
       \mathrm{Var}(\omega_t^{-\ell}) + P_{\omega,\ell} + s_\omega^2\big),

with :math:`P_{\omega,\ell}` the object's own turn-rate variance (a young or uncertain object's
turn rate is weak evidence, a confident one strong).  The prior of :math:`\omega_t` is the
object level's base distribution :math:`H` on the turn rate, :math:`\mathcal N(0, \sigma_{\omega,H}^2)`
(``objects.birth_turn_std_deg``), for a new cluster (case D3) **and for a transitioned one**
(case D2): the cluster's turn rate is not carried from frame to frame (the kernel
:math:`\varphi` of eq. (8) [HH] resets its turn-rate part to :math:`H`), a departure that keeps
:class:`tracker.bnp.groups.GroupState` unchanged; a table's turn rate is informed by the members
chosen this frame.

The part is one-dimensional; the partition kernel works on 2-vectors, so the second coordinate
is a constant known exactly (value 0, prior variance :data:`_KNOWN`, member variance 1): its
predictive factor is the same for every table and cancels in the conditional.
"""

from __future__ import annotations

import numpy as np

__all__ = ["turn_block"]

#: Prior variance of the exactly known dummy coordinate (information 1e12 against a member's 1).
_KNOWN = 1e-12


def turn_block(omega: np.ndarray, var: np.ndarray, n_tables: int, within_var: float, h_var: float) -> tuple:
    r"""The turn-rate part of :math:`\theta`, the fields of a :class:`tracker.bnp.groups.Block`
    ``(v, R, prior_mean, prior_cov, h_mean, h_cov)`` for :func:`tracker.bnp.groups.sample_partition`.

    ``omega`` (L,), ``var`` (L,): the members' turn-rate estimates and variances (rad/s);
    ``n_tables``: the transitioned clusters (G); ``within_var`` :math:`s_\omega^2`; ``h_var``
    :math:`\sigma_{\omega,H}^2`, the prior of every table's turn rate (new and transitioned).
    """
    L = omega.shape[0]
    v = np.zeros((L, 2))
    v[:, 0] = omega
    R = np.zeros((L, 2, 2))
    R[:, 0, 0] = var + within_var
    R[:, 1, 1] = 1.0
    h_cov = np.diag([h_var, _KNOWN])
    prior_cov = np.broadcast_to(h_cov, (n_tables, 2, 2)).copy()
    return v, R, np.zeros((n_tables, 2)), prior_cov, np.zeros(2), h_cov
