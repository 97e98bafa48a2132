r"""The base distribution :math:`H` of DDP-EMM / DPY-STP: where new objects come from.

Case D3/P3 (eqs. (5)-(6), (19)) opens a new cluster with :math:`\theta \sim H`; the Gibbs
sampler needs the predictive density of a measurement under :math:`H`,
:math:`u_H(z) = \int R(z \mid x)\, dH(x)` (eq. (14)), and the new cluster's parameter is
:math:`H` conditioned on its measurement, :math:`dH_\ell \propto R(z \mid x)\, dH` (eq. (14)).

We use a birth *intensity* that is a sum of independent sources, normalised into :math:`H`:

.. math::
    H = \frac{\lambda_U}{\lambda_U + \sum_j r_j}\, \mathcal U_{\text{FOV}}
        + \sum_i \frac{r_i}{\lambda_U + \sum_j r_j}\, \mathcal N(x; \mu_i, \Sigma_i)

* :math:`\mathcal U_\text{FOV}`: positions uniform over the field of view of the frame's
  sensor (its own pose and field of view) *in measurement coordinates* (so :math:`u(z) = 1/|V|`, the clutter density), velocity
  :math:`\mathcal N(0, \sigma_v^2 I)`, turn rate :math:`\mathcal N(0, \sigma_\omega^2)`: the
  paper's uninformative choice (its NIW has a near-zero mean and a vague scale).  Objects may
  appear anywhere (case D3/P3 with no prior knowledge of where).
* :math:`\lambda_U` = ``params.anywhere_birth_rate``: expected new objects per scan appearing
  anywhere (default 0.1; the scenarios whose regions cover all their births state 0.01).
* The Gaussian components are the parameter set's optional birth regions (the labeled
  multi-Bernoulli birth of the GLMB baseline), each with its expected births per scan
  :math:`r_i`: prior knowledge of where objects appear, an informative part of :math:`H` that
  adds to the uniform part instead of replacing it.  Without regions :math:`H` is uniform.

With ``learn_births`` this :math:`H` is the base :math:`H_0` of a learned :math:`H_k` (a Polya-urn
posterior predictive over the births so far, :meth:`BaseDistribution.mixed_with` adds its
kernels): :mod:`tracker.bnp.birth_memory`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bnptrack.tracker import filtering as kf
from bnptrack.tracker.numerics import logsumexp
from bnptrack.tracker.bnp import _birth_kernels as _k
from bnptrack.tracker.models.params import ModelParams


@dataclass(frozen=True)
class BaseDistribution:
    weights: np.ndarray  # (B,) mixture weights of the Gaussian components (sum 1 - w0)
    means: np.ndarray  # (B, 5)
    covs: np.ndarray  # (B, 5, 5)
    uniform_weight: float
    velocity_std: float
    turn_std: float
    half_fov: float
    _innovations: dict = field(default_factory=dict, compare=False, repr=False)

    @staticmethod
    def from_params(params: ModelParams, velocity_std: float, turn_std: float) -> "BaseDistribution":
        """:math:`H` of ``params``: uniform weight ``birth_rate / (birth_rate + sum r)``."""
        comps = [c for c in params.birth if c.r > 0.0]
        total = params.anywhere_birth_rate + sum(c.r for c in comps)
        if not comps or total <= 0.0:
            w = np.zeros(0)
            means, covs, uniform_weight = np.zeros((0, 5)), np.zeros((0, 5, 5)), 1.0
        else:
            w = np.array([c.r for c in comps]) / total
            uniform_weight = params.anywhere_birth_rate / total
            means = np.array([c.mean for c in comps], dtype=float)
            covs = np.stack([np.diag(np.square(c.std)) for c in comps])
        return BaseDistribution(w, means, covs, float(uniform_weight), velocity_std, turn_std,
                                np.deg2rad(params.bearing_half_fov_deg))

    def mixed_with(self, share: float, weights: np.ndarray, means: np.ndarray, covs: np.ndarray,
                   innovations: dict | None = None) -> "BaseDistribution":
        r""":math:`(1 - s) H + s \sum_i w_i \mathcal N(\mu_i, \Sigma_i)` (``weights`` summing to 1,
        ``share`` = :math:`s`): the learned base distribution :math:`H_k` of
        :mod:`tracker.bnp.birth_memory`.  The new components go after this one's.
        ``innovations``: a cache of the components' predicted measurements per sensor model to
        share with other mixtures of the same components (they depend on the components only)."""
        keep = 1.0 - share
        return BaseDistribution(np.concatenate([keep * self.weights, share * weights]),
                                np.concatenate([self.means, means]), np.concatenate([self.covs, covs]),
                                keep * self.uniform_weight, self.velocity_std, self.turn_std, self.half_fov,
                                {} if innovations is None else innovations)

    def _innovation(self, meas):
        """Predicted measurements of the birth components (fixed: cached per sensor model)."""
        innov = self._innovations.get(meas)
        if innov is None:
            innov = self._innovations[meas] = kf.ekf_innovation(meas, self.means, self.covs)
        return innov

    def log_weights(self, meas, clutter, Z: np.ndarray) -> np.ndarray:
        """``(B + 1, M)``: the log of each component's term of :math:`u_H(z_m)` (weight times
        predictive density), the uniform part last."""
        M = Z.shape[0]
        uniform = np.full(M, np.log(self.uniform_weight) + clutter.log_density) if self.uniform_weight > 0 else np.full(M, -np.inf)
        if self.weights.size == 0 or M == 0:
            return uniform[None]
        ll = kf.log_likelihood_matrix(meas, self._innovation(meas), Z)  # (B, M)
        return np.vstack([np.log(self.weights)[:, None] + ll, uniform[None]])

    def log_predictive(self, meas, clutter, Z: np.ndarray, log_w: np.ndarray | None = None) -> np.ndarray:
        r""":math:`\log u_H(z_m)` for ``(M, d)`` measurements (``log_w``: their
        :meth:`log_weights`, if already computed)."""
        log_w = self.log_weights(meas, clutter, Z) if log_w is None else log_w
        return log_w[0] if log_w.shape[0] == 1 else logsumexp(log_w, axis=0)

    def posterior(self, meas, clutter, Z: np.ndarray, kind: str, log_w: np.ndarray | None = None,
                  log_u: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Moment-matched :math:`H` conditioned on each measurement: ``(M, 5)``, ``(M, 5, 5)``
        (``log_w``, ``log_u``: the measurements' :meth:`log_weights` and :meth:`log_predictive`,
        if already computed).  The mixture's moments: :func:`tracker.bnp._birth_kernels.birth_moments`."""
        if self.weights.size == 0:
            return self._uniform_posterior(meas, Z, kind)
        if log_w is None:
            log_w = self.log_weights(meas, clutter, Z)
            log_u = logsumexp(log_w, axis=0)
        w = np.ascontiguousarray(np.exp(log_w - log_u))  # (B+1, M); C order as below: one compile of the kernel
        innov = self._innovation(meas)
        mu = kf.update_means(meas, innov, self.means, Z)  # (B, M, 5)
        pos, pcov = meas.birth_position(Z)
        return _k.birth_moments(w, mu, innov.P_upd, pos, pcov, self.velocity_std**2, self.turn_std**2)

    def _uniform_posterior(self, meas, Z: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """The uniform part conditioned on each measurement: the measured position in the
        world frame (``meas.birth_position``: the sensor's pose and field of view), velocity
        and turn rate from the prior."""
        pos, pcov = meas.birth_position(Z)
        return _k.birth_moments(np.zeros((0, 0)), np.zeros((0, 0, 5)), np.zeros((0, 5, 5)), pos, pcov,
                                self.velocity_std**2, self.turn_std**2)
