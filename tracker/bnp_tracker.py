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

import logging
import math
from itertools import chain
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Annotated, Literal

import msgspec
import numpy as np

from tracker import filtering as kf
from tracker.base import BaseDistribution
from tracker.gibbs import CLUTTER, NEW, GibbsProblem, SparsePairs, run_gibbs
from tracker.models.params import ModelParams
from tracker.types import Estimate, Frame, TrackEstimate, check_finite_rows, frame_dt
from tracker.urn import ALPHA_GRID, D_GRID, frame_loglik_grid, grid_mean, log_gamma_prior, sample_grid

_EPS = 1e-12
_FORBIDDEN = 1e6  # assignment cost of an impossible pair
_log = logging.getLogger(__name__)

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
    max_clusters: Annotated[int, msgspec.Meta(ge=1)] = 100_000
    """Memory guard, not a model setting: at most this many clusters are kept (highest
    existence first).  Far above any scene's object count (clutter-born tentative clusters
    included); when it bites, the step's diagnostics report ``clusters_capped`` (> 0) and one
    warning is logged (once per process)."""
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
        kept, capped = self._prune(merge_duplicates(_concat(existing, born), self.config.merge_distance), floor)
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
            "clusters_capped": float(capped),
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
        if len(pred.mean):  # gated pairs only (KD-tree), never the (N, M) matrix
            ti, mi, log_lik = kf.gated_log_likelihood(meas, innov, Z, cfg.gate_prob)
        else:
            ti, mi, log_lik = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        pd = np.clip(pred.p_detect, 0.0, 1.0 - 1e-9)
        q = np.clip(pred.q, 0.0, 1.0)
        miss = np.maximum(q * (1.0 - pd) + 1.0 - q, _EPS)
        with np.errstate(divide="ignore"):
            log_det = np.log(q) + np.log(pd) - np.log(miss) + np.log(state.popularity - state.d)
        pairs = SparsePairs.from_pairs(len(pred.mean), M, ti, mi, log_det[ti] + log_lik, log_lik)
        return GibbsProblem(
            mass=float(np.sum(q * state.popularity)),
            log_first=None,
            log_lik=None,
            pairs=pairs,
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
        ti, mi, p = _pairs_by_cluster(result)
        p_det = np.clip(np.bincount(ti, weights=p, minlength=N), 0.0, 1.0)
        pd = pred.p_detect
        q = pred.q
        miss_alive = q * (1.0 - pd)
        eps_alive = miss_alive / np.maximum(miss_alive + 1.0 - q, _EPS)
        w_miss = (1.0 - p_det) * eps_alive
        r = np.clip(p_det + w_miss, 0.0, 1.0)
        # moment-matched mixture (conditional on existence) of missed + each detection
        if self.config.state_update == "best-permutation" and p.size:
            ti, mi, p = best_permutation_pairs(N, ti, mi, p)
        mean, cov = _moment_match(meas, innov, pred, Z, w_miss, ti, mi, p, r)
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

    def _prune(self, c: "_Clusters", floor: float) -> tuple["_Clusters", int]:
        """Drop clusters below ``floor``; keep at most ``max_clusters`` (the memory guard).
        Returns the kept clusters and how many the guard dropped (0 unless it bit)."""
        keep = np.flatnonzero(c.existence >= floor)
        capped = max(keep.size - self.config.max_clusters, 0)
        if capped:
            order = np.argsort(-c.existence[keep], kind="stable")
            keep = np.sort(keep[order[: self.config.max_clusters]])
            _warn_capped(self.config.max_clusters, capped)
        return c.take(keep), capped

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
        ex_rep = np.array([lab in reported for lab in existing.labels], dtype=bool)
        p_ex, lab_ex, p_sum = _best_reported(result, ex_rep, existing.labels, M)
        born_p = np.zeros(M)
        born_lab = np.full(M, None, dtype=object)
        for lab in born.labels:
            if lab in reported:
                m = int(lab.split(".")[1])
                born_p[m], born_lab[m] = result.p_new[m], lab
        use_born = born_p > p_ex  # on a tie the transitioned cluster wins
        p_best = np.where(use_born, born_p, p_ex)
        p_none = np.clip(1.0 - (p_sum + born_p), 0.0, 1.0)
        assignments: list[str | None] = []
        probs: list[float] = []
        for m in range(M):
            if p_best[m] <= p_none[m]:
                assignments.append(None)
                probs.append(float(p_none[m]))
            else:
                assignments.append(born_lab[m] if use_born[m] else lab_ex[m])
                probs.append(float(p_best[m]))
        return Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assignments), tuple(probs))


def _best_reported(result, rep: np.ndarray, labels: tuple[str, ...], M: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per measurement: the largest ``Pr(c_m = l)`` over reported clusters ``l`` (the lowest
    index on a tie), that cluster's label (None if none) and the sum over reported clusters."""
    pr = result.pairs
    mt = pr.rows
    sel = rep[pr.idx] if pr.idx.size else np.zeros(0, dtype=bool)
    t, m, p = pr.idx[sel], mt[sel], result.p_pairs[sel]
    p_sum = np.bincount(m, weights=p, minlength=M)
    p_ex = np.zeros(M)
    lab = np.full(M, None, dtype=object)
    if t.size:
        order = np.lexsort((t, -p, m))
        first = order[np.r_[True, np.diff(m[order]) != 0]]
        p_ex[m[first]] = p[first]
        lab[m[first]] = [labels[i] for i in t[first].tolist()]
    return p_ex, lab, p_sum


def _pairs_by_cluster(result) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sampler's gated pairs and ``Pr(c_m = l)``, sorted by cluster then measurement."""
    pr = result.pairs
    mt = pr.rows
    order = np.lexsort((mt, pr.idx))
    return pr.idx[order], mt[order], result.p_pairs[order]


_capped_warned: list[bool] = []


def _warn_capped(limit: int, dropped: int) -> None:
    if not _capped_warned:
        _capped_warned.append(True)
        _log.warning("max_clusters (%d) reached: %d cluster(s) with the lowest existence dropped "
                     "(reported once; see the step diagnostics' clusters_capped)", limit, dropped)


def _moment_match(meas, innov, pred: _Prediction, Z: np.ndarray, w_miss: np.ndarray, ti: np.ndarray,
                  mi: np.ndarray, p: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cluster's Gaussian moment-matched over "missed" (weight ``w_miss / r``) and
    "updated with ``z_m``" (weight ``p / r`` for the pairs ``(ti, mi)``, sorted by cluster then
    measurement), computed only for the pairs that carry
    weight: a pair the sampler never used (gated out, or a non-finite measurement) never
    enters the arithmetic, so no ``0 * NaN`` can reach a state."""
    inv_r = 1.0 / np.maximum(r, _EPS)
    w0 = w_miss * inv_r  # (N,)
    carry = p > 0.0
    ti, mi = ti[carry], mi[carry]
    wp = p[carry] * inv_r[ti]  # (L,)
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
    r"""Dense form of :func:`best_permutation_pairs`: ``(N, M)`` marginals in, ``(N, M)`` out."""
    N, M = p_lm.shape
    ti, mi = np.nonzero(p_lm > 0.0)
    t, m, p = best_permutation_pairs(N, ti, mi, p_lm[ti, mi])
    out = np.zeros_like(p_lm)
    out[t, m] = p
    return out


def best_permutation_pairs(n: int, ti: np.ndarray, mi: np.ndarray, p: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Move each cluster's detection probability onto one measurement: the one it takes in the
    most probable one-to-one assignment of the marginals (JPDA*, Blom & Bloem 2000).

    ``p[j] = Pr(c_{mi_j} = ti_j)`` for the gated pairs (``n`` clusters).  The assignment
    maximises :math:`\sum_l \log p_{l, m(l)}` with "missed" (cost
    :math:`-\log(1 - \sum_m p_{lm})`) as every cluster's private alternative; a cluster the
    assignment leaves missed keeps its mass on its most likely measurement.  Row sums
    (detection probabilities) are unchanged.  The problem separates over the connected
    components of the pairs graph: a component with one cluster needs no solver (either
    way its mass goes to its most likely measurement), the others are solved one by one
    (``linear_sum_assignment``), so the cost follows the size of the groups, not N x M.
    Returns one pair per cluster that has any mass, sorted by cluster.
    """
    p_det = np.bincount(ti, weights=p, minlength=n)
    live = (p > 0.0) & (p_det[ti] > 1e-9)
    ti, mi, p = ti[live], mi[live], p[live]
    if ti.size == 0:
        return ti, mi, p
    order = np.lexsort((mi, -p, ti))  # per cluster: most likely measurement first (lowest m on ties)
    first = order[np.r_[True, np.diff(ti[order]) != 0]]
    clusters, choice = ti[first], mi[first].copy()
    _solve_shared(n, ti, mi, p, p_det, clusters, choice)
    return clusters, choice, p_det[clusters]


def _solve_shared(n, ti, mi, p, p_det, clusters, choice) -> None:
    """Per connected component with two or more clusters, the JPDA* assignment (updates
    ``choice``, aligned with the sorted ``clusters``)."""
    from scipy.optimize import linear_sum_assignment  # lazy: scipy.optimize costs ~0.5 s to import

    if np.unique(choice).size == choice.size:
        return  # no two clusters prefer one measurement: each keeps its own
    M = int(mi.max()) + 1
    if clusters.size * M <= 20_000:  # small: one assignment over every live cluster
        pos = np.searchsorted(clusters, ti)
        r_idx = np.unique(pos, return_inverse=True)[1]
        cols, c_idx = np.unique(mi, return_inverse=True)
        _solve_block(r_idx, c_idx, pos, mi, p, p_det[ti], choice, linear_sum_assignment)
        return
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(ti.size), (ti, n + mi)), shape=(n + M, n + M))
    _, comp = connected_components(graph, directed=False)
    # a component whose clusters' most likely measurements are all different is solved by
    # them (a lower bound every cluster attains; a missed cluster keeps that measurement too)
    key = comp[clusters] * M + choice
    uniq, count = np.unique(key, return_counts=True)
    conflict = np.zeros(comp.max() + 1, dtype=bool)
    conflict[uniq[count > 1] // M] = True
    shared = conflict[comp[ti]]
    if not shared.any():
        return
    ts, ms, ps = ti[shared], mi[shared], p[shared]
    cs = comp[ts]
    order = np.lexsort((ts, cs))
    ts, ms, ps, cs = ts[order], ms[order], ps[order], cs[order]
    starts = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
    row = _local_rank(cs * n + ts, starts, cs[starts] * n)  # 0.. within each component
    col = _local_rank(cs * M + ms, starts, cs[starts] * M)
    pos = np.searchsorted(clusters, ts)  # where each edge's cluster sits in ``clusters``
    pd_edge = p_det[ts]
    for a, b in zip(starts.tolist(), np.r_[starts[1:], ts.size].tolist()):
        _solve_block(row[a:b], col[a:b], pos[a:b], ms[a:b], ps[a:b], pd_edge[a:b], choice, linear_sum_assignment)


def _solve_block(r_idx, c_idx, pos, meas, p, p_det, choice, lsa) -> None:
    """One JPDA* assignment over a block of edges (local row/column indices ``r_idx``,
    ``c_idx``; ``pos`` the edge's place in ``choice``, ``meas`` its measurement, ``p_det`` its
    cluster's detection probability): "missed" is each cluster's private column."""
    L, C = int(r_idx.max()) + 1, int(c_idx.max()) + 1
    rows = np.zeros(L, dtype=np.int64)
    rows[r_idx] = pos
    cols = np.zeros(C, dtype=np.int64)
    cols[c_idx] = meas
    miss = np.zeros(L)
    miss[r_idx] = -np.log(np.maximum(1.0 - p_det, 1e-300))
    cost = np.full((L, C + L), _FORBIDDEN)
    cost[r_idx, c_idx] = np.minimum(-np.log(p), _FORBIDDEN)
    cost[np.arange(L), C + np.arange(L)] = miss
    rr, cc = lsa(cost)
    hit = cc < C  # missed: keeps its most likely measurement (already in choice)
    choice[rows[rr[hit]]] = cols[cc[hit]]


def _local_rank(key: np.ndarray, starts: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Dense rank of ``key`` within each group (the groups are the runs beginning at
    ``starts``; a group's keys all lie in ``[base, next group's base)``)."""
    uniq, inv = np.unique(key, return_inverse=True)
    first = np.searchsorted(uniq, base)  # rank of each group's smallest key
    grp = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, key.size]))
    return inv - first[grp]


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
    ii, jj = _near_pairs(c, max_d2)
    both = r[ii] + r[jj] <= 1.0  # pairs that may both be one
    ii, jj = ii[both], jj[both]
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
    groups: list[list[int]] = []  # groups of two or more; every other cluster stays as it is
    for i in sorted(neighbours, key=rank.__getitem__):
        if not free[i]:
            continue
        group, total = [i], r[i]
        for j in sorted(neighbours[i], key=rank.__getitem__):  # decreasing existence
            if free[j] and total + r[j] <= 1.0:
                group.append(j)
                total += r[j]
        free[group] = False
        if len(group) > 1:
            groups.append(group)
    return _merge_groups(c, groups) if groups else c


def _near_pairs(c: _Clusters, max_d2: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Pairs ``i < j`` that can be within ``max_d2`` (a superset, from a KD-tree on positions).

    The position-velocity distance is at least the position-only one, which is at least
    :math:`\lVert \Delta p \rVert^2 / (\lambda_i + \lambda_j)` with :math:`\lambda` the
    largest eigenvalue of a cluster's position covariance; so pair ``(i, j)`` is a candidate
    only if :math:`\lVert \Delta p\rVert^2 \le d^2_{max} (\lambda_i + \lambda_j) \le 2 d^2_{max}
    \max(\lambda_i, \lambda_j)`: each cluster queries the ball of radius
    :math:`\sqrt{2 d^2_{max} \lambda_i}`, which holds every partner with a smaller :math:`\lambda`."""
    from scipy.spatial import cKDTree

    n = len(c.labels)
    if n <= 200:  # few clusters: every pair (cheaper than a tree)
        lo, hi = np.triu_indices(n, k=1)
        return lo.astype(np.int64), hi.astype(np.int64)
    pos = c.mean[:, [0, 2]]
    a, b, d = c.cov[:, 0, 0], c.cov[:, 2, 2], c.cov[:, 0, 2]
    lam = 0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + d * d)
    ok = np.flatnonzero(np.isfinite(pos).all(axis=1) & np.isfinite(lam))
    if ok.size < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    radius = np.sqrt(2.0 * max_d2 * lam[ok]) * (1.0 + 1e-9)
    hits = cKDTree(pos[ok]).query_ball_point(pos[ok], radius, return_sorted=False)
    lens = np.fromiter(map(len, hits), dtype=np.int64, count=len(hits))
    i = ok[np.repeat(np.arange(ok.size), lens)]
    j = ok[np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=int(lens.sum()))]
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    key = np.unique(lo[lo < hi] * len(c.labels) + hi[lo < hi])
    lo, hi = key // len(c.labels), key % len(c.labels)
    d2p = np.sum((pos[lo] - pos[hi]) ** 2, axis=1)
    near = d2p <= max_d2 * (lam[lo] + lam[hi]) * (1.0 + 1e-9)
    return lo[near], hi[near]


def _merge_groups(c: _Clusters, groups: list[list[int]]) -> _Clusters:
    """Each group (leader first) becomes one cluster in its leader's place: existences added,
    existence-weighted moment match, the oldest member's label; the other clusters are kept."""
    n = len(c.labels)
    mean, cov, r = c.mean.copy(), c.cov.copy(), c.existence.copy()
    labels = list(c.labels)
    leaders = np.array([g[0] for g in groups])
    members = np.concatenate([np.asarray(g) for g in groups])
    gk = np.repeat(leaders, [len(g) for g in groups])  # member -> its leader
    w = c.existence[members]
    r[leaders] = np.bincount(gk, weights=w, minlength=n)[leaders]
    w = w / r[gk]
    mean[leaders] = 0.0
    np.add.at(mean, gk, w[:, None] * c.mean[members])
    dev = c.mean[members] - mean[gk]
    cov[leaders] = 0.0
    np.add.at(cov, gk, w[:, None, None] * (c.cov[members] + dev[:, :, None] * dev[:, None, :]))
    for g in groups:
        labels[g[0]] = min((c.labels[i] for i in g), key=_birth_frame)
    keep = np.setdiff1d(np.arange(n), np.concatenate([np.asarray(g[1:]) for g in groups]))
    return _Clusters(tuple(labels[k] for k in keep.tolist()), mean[keep], cov[keep],
                     np.minimum(r[keep], 1.0), c.popularity[keep])


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
