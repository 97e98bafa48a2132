r"""Which members receive the velocity sharing (``GroupConfig.share_min_info``).

The sharing (:func:`tracker.bnp.group_share.share_velocity`) gives member :math:`\ell` a Kalman
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

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.bnp.group_fma import sum2
from bnptrack.tracker.bnp.group_sample import Shares

__all__ = ["informed", "own_update", "restrict", "share_turn", "share_velocity", "together_scans"]


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
    """The rows of a :class:`tracker.bnp.group_sample.Shares` (object index ``obj``, (P,)) whose object
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


def share_velocity(mean: np.ndarray, cov: np.ndarray, shares: Shares, S_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Each member's state given the others' assignments: a Kalman pseudo-measurement of its velocity
    per option, moment-matched over the options.

    Option :math:`o` of object :math:`\ell` (weight :math:`w_o`, the Gibbs conditional of eq.
    (Gibbs)): the pseudo-measurement :math:`y = \hat\theta_o^{-\ell}` of :math:`H x = (v_x, v_y)`
    with covariance :math:`S_w + \mathrm{Cov}(\theta_o^{-\ell})`.  Since the weight already
    carries :math:`\mathcal N(\hat v_\ell; \hat\theta_o^{-\ell}, \mathrm{Cov}(\theta_o^{-\ell}) + P_{v,\ell} + S_w)`,
    the mixture is the exact conditional :math:`p(x_\ell \mid \text{others})`.  A new
    cluster's option (prior :math:`H_2`, vague) barely moves the state.  ``mean`` (L, 5), ``cov`` (L, 5, 5).
    """
    if shares.obj.size == 0:
        return mean, cov
    return _share_velocity_kernel(mean, cov, shares.obj, S_w, shares.mu, shares.cov, shares.w)


def _share_velocity_kernel(mean, cov, o, S_w, s_mu, s_cov, w):  # pragma: no cover - compiled
    """:func:`share_velocity`'s gains compiled, as its numpy code computed them: ``P = cov[o]``,
    ``PHt = P[:, :, _VEL]``, ``Si = inv2(P_vv + S_w + s_cov)``
    (:func:`tracker.bnp.group_theta.inv2`: entries over the determinant), ``K = PHt @ Si`` and ``KHP = K @ PHt'`` (numpy's stacked matmul: each entry
    :func:`tracker.bnp.group_fma.sum2`); then :func:`_share_moments`."""
    Q = o.size
    m, P = np.empty((Q, 5)), np.empty((Q, 5, 5))
    K, KHP = np.empty((Q, 5, 2)), np.empty((Q, 5, 5))
    A, Si = np.empty((2, 2)), np.empty((2, 2))
    vel = (1, 3)
    for q in range(Q):
        for i in range(5):  # not m[q] = mean[o[q]]: a slice assignment compiles numba's string code
            m[q, i] = mean[o[q], i]
            for j in range(5):
                P[q, i, j] = cov[o[q], i, j]
        for i in range(2):
            for j in range(2):
                A[i, j] = (P[q, vel[i], vel[j]] + S_w[i, j]) + s_cov[q, i, j]
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        Si[0, 0], Si[1, 1] = A[1, 1] / det, A[0, 0] / det
        Si[0, 1], Si[1, 0] = -A[0, 1] / det, -A[1, 0] / det
        for i in range(5):
            for j in range(2):
                K[q, i, j] = sum2(P[q, i, 1], Si[0, j], P[q, i, 3], Si[1, j])
        for i in range(5):
            for j in range(5):
                KHP[q, i, j] = sum2(K[q, i, 0], P[q, j, 1], K[q, i, 1], P[q, j, 3])
    return _share_moments(mean.shape[0], m, P, K, KHP, s_mu, w, o)


def _share_moments(N, m, P, K, KHP, s_mu, w, o):  # pragma: no cover - compiled
    """:func:`share_velocity`'s update and moment match after its gains ``K`` (Q, 5, 2) and
    ``KHP`` = K (P H')' (Q, 5, 5): ``mu = m + K (s_mu - H m)`` (the product as ``np.einsum``:
    from 0.0 in index order), ``Pu = P - KHP``; the mixture's mean and covariance per object,
    added in option order (``np.add.at``), then symmetrised.  Returns ``(N, 5)``, ``(N, 5, 5)``."""
    Q = o.size
    mu = np.empty((Q, 5))
    for q in range(Q):
        d0, d1 = s_mu[q, 0] - m[q, 1], s_mu[q, 1] - m[q, 3]
        for i in range(5):
            mu[q, i] = m[q, i] + (0.0 + K[q, i, 0] * d0 + K[q, i, 1] * d1)
    new_mean = np.zeros((N, 5))
    for q in range(Q):
        for i in range(5):
            new_mean[o[q], i] += w[q] * mu[q, i]
    new_cov = np.zeros((N, 5, 5))
    dev = np.empty(5)
    for q in range(Q):
        for i in range(5):
            dev[i] = mu[q, i] - new_mean[o[q], i]
        for i in range(5):
            for j in range(5):
                new_cov[o[q], i, j] += w[q] * ((P[q, i, j] - KHP[q, i, j]) + dev[i] * dev[j])
    sym = np.empty((N, 5, 5))
    for n in range(N):
        for i in range(5):
            for j in range(5):
                sym[n, i, j] = 0.5 * (new_cov[n, i, j] + new_cov[n, j, i])
    return new_mean, sym


_share_moments = jit(_share_moments, kernels_only=True)
_share_velocity_kernel = jit(_share_velocity_kernel)


def share_turn(mean: np.ndarray, cov: np.ndarray, omega: np.ndarray, var: np.ndarray, z: np.ndarray,
               within_var: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Each member's turn rate takes its cluster's leave-one-out turn rate as a pseudo-measurement.

    The members of a cluster share one turn rate (``groups`` scene; part of theta in eq. (2)
    [state1]); given the sample ``z``, member :math:`\ell`'s pseudo-measurement of :math:`x_4` is the
    information-weighted mean of the *other* members' turn rates ``omega`` (variances ``var``,
    flat prior), variance :math:`1/\sum_{j \ne \ell} \mathrm{var}_j^{-1}` + ``within_var``.
    A member alone takes none.  ``mean`` (L, 5), ``cov`` (L, 5, 5)."""
    if z.size < 2:
        return mean, cov
    new_mean, new_cov, shared = _share_turn_kernel(mean, cov, omega, var, z, float(within_var))
    return (new_mean, new_cov) if shared else (mean, cov)


def _share_turn_kernel(mean, cov, omega, var, z, within_var):  # pragma: no cover - compiled
    """:func:`share_turn` compiled: the information sums per cluster added in member order from
    0.0 (``np.bincount``), then each member with other members' information (> 0) updated as a
    scalar Kalman step on ``x_4``, its covariance symmetrised.  The third output: any updated."""
    L = z.size
    info, im = np.empty(L), np.empty(L)
    n_tables = 0
    for l in range(L):
        info[l] = 1.0 / var[l]
        im[l] = info[l] * omega[l]
        n_tables = max(n_tables, z[l] + 1)
    s_i, s_m = np.zeros(n_tables), np.zeros(n_tables)
    for l in range(L):
        s_i[z[l]] += info[l]
        s_m[z[l]] += im[l]
    out_mean, out_cov = mean.copy(), cov.copy()
    K, Pu = np.empty(5), np.empty((5, 5))
    shared = False
    for l in range(L):
        tot_i = s_i[z[l]] - info[l]
        if not tot_i > 0:
            continue
        shared = True
        y = (s_m[z[l]] - im[l]) / tot_i
        r = 1.0 / tot_i + within_var
        for i in range(5):
            K[i] = cov[l, i, 4] / (cov[l, 4, 4] + r)
            out_mean[l, i] = mean[l, i] + K[i] * (y - mean[l, 4])
        for i in range(5):
            for j in range(5):
                Pu[i, j] = cov[l, i, j] - K[i] * cov[l, 4, j]
        for i in range(5):
            for j in range(5):
                out_cov[l, i, j] = 0.5 * (Pu[i, j] + Pu[j, i])
    return out_mean, out_cov, shared


_share_turn_kernel = jit(_share_turn_kernel)


def together_scans(cluster: np.ndarray, previous_cluster: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """(L,) consecutive scans each member has sat in its cluster with at least one other member
    (``share_after``): ``previous + 1`` when its cluster id ``cluster`` is last scan's
    (``previous_cluster``) and holds another member, 1 when it holds another member but is not
    last scan's, else 0 (``previous``: last scan's counts, -1 or None: none)."""
    if cluster.size == 0:
        return np.zeros(0, dtype=np.int64)
    _, inverse, counts = np.unique(cluster, return_inverse=True, return_counts=True)
    shared = counts[inverse] >= 2
    before = np.zeros(cluster.size, dtype=np.int64) if previous is None else np.maximum(previous, 0)
    stay = shared & (cluster == previous_cluster)
    return np.where(stay, before + 1, np.where(shared, 1, 0)).astype(np.int64)
