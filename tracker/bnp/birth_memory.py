r"""A learned base distribution :math:`H_k`: where (and how fast) objects appear, from the births so far.

The paper draws a new cluster's parameter from a fixed base distribution :math:`H` (case
D3/P3, eqs. (5)-(6), (19); :mod:`tracker.bnp.base_measure`).  In a hierarchical DP the base
measure is itself random, :math:`H \sim \mathrm{DP}(\alpha_H, H_0)`, and its posterior
predictive given the atoms drawn so far is the Polya urn (Blackwell & MacQueen 1973; Teh et
al. 2006, the HDP's top level).  Here the atoms are the birth states of the objects born so
far, :math:`b_1, \dots, b_n`; each is known only up to a Gaussian, so every atom is smoothed
by a kernel and the predictive is a DP-mixture predictive:

.. math::
    H_k(x) = \mathbb E\!\left[\frac{\alpha_H}{\alpha_H + W}\right] H_0(x)
           + \mathbb E\!\left[\frac{1}{\alpha_H + W}\right] \sum_i w_i\, \kappa(x; b_i, C_i),
    \qquad W = \sum_i w_i

* :math:`H_0` is the configured base distribution (uniform over the field of view plus the
  optional birth regions; :class:`~tracker.bnp.base_measure.BaseDistribution`).
* :math:`w_i` is birth :math:`i`'s weight: the existence of its cluster ``birth_memory_lag``
  scans after its birth (the posterior probability that it was an object, a fixed-lag smoothed
  count like the one that drives :math:`\alpha`), times the forgetting factor
  :math:`\gamma^{\Delta k}` (``birth_memory_forgetting``) for the scans since, so :math:`H_k`
  follows a scene whose entry points change.  Births with weight below :data:`MIN_WEIGHT` are
  not recorded (their kernels would carry less than 5 % of one birth).
* :math:`\kappa(x; b_i, C_i)`: a Gaussian in the 5-D state, position mean :math:`b_i`,
  position covariance :math:`C_i + s^2 I` (:math:`C_i` the uncertainty of the birth position,
  :math:`s` = ``birth_kernel_std``, the extent of an entry point), velocity
  :math:`\mathcal N(0, \sigma_v^2 I)` and turn rate :math:`\mathcal N(0, \sigma_\omega^2)` as
  the uniform part of :math:`H_0`: it learns *where* objects appear, not where they go.
* :math:`b_i, C_i`: the cluster's position at the lag, propagated back to its birth scan with
  its velocity over :math:`\tau` = lag :math:`\times T` seconds,
  :math:`b = p - \tau v`, :math:`C = J P J^T` with :math:`J = [I, -\tau I]` on (position,
  velocity): the smoothed birth position.
* :math:`\alpha_H` (the DP's concentration, in births) is inferred on the grid
  :data:`ALPHA_H_GRID` with a log-uniform prior, from the sequential predictive likelihood of
  each recorded birth under the memory before it, in measurement space where the tracker uses
  :math:`H` (:math:`u_H(z) = \int R(z|x) dH(x)`, eq. (14)):
  :math:`\ell(\alpha_H) \mathrel{+}= w_j \log\big[(\alpha_H u_{H_0}(\hat z_j)
  + \sum_i w_i u_{\kappa_i}(\hat z_j)) / (\alpha_H + W)\big]`, with :math:`\hat z_j = h(b_j)`
  the birth's predicted measurement, and forgotten like the weights.  Births that recur at
  the same places pull :math:`\alpha_H` down (the learned part dominates); births anywhere
  (``random`` scenes) push it up, and :math:`H_k \to H_0`.  The expectations above are
  under this grid posterior (the predictive averaged over :math:`\alpha_H`).

A second, optional, learned part (``learn_birth_velocity``): the newborn's velocity prior
:math:`\mathcal N(0, \sigma_v^2 I)` with :math:`\sigma_v^2` given an inverse-gamma prior of
``birth_velocity_strength`` pseudo-births at ``birth_velocity_std``, updated with the
recorded births' velocities (conjugate, per axis):
:math:`\sigma_v^2 = (n_0 \sigma_0^2 + \tfrac12 \sum_i w_i \mathbb E|v_i|^2) / (n_0 + \sum_i w_i)`.

Everything is plain arrays (:class:`BirthMemory`), carried in the tracker's state.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from bnptrack.tracker import filtering as kf
from bnptrack.tracker.numerics import logsumexp
from bnptrack.tracker.bnp.base_measure import BaseDistribution

#: Grid of the DP concentration alpha_H (in births); its prior is log-uniform on the grid.
ALPHA_H_GRID = np.geomspace(0.1, 1000.0, 41)
#: Births whose weight (existence at the lag) is below this are not recorded.
MIN_WEIGHT = 0.05
#: Recorded births whose forgotten weight falls below this are dropped.
DROP_WEIGHT = 0.01
#: At most this many recorded births are kept (the heaviest).
MAX_BIRTHS = 200


@dataclass(frozen=True)
class BirthMemory:
    """The births recorded so far: positions ``pos`` (B, 2), their covariances ``cov`` (B, 2, 2)
    (without the kernel's ``s^2 I``), weights ``weight`` (B,), the accumulated log-likelihood
    ``loglik`` of alpha_H on :data:`ALPHA_H_GRID`, and the velocity statistics
    ``vel_stats`` = (sum w, sum w E|v|^2 / 2)."""

    pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    weight: np.ndarray = field(default_factory=lambda: np.zeros(0))
    loglik: np.ndarray = field(default_factory=lambda: np.zeros(ALPHA_H_GRID.size))
    vel_stats: np.ndarray = field(default_factory=lambda: np.zeros(2))


@dataclass(frozen=True)
class BirthSettings:
    """The learning's settings (from :class:`~tracker.bnp.config.BnpConfig`)."""

    learn_where: bool
    learn_velocity: bool
    forgetting: float
    kernel_std: float
    lag: int
    velocity_std: float
    velocity_strength: float
    alpha_min: float = float(ALPHA_H_GRID[0])


def learned_share(loglik: np.ndarray, total: float, alpha_min: float = float(ALPHA_H_GRID[0])) -> float:
    r""":math:`\mathbb E[W / (\alpha_H + W)]` under the grid posterior
    :math:`p(\alpha_H) \propto e^{\ell(\alpha_H)}` (prior log-uniform on the grid's points
    :math:`\ge` ``alpha_min``): the weight of the learned part of :math:`H_k`."""
    if total <= 0.0:
        return 0.0
    lp = np.where(ALPHA_H_GRID >= alpha_min * (1 - 1e-9), loglik, -np.inf)
    post = np.exp(lp - logsumexp(lp))
    return float(np.sum(post * total / (ALPHA_H_GRID + total)))


def velocity_variance(mem: BirthMemory, s: BirthSettings) -> float:
    r"""The newborn's per-axis velocity variance: :math:`\sigma_0^2` unless velocities are
    learned, else the conjugate posterior mean of the module docstring."""
    v0 = s.velocity_std**2
    if not s.learn_velocity:
        return v0
    n0 = s.velocity_strength
    return float((n0 * v0 + mem.vel_stats[1]) / (n0 + mem.vel_stats[0]))


def kernels(pos: np.ndarray, cov: np.ndarray, kernel_std: float, var_v: float, var_turn: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' 5-D Gaussians ``(B, 5)``, ``(B, 5, 5)`` (state order px, vx, py, vy, omega)."""
    B = pos.shape[0]
    means = np.zeros((B, 5))
    means[:, 0], means[:, 2] = pos[:, 0], pos[:, 1]
    covs = np.zeros((B, 5, 5))
    p = cov + kernel_std**2 * np.eye(2)
    covs[:, 0, 0], covs[:, 0, 2], covs[:, 2, 0], covs[:, 2, 2] = p[:, 0, 0], p[:, 0, 1], p[:, 1, 0], p[:, 1, 1]
    covs[:, 1, 1] = covs[:, 3, 3] = var_v
    covs[:, 4, 4] = var_turn
    return means, covs


def learned_base(base0: BaseDistribution, mem: BirthMemory, s: BirthSettings, cache: dict | None = None
                 ) -> BaseDistribution:
    r""":math:`H_k` (module docstring) from the configured :math:`H_0` and the memory.  ``cache``
    (optional, kept by the tracker): the components' predicted measurements by component set, so a
    memory that did not change since the last frame costs no new EKF innovations (same numbers)."""
    var_v = velocity_variance(mem, s)
    base = base0 if var_v == base0.velocity_std**2 else replace(base0, velocity_std=float(np.sqrt(var_v)),
                                                                _innovations={})
    total = float(mem.weight.sum()) if s.learn_where else 0.0
    share = learned_share(mem.loglik, total, s.alpha_min)
    if share <= 0.0:
        return base
    means, covs = kernels(mem.pos, mem.cov, s.kernel_std, var_v, base.turn_std**2)
    innovations = None
    if cache is not None:
        key = (means.tobytes(), covs.tobytes(), var_v)
        if key not in cache and len(cache) >= 8:
            cache.clear()
        innovations = cache.setdefault(key, {})
    return base.mixed_with(share, mem.weight / total, means, covs, innovations)


def birth_states(labels, mean: np.ndarray, cov: np.ndarray, existence: np.ndarray, lo: int, hi: int,
                 frame: int, T: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    r"""The clusters born at frames ``lo < f <= hi`` (labels ``"<f>.<m>"``) with existence at
    least :data:`MIN_WEIGHT`, propagated back to their birth: positions ``(n, 2)``,
    covariances ``(n, 2, 2)`` (:math:`J P J^T`), weights ``(n,)`` and :math:`\mathbb E|v|^2`
    ``(n,)``, in label order."""
    rows, taus = [], []
    for i in np.flatnonzero(existence >= MIN_WEIGHT).tolist():
        born = int(labels[i].split(".", 1)[0])
        if lo < born <= hi:
            rows.append(i)
            taus.append((frame - born) * T)
    idx = np.array(rows, dtype=np.int64)
    tau = np.array(taus, dtype=float)
    m, P = mean[idx], cov[idx]
    pos = np.stack([m[:, 0] - tau * m[:, 1], m[:, 2] - tau * m[:, 3]], axis=1) if idx.size else np.zeros((0, 2))
    J = np.zeros((idx.size, 2, 5))
    J[:, 0, 0] = J[:, 1, 2] = 1.0
    J[:, 0, 1] = J[:, 1, 3] = -tau
    C = J @ P @ J.transpose(0, 2, 1)
    vel_sq = m[:, 1] ** 2 + m[:, 3] ** 2 + P[:, 1, 1] + P[:, 3, 3]
    return pos, 0.5 * (C + C.transpose(0, 2, 1)), existence[idx].astype(float), vel_sq


def birth_log_predictive(base0: BaseDistribution, mem: BirthMemory, s: BirthSettings, meas, clutter,
                         pos: np.ndarray, cov: np.ndarray) -> np.ndarray:
    r"""The urn's log predictive of one birth at ``pos`` (covariance ``cov``) for every
    :math:`\alpha_H` of the grid, in measurement space at :math:`\hat z = h(b)`:
    :math:`\log[(\alpha_H u_{H_0}(\hat z) + \sum_i w_i u_{\kappa_i}(\hat z)) / (\alpha_H + W)]`."""
    var_v = velocity_variance(mem, s)
    bm, bc = kernels(pos[None], np.zeros((1, 2, 2)), 0.0, var_v, base0.turn_std**2)
    z = kf.ekf_innovation(meas, bm, bc + 1e-9 * np.eye(5)).z_pred  # (1, d)
    log_u0 = float(base0.log_predictive(meas, clutter, z)[0])
    terms = np.log(ALPHA_H_GRID) + log_u0
    W = float(mem.weight.sum())
    if W > 0.0:
        means, covs = kernels(mem.pos, mem.cov + cov[None], s.kernel_std, var_v, base0.turn_std**2)
        ll = kf.log_likelihood_matrix(meas, kf.ekf_innovation(meas, means, covs), z)[:, 0]
        kern = float(logsumexp(np.log(mem.weight) + ll))
        terms = np.logaddexp(terms, kern)
    return terms - np.log(ALPHA_H_GRID + W)


def record(mem: BirthMemory, base0: BaseDistribution, s: BirthSettings, meas, clutter, decay: float,
           births: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> BirthMemory:
    """The memory after one frame: everything forgotten by ``decay`` (= forgetting^(dt/T)), then
    each new birth's predictive likelihood added to ``loglik`` (weighted by its weight) and the
    birth appended, in order; light and surplus births dropped."""
    pos, cov, w, vel_sq = births
    if w.size == 0 and decay == 1.0:
        return mem
    mem = BirthMemory(mem.pos, mem.cov, decay * mem.weight, decay * mem.loglik,
                      np.array([decay * mem.vel_stats[0] + w.sum(), decay * mem.vel_stats[1] + 0.5 * w @ vel_sq]))
    for j in range(w.size):
        loglik = mem.loglik + w[j] * birth_log_predictive(base0, mem, s, meas, clutter, pos[j], cov[j])
        mem = BirthMemory(np.vstack([mem.pos, pos[j:j + 1]]), np.concatenate([mem.cov, cov[j:j + 1]]),
                          np.append(mem.weight, w[j]), loglik, mem.vel_stats)
    keep = np.flatnonzero(mem.weight >= DROP_WEIGHT)
    if keep.size > MAX_BIRTHS:
        keep = np.sort(keep[np.argsort(-mem.weight[keep], kind="stable")[:MAX_BIRTHS]])
    if keep.size < mem.weight.size:
        mem = BirthMemory(mem.pos[keep], mem.cov[keep], mem.weight[keep], mem.loglik, mem.vel_stats)
    return mem
