r"""DDP-EMM and DPY-STP: streaming Gibbs trackers that keep their Markov prior across frames.

``BnpTracker.step(state, frame, rng) -> (state, estimate)`` is a pure function of its inputs.
The state (:class:`BnpState`) is plain data: one row per cluster (object) with its label,
Gaussian state, existence probability and popularity, plus the hyperparameters.  One frame:

1. **Transition** (Algorithm 1, step 2): each cluster survives with :math:`P_S`
   (:math:`q_l = P_S r_l`), its parameter moves through the transition kernel
   :math:`\varphi` = the coordinated-turn model (UKF or EKF prediction), and its popularity
   carries forward with decay :math:`\rho` (``popularity_decay``).
2. **Association** (Algorithm 2, eq. (13)-(14)): collapsed Gibbs sweeps over measurement
   assignments with the dependent Polya-urn weights of cases D1-D3 / P1-P3
   (:mod:`tracker.gibbs`), the EKF/UKF predictive likelihood, :math:`P_D`, and Poisson clutter.
3. **Update**: each cluster's existence is its Gibbs-averaged detection probability plus the
   missed-detection term; its Gaussian is moment-matched over "missed" and "detected by the
   measurement it takes in the most probable one-to-one assignment" (JPDA*; or over every
   measurement, ``state_update = "mixture"``).  Each measurement that opened a new cluster in
   some sweeps starts a cluster from the base distribution :math:`H` conditioned on it
   (case D3/P3), with existence equal to that probability.
4. **Hyperparameters**: :math:`(\alpha, d)` on a grid: the Gamma priors times each frame's
   Poisson-urn likelihood of its last Gibbs sample, accumulated with forgetting; the next frame
   uses the posterior mean (or one draw, ``hyper_estimate = "sample"``).

``docs/trackers.md`` maps every term of the paper to this code and lists the choices made
where the paper is silent.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Annotated, Literal

import msgspec
import numpy as np

from tracker import filtering as kf
from tracker.base import BaseDistribution
from tracker.gibbs import CLUTTER, NEW, GibbsProblem, run_gibbs
from tracker.models.params import ModelParams
from tracker.types import Estimate, Frame, TrackEstimate, check_finite_rows, frame_dt
from tracker.urn import ALPHA_GRID, D_GRID, frame_loglik_grid, grid_mean, log_gamma_prior, sample_grid

_EPS = 1e-12
_FORBIDDEN = 1e6  # assignment cost of an impossible pair

Prob = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
OpenProb = Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)]
Positive = Annotated[float, msgspec.Meta(gt=0.0)]


class BnpConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of the DDP-EMM / DPY-STP trackers (model physics live in ``ModelParams``)."""

    sweeps: Annotated[int, msgspec.Meta(ge=1)] = 30
    """Gibbs sweeps per chain and frame (including burn-in)."""
    burn_in: Annotated[int, msgspec.Meta(ge=0)] = 5
    swap_moves: bool = True
    """After each single-site sweep, propose exchanging the assignments of every pair of
    measurements that share a gated cluster (Metropolis-Hastings, exact joint ratio)."""
    chains: Annotated[int, msgspec.Meta(ge=1, le=8)] = 2
    """Gibbs chains per frame, each of ``sweeps`` sweeps, from the greedy and the reversed
    greedy start; their average gives the marginals, their spread the R-hat diagnostic."""
    filter: Literal["ukf", "ekf"] = "ukf"
    gate_prob: OpenProb = 0.9999
    """Chi-square gate on the predictive density; pairs outside are impossible."""
    existence_threshold: Prob = 0.35
    """Clusters with existence above this are reported as tracks."""
    prune_threshold: Prob = 1e-3
    """Clusters whose existence is below ``min(prune_threshold, birth_prune_fraction * p_birth)``
    are dropped; ``p_birth`` is the probability that a measurement far from every cluster
    opens a new one (``BnpTracker.birth_probability``).  Tying the floor to ``p_birth`` means
    no fixed threshold can stop births, however dense the clutter."""
    birth_prune_fraction: Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)] = 0.1
    """A cluster is kept while its existence is at least this fraction of ``p_birth``: a
    newborn survives its birth frame, and is dropped after a missed first re-detection."""
    max_clusters: Annotated[int, msgspec.Meta(ge=1)] = 200
    popularity_decay: Annotated[float, msgspec.Meta(ge=0.0, lt=1.0)] = 0.0
    """rho: v <- max(1, rho * v + (1 - rho) * n_k).  0 carries the last frame's cardinality
    (the paper's v*_{l,k|k-1}); for point objects v = 1 whatever rho is."""
    state_update: Literal["best-permutation", "mixture"] = "best-permutation"
    """How a cluster's Gaussian takes its measurements: moment-matched over every measurement
    it may have taken ("mixture", JPDA-like), or over "missed" and the one measurement it takes
    in the most probable one-to-one assignment ("best-permutation", JPDA*), which keeps two
    clusters that share a gate from coalescing."""
    merge_distance: Annotated[float, msgspec.Meta(ge=0.0)] = 9.0
    """Clusters whose position-velocity states are within this squared Mahalanobis distance
    (summed covariances) and whose existences sum to at most 1 are one object split over
    exclusive hypotheses: they are merged (existences added).  0 disables merging."""
    birth_velocity_std: Positive = 30.0
    """Base distribution H (uniform part): velocity std (m/s) of a new cluster."""
    birth_turn_std_deg: Positive = 3.0
    """Base distribution H (uniform part): turn-rate std (deg/s) of a new cluster."""
    alpha: Positive = 0.1
    """Initial concentration alpha (kept fixed if ``infer_alpha`` is false)."""
    alpha_shape: Positive = 1.0
    alpha_scale: Positive = 0.1
    """alpha ~ Gamma(shape, scale): the paper's Gamma(1, 0.1), 0.1 read as the scale."""
    infer_alpha: bool = True
    d: Annotated[float, msgspec.Meta(ge=0.0, lt=1.0)] = 0.0
    """Pitman-Yor discount (0 = DDP-EMM)."""
    d_shape: Positive = 1.0
    d_scale: Positive = 0.1
    """d ~ Gamma(shape, scale) truncated to [0, 1)."""
    infer_d: bool = False
    hyper_estimate: Literal["mean", "sample"] = "mean"
    """What the next frame's urn uses of the grid posterior of (alpha, d): its mean
    (Rao-Blackwellised over the hyperparameter) or one draw (a plain Gibbs step)."""
    hyper_forgetting: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 0.98
    """Past frames' hyperparameter log-likelihood is multiplied by this each frame."""
    birth_lag: Annotated[int, msgspec.Meta(ge=0, le=50)] = 4
    """The hyperparameter likelihood counts the new clusters of frame ``k - birth_lag`` by their
    existence at frame ``k`` (fixed-lag smoothing): at its birth frame a new object's
    measurement is 'new' with probability ~ alpha / lambda_c, so counting that frame's sample
    would drive alpha towards 0 (see docs/trackers.md).  0 counts the current sample."""
    extended: bool = False
    """Allow several measurements per object per frame (case D1/P1); off for point objects."""

    def __post_init__(self) -> None:
        if self.burn_in >= self.sweeps:
            raise ValueError(f"burn_in ({self.burn_in}) must be smaller than sweeps ({self.sweeps})")


TRACKER_PRESETS: dict[str, BnpConfig] = {
    # Experiment 1 (DDP-EMM vs GLMB): alpha ~ Gamma(1, 0.1).
    "ddp": BnpConfig(),
    # Experiments 4-5 (DPY-STP): alpha and d ~ Gamma(1, 0.1), both inferred.
    "dpyp": BnpConfig(d=0.1, infer_d=True),
    # Experiment 2 (close proximity): alpha ~ Gamma(1, 0.3).
    "ddp-proximity": BnpConfig(alpha_scale=0.3),
    # Experiment 3 (varying SNR): alpha ~ Gamma(1, 0.2).  Range-only tracks cannot be localised
    # (position is known up to a rotation about the sensor), so they keep losing their
    # measurements to new clusters; counting the current sample's new clusters (birth_lag = 0)
    # keeps alpha high enough to re-open them (docs/trackers.md, "Births").
    "ddp-snr": BnpConfig(alpha_scale=0.2, birth_lag=0),
}


@dataclass(frozen=True)
class BnpState:
    """Everything the next frame needs, as plain arrays (snapshot with :mod:`tracker.state`).

    One row per cluster: ``labels`` (N,), ``mean`` (N, 5), ``cov`` (N, 5, 5),
    ``existence`` (N,) = Pr(object exists), ``popularity`` (N,) = decayed customer count
    :math:`v_l` (>= 1).  ``frame`` is the last frame processed (-1 before the first).
    """

    frame: int = -1
    stamp_ns: int = 0
    labels: tuple[str, ...] = ()
    mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 5, 5)))
    existence: np.ndarray = field(default_factory=lambda: np.zeros(0))
    popularity: np.ndarray = field(default_factory=lambda: np.zeros(0))
    alpha: float = 1.0
    d: float = 0.0
    hyper_loglik: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    """Accumulated (forgetting-weighted) log-likelihood of (alpha, d) on the tracker's grid."""

    @property
    def n_clusters(self) -> int:
        return len(self.labels)


@dataclass(frozen=True)
class _Prediction:
    mean: np.ndarray
    cov: np.ndarray
    q: np.ndarray  # predicted existence P_S^(dt/T) * r
    p_detect: np.ndarray


@dataclass(frozen=True)
class BnpTracker:
    """DDP-EMM (``config.d == 0`` and not ``infer_d``) or DPY-STP tracker."""

    params: ModelParams
    config: BnpConfig = BnpConfig()
    name: str = "ddp"

    @cached_property
    def motion(self):
        return self.params.motion()

    def _motion(self, dt: float):
        """The motion model over ``dt`` (the cached one at ``dt == T``)."""
        return self.motion if dt == self.params.T else self.params.motion(dt)

    @cached_property
    def base(self) -> BaseDistribution:
        cfg = self.config
        return BaseDistribution.from_params(self.params, cfg.birth_velocity_std, np.deg2rad(cfg.birth_turn_std_deg))

    def birth_probability(self, alpha: float, clutter) -> float:
        r"""``p_birth``: probability that a measurement no cluster explains opens a new one,
        :math:`\alpha w_0 u / (\lambda_c \kappa + \alpha w_0 u)` with the uniform part of
        :math:`H` (:math:`u = \kappa`, both uniform over the field of view in measurement space)."""
        new = alpha * self.base.uniform_weight
        return float(new / (clutter.rate + new)) if new > 0 else 0.0

    @cached_property
    def alpha_grid(self) -> np.ndarray:
        return ALPHA_GRID if self.config.infer_alpha else np.array([self.config.alpha])

    @cached_property
    def d_grid(self) -> np.ndarray:
        return D_GRID if self.config.infer_d else np.array([self.config.d])

    def initial_state(self) -> BnpState:
        grid = np.zeros((self.alpha_grid.size, self.d_grid.size))
        return BnpState(alpha=self.config.alpha, d=self.config.d, hyper_loglik=grid)

    # -- the step -----------------------------------------------------------------------
    def step(self, state: BnpState, frame: Frame, rng: np.random.Generator) -> tuple[BnpState, Estimate]:
        """Process one frame; returns the new state and the frame's estimate."""
        t0 = time.perf_counter()
        if frame.frame <= state.frame:
            raise ValueError(f"frame {frame.frame} is not after the last processed frame {state.frame}")
        check_finite_rows(frame.frame, frame.z)  # z may have been edited in place since construction
        dt = frame_dt(state.frame, state.stamp_ns, frame.frame, frame.stamp_ns, self.params.T)
        sensor = self.params.frame_sensor(frame)
        meas = self.params.measurement(frame.kind, sensor)
        clutter = self.params.clutter(frame.kind, sensor)
        pred = self._predict(state, dt, frame.kind, sensor)
        innov = self._innovation(meas, pred)
        problem = self._problem(state, pred, innov, meas, clutter, frame.z)
        result = run_gibbs(problem, rng, self.config.sweeps, self.config.burn_in, swaps=self.config.swap_moves,
                           chains=self.config.chains)
        existing = self._update_existing(state, pred, innov, meas, frame.z, result)
        floor = self._prune_floor(state.alpha, clutter)
        born = self._births(frame, meas, clutter, result, floor)
        kept = self._prune(merge_duplicates(_concat(existing, born), self.config.merge_distance), floor)
        alpha, d, hyper = self._hyper(rng, state, problem, result, kept, frame.frame)
        new_state = BnpState(frame.frame, frame.stamp_ns, kept.labels, kept.mean, kept.cov,
                             kept.existence, kept.popularity, alpha, d, hyper)
        est = self._estimate(new_state, frame, existing, born, result, problem)
        diagnostics = {
            "alpha": alpha, "d": d, "n_clusters": float(new_state.n_clusters),
            "p_birth": self.birth_probability(state.alpha, clutter),
            "n_tracks": float(len(est.tracks)),
            "log_joint": result.log_joint if math.isfinite(result.log_joint) else 0.0,
            "rhat_max": result.rhat_max,
            "swap_accept": result.swaps_accepted / max(result.swaps_proposed, 1),
            "ms": (time.perf_counter() - t0) * 1e3,
        }
        return new_state, Estimate(est.frame, est.stamp_ns, est.tracks, est.assignments,
                                   est.assignment_prob, diagnostics)

    # -- pieces ---------------------------------------------------------------------------
    def _predict(self, state: BnpState, dt: float, kind: str, sensor=None) -> _Prediction:
        """Transition (Algorithm 1, step 2) over ``dt`` seconds in one step: phi = the CT model
        built for ``dt`` (process noise ``Q(dt)``), q = r * P_S(x)^(dt/T) at the predicted mean."""
        m, P, q = state.mean, state.cov, state.existence
        predict = kf.ukf_predict if self.config.filter == "ukf" else kf.ekf_predict
        if state.n_clusters:
            m, P = predict(self._motion(dt), m, P)
            q = q * self.params.survival_over(m, dt, kind, sensor)
        p_detect = self.params.detection(kind, sensor).prob(m) if len(m) else np.zeros(0)
        return _Prediction(m, P, q, p_detect)

    def _innovation(self, meas, pred: _Prediction):
        if self.config.filter == "ukf":
            return kf.ukf_innovation(meas, pred.mean, pred.cov)
        return kf.ekf_innovation(meas, pred.mean, pred.cov)

    def _problem(self, state, pred, innov, meas, clutter, Z) -> GibbsProblem:
        cfg = self.config
        M = Z.shape[0]
        log_lik = kf.log_likelihood_matrix(meas, innov, Z, cfg.gate_prob) if len(pred.mean) else np.zeros((0, M))
        pd = np.clip(pred.p_detect, 0.0, 1.0 - 1e-9)
        q = np.clip(pred.q, 0.0, 1.0)
        miss = np.maximum(q * (1.0 - pd) + 1.0 - q, _EPS)
        with np.errstate(divide="ignore"):
            log_det = np.log(q) + np.log(pd) - np.log(miss) + np.log(state.popularity - state.d)
        log_first = log_det[:, None] + log_lik
        return GibbsProblem(
            mass=float(np.sum(q * state.popularity)),
            log_first=log_first,
            log_lik=log_lik,
            log_clutter=np.full(M, clutter.log_intensity),
            log_new=self.base.log_predictive(meas, clutter, Z),
            popularity=state.popularity,
            alpha=state.alpha,
            d=state.d,
            d_bar=float(q.sum()),
            extended=cfg.extended,
        )

    def _update_existing(self, state, pred, innov, meas, Z, result) -> "_Clusters":
        N = state.n_clusters
        if N == 0:
            return _Clusters.empty()
        p_lm = result.p_cluster  # (N, M)
        p_det = np.clip(p_lm.sum(axis=1), 0.0, 1.0)
        pd = pred.p_detect
        q = pred.q
        miss_alive = q * (1.0 - pd)
        eps_alive = miss_alive / np.maximum(miss_alive + 1.0 - q, _EPS)
        w_miss = (1.0 - p_det) * eps_alive
        r = np.clip(p_det + w_miss, 0.0, 1.0)
        # moment-matched mixture (conditional on existence) of missed + each detection
        if self.config.state_update == "best-permutation" and p_lm.size:
            p_lm = best_permutation(p_lm)
        mean, cov = _moment_match(meas, innov, pred, Z, w_miss, p_lm, r)
        n_expected = p_det / np.maximum(r, _EPS)  # E[customers this frame | alive]
        rho = self.config.popularity_decay
        pop = np.maximum(rho * state.popularity + (1.0 - rho) * n_expected, 1.0)
        return _Clusters(state.labels, mean, cov, r, pop)

    def _prune_floor(self, alpha: float, clutter) -> float:
        """Existence below which a cluster is dropped (``BnpConfig.prune_threshold``)."""
        cfg = self.config
        p_birth = self.birth_probability(alpha, clutter)
        return min(cfg.prune_threshold, cfg.birth_prune_fraction * p_birth) if p_birth > 0 else cfg.prune_threshold

    def _births(self, frame: Frame, meas, clutter, result, floor: float) -> "_Clusters":
        """New clusters (case D3/P3): every measurement whose Rao-Blackwellised probability of
        opening one is above the prune floor (a fraction of ``p_birth``, never a fixed cut)."""
        p_new = result.p_new
        idx = np.flatnonzero(p_new >= max(floor, 1e-300))
        if idx.size == 0:
            return _Clusters.empty()
        mean, cov = self.base.posterior(meas, clutter, frame.z[idx], frame.kind)
        labels = tuple(f"{frame.frame}.{m}" for m in idx.tolist())
        return _Clusters(labels, mean, cov, p_new[idx], np.ones(idx.size))

    def _prune(self, c: "_Clusters", floor: float) -> "_Clusters":
        keep = np.flatnonzero(c.existence >= floor)
        if keep.size > self.config.max_clusters:
            order = np.argsort(-c.existence[keep], kind="stable")
            keep = np.sort(keep[order[: self.config.max_clusters]])
        return c.take(keep)

    def _hyper(self, rng, state: BnpState, problem: GibbsProblem, result, kept: "_Clusters",
               frame: int) -> tuple[float, float, np.ndarray]:
        """Grid-Gibbs step for (alpha, d) given this frame's last Gibbs sample.

        The log-likelihood of past frames is kept on the grid (with forgetting), so the
        posterior accumulates over the stream; see :func:`tracker.urn.frame_loglik_grid`.
        """
        cfg = self.config
        if not cfg.infer_alpha and not cfg.infer_d:
            return state.alpha, state.d, state.hyper_loglik
        last = result.last
        counts = np.bincount(last[last >= 0], minlength=state.n_clusters)
        n_new_sample = int(np.sum(last == NEW))
        n_new = n_new_sample if cfg.birth_lag == 0 else _born_at(kept, frame - cfg.birth_lag)
        frame_ll = frame_loglik_grid(
            self.alpha_grid[:, None], self.d_grid[None, :],
            mass=problem.mass, d_bar=problem.d_bar,
            n_object=int(np.sum(last != CLUTTER)) - n_new_sample + n_new, n_new=n_new,
            seated_popularity=state.popularity, seated_counts=counts,
        )
        hyper = cfg.hyper_forgetting * state.hyper_loglik + frame_ll
        # log-spaced alpha grid: cell width is proportional to alpha (Jacobian term log alpha)
        log_prior_a = log_gamma_prior(self.alpha_grid, cfg.alpha_shape, cfg.alpha_scale) + np.log(self.alpha_grid)
        log_post = hyper + log_prior_a[:, None]
        if cfg.infer_d:
            log_post = log_post + log_gamma_prior(np.maximum(self.d_grid, 1e-12), cfg.d_shape, cfg.d_scale)[None, :]
        if cfg.hyper_estimate == "sample":
            i, j = sample_grid(rng, log_post)
            return float(self.alpha_grid[i]), float(self.d_grid[j]), hyper
        alpha, d = grid_mean(log_post, self.alpha_grid, self.d_grid)
        return alpha, d, hyper

    def _estimate(self, state: BnpState, frame: Frame, existing, born, result, problem) -> Estimate:
        thr = self.config.existence_threshold
        reported = {lab for lab, r in zip(state.labels, state.existence) if r > thr}
        tracks = tuple(
            TrackEstimate(lab, state.mean[i].copy(), state.cov[i].copy(), float(state.existence[i]))
            for i, lab in enumerate(state.labels) if lab in reported
        )
        M = frame.n_measurements
        # options per measurement: reported transitioned clusters, and its own newborn if reported
        ex_labels = np.array(existing.labels, dtype=object)
        ex_rep = np.array([lab in reported for lab in existing.labels], dtype=bool)
        p_opts = result.p_cluster[ex_rep] if ex_rep.any() else np.zeros((0, M))
        lab_opts = ex_labels[ex_rep]
        born_p = np.zeros(M)
        born_lab = np.full(M, None, dtype=object)
        for lab in born.labels:
            if lab in reported:
                m = int(lab.split(".")[1])
                born_p[m], born_lab[m] = result.p_new[m], lab
        p_all = np.vstack([p_opts, born_p[None]])  # (R+1, M)
        best = np.argmax(p_all, axis=0)
        p_best = p_all[best, np.arange(M)]
        p_none = np.clip(1.0 - p_all.sum(axis=0), 0.0, 1.0)
        assignments: list[str | None] = []
        probs: list[float] = []
        for m in range(M):
            if p_best[m] <= p_none[m]:
                assignments.append(None)
                probs.append(float(p_none[m]))
            else:
                b = int(best[m])
                assignments.append(lab_opts[b] if b < lab_opts.size else born_lab[m])
                probs.append(float(p_best[m]))
        return Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assignments), tuple(probs))


def _moment_match(meas, innov, pred: _Prediction, Z: np.ndarray, w_miss: np.ndarray, p_lm: np.ndarray,
                  r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cluster's Gaussian moment-matched over "missed" (weight ``w_miss / r``) and
    "updated with ``z_m``" (weight ``p_lm / r``), computed only for the pairs that carry
    weight: a pair the sampler never used (gated out, or a non-finite measurement) never
    enters the arithmetic, so no ``0 * NaN`` can reach a state."""
    inv_r = 1.0 / np.maximum(r, _EPS)
    w0 = w_miss * inv_r  # (N,)
    ti, mi = np.nonzero(p_lm > 0.0)
    wp = p_lm[ti, mi] * inv_r[ti]  # (L,)
    mu = kf.update_pairs(meas, innov, pred.mean, Z, ti, mi) if ti.size else np.zeros((0, pred.mean.shape[1]))
    mean = w0[:, None] * pred.mean
    np.add.at(mean, ti, wp[:, None] * mu)
    dev0 = pred.mean - mean
    dev = mu - mean[ti]
    cov = w0[:, None, None] * (pred.cov + dev0[:, :, None] * dev0[:, None, :])
    w_det = np.bincount(ti, weights=wp, minlength=len(r))
    cov += w_det[:, None, None] * innov.P_upd
    np.add.at(cov, ti, wp[:, None, None] * dev[:, :, None] * dev[:, None, :])
    return mean, 0.5 * (cov + np.swapaxes(cov, 1, 2))


@dataclass(frozen=True)
class _Clusters:
    labels: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    existence: np.ndarray
    popularity: np.ndarray

    @staticmethod
    def empty() -> "_Clusters":
        return _Clusters((), np.zeros((0, 5)), np.zeros((0, 5, 5)), np.zeros(0), np.zeros(0))

    def take(self, idx: np.ndarray) -> "_Clusters":
        return _Clusters(tuple(self.labels[i] for i in idx.tolist()), self.mean[idx], self.cov[idx],
                         self.existence[idx], self.popularity[idx])


def best_permutation(p_lm: np.ndarray) -> np.ndarray:
    r"""Move each cluster's detection probability onto one measurement: the one it takes in the
    most probable one-to-one assignment of the marginals (JPDA*, Blom & Bloem 2000).

    ``p_lm[l, m] = Pr(c_m = l)``.  The assignment maximises
    :math:`\sum_l \log p_{l, m(l)}` with "missed" (cost :math:`-\log(1 - \sum_m p_{lm})`) as
    every cluster's private alternative; a cluster the assignment leaves missed keeps its mass on
    its most likely measurement.  Row sums (detection probabilities) are unchanged.
    """
    from scipy.optimize import linear_sum_assignment  # lazy: scipy.optimize costs ~0.5 s to import

    N, M = p_lm.shape
    p_det = p_lm.sum(axis=1)
    live = np.flatnonzero(p_det > 1e-9)
    out = np.zeros_like(p_lm)
    if live.size == 0:
        return out
    L = live.size
    cost = np.full((L, M + L), _FORBIDDEN)
    with np.errstate(divide="ignore"):
        cost[:, :M] = np.minimum(-np.log(p_lm[live]), _FORBIDDEN)
        cost[np.arange(L), M + np.arange(L)] = -np.log(np.maximum(1.0 - p_det[live], 1e-300))
    rows, cols = linear_sum_assignment(cost)
    fallback = np.argmax(p_lm[live[rows]], axis=1)
    chosen = np.where(cols < M, cols, fallback)
    out[live[rows], chosen] = p_det[live[rows]]
    return out


_POS_VEL = np.array([0, 1, 2, 3])


def merge_duplicates(c: _Clusters, max_d2: float) -> _Clusters:
    r"""Merge clusters that are one object split over exclusive hypotheses.

    A measurement that a young cluster and the base distribution explain about equally well
    is shared between them, and the object's existence is split over duplicates.  Greedily, in
    order of decreasing existence, a leader absorbs every cluster whose position-velocity state
    lies within squared Mahalanobis distance ``max_d2`` of it (covariance :math:`P_i + P_j`)
    while the existences absorbed so far sum to at most 1 (existences of exclusive hypotheses
    add; two objects that both exist are never merged).  The merged cluster keeps the label of
    its oldest member (the object's identity: a newborn duplicate never renames a track, nor
    counts as a second birth of the object) and the leader's popularity, its existence is the sum, and its Gaussian is the existence-weighted
    moment match.
    """
    n = len(c.labels)
    if max_d2 <= 0.0 or n < 2:
        return c
    r = c.existence
    ii, jj = np.nonzero(np.triu(r[:, None] + r[None, :] <= 1.0, k=1))  # pairs that may both be one
    if ii.size == 0:
        return c
    diff = c.mean[ii][:, _POS_VEL] - c.mean[jj][:, _POS_VEL]
    S = (c.cov[ii] + c.cov[jj])[:, _POS_VEL][:, :, _POS_VEL]
    d2 = np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])
    near = d2 <= max_d2
    if not near.any():
        return c
    neighbours: dict[int, set[int]] = {}
    for i, j in zip(ii[near].tolist(), jj[near].tolist()):
        neighbours.setdefault(i, set()).add(j)
        neighbours.setdefault(j, set()).add(i)
    order = np.argsort(-r, kind="stable")
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    free = np.ones(n, dtype=bool)
    groups: list[list[int]] = []
    for i in order.tolist():
        if not free[i]:
            continue
        group, total = [i], r[i]
        for j in sorted(neighbours.get(i, ()), key=rank.__getitem__):  # decreasing existence
            if free[j] and total + r[j] <= 1.0:
                group.append(j)
                total += r[j]
        free[group] = False
        groups.append(group)
    return _merge_groups(c, groups)


def _merge_groups(c: _Clusters, groups: list[list[int]]) -> _Clusters:
    """One cluster per group (leader first): existences added, existence-weighted moment match."""
    leaders = np.array([g[0] for g in groups])
    mean = c.mean[leaders].copy()
    cov = c.cov[leaders].copy()
    r = c.existence[leaders].copy()
    for k, g in enumerate(groups):
        if len(g) == 1:
            continue
        w = c.existence[g]
        r[k] = w.sum()
        w = w / r[k]
        mean[k] = w @ c.mean[g]
        dev = c.mean[g] - mean[k]
        cov[k] = np.einsum("g,gij->ij", w, c.cov[g]) + np.einsum("g,gi,gj->ij", w, dev, dev)
    keep = np.argsort(leaders, kind="stable")  # keep the clusters' original order
    labels = [min((c.labels[i] for i in g), key=_birth_frame) for g in groups]
    return _Clusters(tuple(labels[k] for k in keep), mean[keep], cov[keep],
                     np.minimum(r[keep], 1.0), c.popularity[leaders[keep]])


def _birth_frame(label: str) -> int:
    """Birth frame of a cluster label ``"<frame>.<measurement>"`` (labels sort by it)."""
    head, _, _ = label.partition(".")
    return int(head) if head.lstrip("-").isdigit() else 0


def _born_at(c: _Clusters, frame: int) -> float:
    """Expected number of objects born at ``frame``: the summed existence of the clusters whose
    label (``"<birth frame>.<measurement>"``) says they were born then."""
    prefix = f"{frame}."
    return float(sum(r for lab, r in zip(c.labels, c.existence.tolist()) if lab.startswith(prefix)))


def _concat(a: _Clusters, b: _Clusters) -> _Clusters:
    return _Clusters(a.labels + b.labels, np.concatenate([a.mean, b.mean]), np.concatenate([a.cov, b.cov]),
                     np.concatenate([a.existence, b.existence]), np.concatenate([a.popularity, b.popularity]))


def make_tracker(name: str, params: ModelParams, config: BnpConfig | None = None) -> BnpTracker:
    """Build ``ddp`` (DDP-EMM) or ``dpyp`` (DPY-STP) with its preset unless ``config`` is given."""
    if name not in ("ddp", "dpyp"):
        raise ValueError(f"unknown BNP tracker {name!r} (expected 'ddp' or 'dpyp')")
    return BnpTracker(params, config if config is not None else TRACKER_PRESETS[name], name)
