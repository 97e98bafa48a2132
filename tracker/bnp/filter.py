r"""The DDP-EMM / DPY-STP tracker: :class:`BnpTracker` and its pure ``step(state, frame, rng)``."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from bnptrack.tracker import filtering as kf
from bnptrack.tracker.bnp import _estimate_kernels as _est
from bnptrack.tracker.bnp import _update_kernels as _upd
from bnptrack.tracker.bnp.assignment import best_permutation_pairs
from bnptrack.tracker.bnp.base_measure import BaseDistribution
from bnptrack.tracker.bnp.clusters import _Clusters, _concat, merge_duplicates
from bnptrack.tracker.bnp.config import TRACKER_PRESETS, BnpConfig
from bnptrack.tracker.bnp.gibbs import CLUTTER, NEW, GibbsProblem, SparsePairs, run_gibbs
from bnptrack.tracker.bnp.urn import ALPHA_GRID, D_GRID, frame_loglik_grid, grid_mean, log_gamma_prior, sample_grid
from bnptrack.tracker.calibration import CalibrationFields, calibrate, from_config
from bnptrack.tracker.cardinality import TAIL
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, check_finite_rows, frame_dt

_EPS = 1e-12
_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BnpState(CalibrationFields):
    """Everything the next frame needs, as plain arrays (snapshot with :mod:`tracker.state`).

    One row per cluster: ``labels`` (N,), ``mean`` (N, 5), ``cov`` (N, 5, 5),
    ``existence`` (N,) = Pr(object exists), ``popularity`` (N,) = decayed customer count
    :math:`v_l` (>= 1).  ``frame`` is the last frame processed (-1 before the first).  The
    published existence's calibration state: the inherited ``cal_*`` fields.
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
    """Single-level DDP-EMM (``config.d == 0`` and not ``infer_d``) or DPY-STP tracker
    (``ddp-mb`` / ``dpyp-mb``; also the two-level tracker's object level)."""

    params: ModelParams
    config: BnpConfig = BnpConfig()
    name: str = "ddp-mb"

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

    @cached_property
    def _log_prior_alpha(self) -> np.ndarray:
        """Log prior of alpha on its grid; the grid is log-spaced, so a cell's width is
        proportional to alpha (Jacobian term log alpha)."""
        cfg = self.config
        return log_gamma_prior(self.alpha_grid, cfg.alpha_shape, cfg.alpha_scale) + np.log(self.alpha_grid)

    @cached_property
    def _log_prior_d(self) -> np.ndarray:
        cfg = self.config
        return log_gamma_prior(np.maximum(self.d_grid, 1e-12), cfg.d_shape, cfg.d_scale)

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
        sensor, meas, clutter, detection = self._sensor_models(frame)
        pred = self._predict(state, dt, frame.kind, sensor, detection)
        innov = self._innovation(meas, pred)
        log_w = self.base.log_weights(meas, clutter, frame.z)  # the base measure's terms, for the sampler and births
        problem = self._problem(state, pred, innov, meas, clutter, frame.z, log_w)
        result = run_gibbs(problem, rng, self.config.sweeps, self.config.burn_in, swaps=self.config.swap_moves,
                           chains=self.config.chains)
        existing = self._update_existing(state, pred, innov, meas, frame.z, result)
        floor = self._prune_floor(state.alpha, clutter)
        born = self._births(frame, meas, clutter, result, floor, log_w, problem.log_new)
        kept, capped = self._prune(merge_duplicates(_concat(existing, born), self.config.merge_distance), floor)
        alpha, d, hyper = self._hyper(rng, state, problem, result, kept, frame.frame, dt)
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
        est = Estimate(est.frame, est.stamp_ns, est.tracks, est.assignments, est.assignment_prob, diagnostics,
                       _cardinality(new_state.existence))
        return calibrate(self.calibration, state, new_state, est)

    @cached_property
    def calibration(self):
        """The published existence's calibration (:mod:`tracker.calibration`; None: off)."""
        return from_config(self.params, self.config)

    # -- pieces ---------------------------------------------------------------------------
    @cached_property
    def _model_cache(self) -> dict:
        return {}

    def _sensor_models(self, frame: Frame) -> tuple:
        """The frame's sensor and its measurement, clutter and detection models, built once per
        sensor set-up (name, kind, pose, R: what :meth:`ModelParams.frame_sensor` reads) and
        reused while frames keep it (the last set-up only; as the GLMB's): the models' cached
        properties (clutter volume, ``R``) are then computed once per run, not per frame."""
        key = (frame.sensor, frame.kind, frame.pose, None if frame.R is None else np.asarray(frame.R).tobytes())
        hit = self._model_cache.get(key)
        if hit is None:
            sensor = self.params.frame_sensor(frame)
            hit = (sensor, self.params.measurement(frame.kind, sensor), self.params.clutter(frame.kind, sensor),
                   self.params.detection(frame.kind, sensor))
            self._model_cache.clear()
            self._model_cache[key] = hit
        return hit

    def _predict(self, state: BnpState, dt: float, kind: str, sensor=None, detection=None) -> _Prediction:
        """Transition (Algorithm 1, step 2) over ``dt`` seconds in one step: phi = the CT model
        built for ``dt`` (process noise ``Q(dt)``), q = r * P_S(x)^(dt/T) at the predicted mean.
        ``detection``: the sensor's detection model (built here when not given)."""
        m, P, q = state.mean, state.cov, state.existence
        predict = kf.ukf_predict if self.config.filter == "ukf" else kf.ekf_predict
        if detection is None:
            detection = self.params.detection(kind, sensor)
        if not state.n_clusters:
            return _Prediction(m, P, q, np.zeros(0))
        m, P = predict(self._motion(dt), m, P)
        visible = detection.visible(m)  # one field-of-view test for P_S and P_D
        q = q * self.params.survival_over(m, dt, kind, sensor, visible)
        return _Prediction(m, P, q, np.where(visible, detection.p_detect_effective, 0.0))

    def _innovation(self, meas, pred: _Prediction):
        if self.config.filter == "ukf":
            return kf.ukf_innovation(meas, pred.mean, pred.cov)
        return kf.ekf_innovation(meas, pred.mean, pred.cov)

    def _problem(self, state, pred, innov, meas, clutter, Z, log_w=None) -> GibbsProblem:
        """The frame's sampler inputs; ``log_w``: the base measure's :meth:`log_weights` of
        ``Z`` (computed here when not given)."""
        cfg = self.config
        log_w = self.base.log_weights(meas, clutter, Z) if log_w is None else log_w
        M = Z.shape[0]
        if len(pred.mean):  # gated pairs only (KD-tree), never the (N, M) matrix
            ti, mi, log_lik = kf.gated_log_likelihood(meas, innov, Z, cfg.gate_prob)
        else:
            ti, mi, log_lik = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        args, q, zero = _upd.problem_log_args(pred.p_detect, pred.q, state.popularity, float(state.d), _EPS)
        logs = np.log(args)  # log q, log P_D, log miss, log(v - d) (-inf where zero)
        ptr, idx, lf, ll, mass, d_bar = _upd.problem_pairs(logs, zero, q, state.popularity, ti, mi, log_lik, M)
        return GibbsProblem(
            mass=float(mass),
            log_first=None,
            log_lik=None,
            pairs=SparsePairs(len(pred.mean), ptr, idx, lf, ll),
            log_clutter=np.full(M, clutter.log_intensity),
            log_new=self.base.log_predictive(meas, clutter, Z, log_w),
            popularity=state.popularity,
            alpha=state.alpha,
            d=state.d,
            d_bar=float(d_bar),
            extended=cfg.extended,
            urn_normaliser=cfg.urn_normaliser,
        )

    def _update_existing(self, state, pred, innov, meas, Z, result) -> "_Clusters":
        N = state.n_clusters
        if N == 0:
            return _Clusters.empty()
        pr = result.pairs
        ti, mi, p, w_miss, r, pop = _upd.existence_update(pr.ptr, pr.idx, result.p_pairs, N, pred.p_detect, pred.q,
                                                        state.popularity, float(self.config.popularity_decay), _EPS)
        # moment-matched mixture (conditional on existence) of missed + each detection
        if self.config.state_update == "best-permutation" and p.size:
            ti, mi, p = best_permutation_pairs(N, ti, mi, p)
        mean, cov = _moment_match(meas, innov, pred, Z, w_miss, ti, mi, p, r, self.config.state_update == "combined")
        return _Clusters(state.labels, mean, cov, r, pop)

    def _prune_floor(self, alpha: float, clutter) -> float:
        """Existence below which a cluster is dropped (``BnpConfig.prune_threshold``)."""
        cfg = self.config
        p_birth = self.birth_probability(alpha, clutter)
        return min(cfg.prune_threshold, cfg.birth_prune_fraction * p_birth) if p_birth > 0 else cfg.prune_threshold

    def _births(self, frame: Frame, meas, clutter, result, floor: float, log_w, log_u) -> "_Clusters":
        """New clusters (case D3/P3): every measurement whose Rao-Blackwellised probability of
        opening one is above the prune floor (a fraction of ``p_birth``, never a fixed cut).
        ``log_w``, ``log_u``: the frame's base-measure terms and predictive densities."""
        p_new = result.p_new
        idx = np.flatnonzero(p_new >= max(floor, 1e-300))
        if idx.size == 0:
            return _Clusters.empty()
        mean, cov = self.base.posterior(meas, clutter, frame.z[idx], frame.kind, log_w[:, idx], log_u[idx])
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
               frame: int, dt: float) -> tuple[float, float, np.ndarray]:
        """Grid-Gibbs step for (alpha, d) given this frame's last Gibbs sample.

        The log-likelihood of past frames is kept on the grid (with forgetting), so the
        posterior accumulates over the stream; see :func:`tracker.bnp.urn.frame_loglik_grid`.
        """
        cfg = self.config
        if not cfg.infer_alpha and not cfg.infer_d:
            return state.alpha, state.d, state.hyper_loglik
        last = result.last
        counts = np.bincount(last[last >= 0], minlength=state.n_clusters)
        n_new_sample = int(np.count_nonzero(last == NEW))
        lag = cfg.birth_lag  # frames (prev - lag, k - lag]: each counted once however numbers skip
        n_new = n_new_sample if lag == 0 else _born_between(kept, state.frame - lag, frame - lag)
        frame_ll = frame_loglik_grid(
            self.alpha_grid[:, None], self.d_grid[None, :],
            mass=problem.mass, d_bar=problem.d_bar,
            n_object=int(np.count_nonzero(last != CLUTTER)) - n_new_sample + n_new, n_new=n_new,
            seated_popularity=state.popularity, seated_counts=counts, urn_normaliser=cfg.urn_normaliser,
        )
        hyper = cfg.hyper_forgetting ** (dt / self.params.T) * state.hyper_loglik + frame_ll  # forgetting per T
        log_post = hyper + self._log_prior_alpha[:, None]
        if cfg.infer_d:
            log_post = log_post + self._log_prior_d[None, :]
        if cfg.hyper_estimate == "sample":
            i, j = sample_grid(rng, log_post)
            return float(self.alpha_grid[i]), float(self.d_grid[j]), hyper
        alpha, d = grid_mean(log_post, self.alpha_grid, self.d_grid)
        return alpha, d, hyper

    def _estimate(self, state: BnpState, frame: Frame, existing, born, result, problem) -> Estimate:
        rows = (state.existence > self.config.existence_threshold).nonzero()[0]
        shown = rows.tolist()
        reported = {state.labels[i] for i in shown}
        # each track's mean and covariance: a row of one copy of the shown rows (never the state's)
        tracks = tuple(TrackEstimate(state.labels[i], m, P, r) for i, m, P, r in
                       zip(shown, state.mean[rows], state.cov[rows], state.existence[rows].tolist()))
        # options per measurement: reported transitioned clusters, and its own newborn if reported
        ex_rep = np.array([lab in reported for lab in existing.labels], dtype=bool)
        born_of = {int(lab.split(".")[1]): lab for lab in born.labels if lab in reported}
        pr = result.pairs
        choice, prob = _est.estimate_assignments(pr.ptr, pr.idx, result.p_pairs, ex_rep, result.p_new,
                                               np.fromiter(born_of, dtype=np.int64, count=len(born_of)))
        labels = existing.labels
        assignments = [None if c == -1 else (born_of[m] if c == -2 else labels[c])
                       for m, c in enumerate(choice.tolist())]
        probs = prob.tolist()
        return Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assignments), tuple(probs))


def _cardinality(existence: np.ndarray) -> np.ndarray:
    """:func:`tracker.cardinality.existence_cardinality`, compiled
    (:func:`tracker.bnp._estimate_kernels.cardinality_pmf`, the same numbers)."""
    pmf, ok = _est.cardinality_pmf(np.asarray(existence, dtype=float), TAIL)
    if not ok:
        raise ValueError("poisson_binomial: existence probabilities must be finite")
    return pmf


def _born_between(c, lo: int, hi: int) -> float:
    """Expected objects born at frames ``lo < f <= hi`` (labels ``"<f>.<m>"``): with ``lo`` the
    lag before the previous processed frame, each frame is counted once however frames skip."""
    return float(sum(r for lab, r in zip(c.labels, c.existence.tolist()) if lo < _label_frame(lab) <= hi))


@lru_cache(maxsize=1 << 14)
def _label_frame(label: str) -> int:
    """``int(label.split(".")[0])``, remembered: a cluster keeps its label for many frames."""
    return int(label.split(".")[0])


_capped_warned: list[bool] = []


def _warn_capped(limit: int, dropped: int) -> None:
    if not _capped_warned:
        _capped_warned.append(True)
        _log.warning("max_clusters (%d) reached: %d cluster(s) with the lowest existence dropped "
                     "(reported once; see the step diagnostics' clusters_capped)", limit, dropped)


def _moment_match(meas, innov, pred: _Prediction, Z: np.ndarray, w_miss: np.ndarray, ti: np.ndarray,
                  mi: np.ndarray, p: np.ndarray, r: np.ndarray, combined: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Each cluster's Gaussian moment-matched over "missed" (weight ``w_miss / r``) and
    "updated with ``z_m``" (weight ``p / r`` for the pairs ``(ti, mi)``, sorted by cluster then
    measurement), computed only for the pairs that carry
    weight: a pair the sampler never used (gated out, or a non-finite measurement) never
    enters the arithmetic, so no ``0 * NaN`` can reach a state.  ``combined``: the updates
    with ``z_m`` as one component (``BnpConfig.state_update = "combined"``)."""
    carry = p > 0.0
    ti, mi, p = ti[carry], mi[carry], p[carry]
    mu = kf.update_pairs(meas, innov, pred.mean, Z, ti, mi) if ti.size else np.zeros((0, pred.mean.shape[1]))
    match = _upd.moment_match_combined if combined else _upd.moment_match
    return match(w_miss, r, ti, p, pred.mean, pred.cov, mu, innov.P_upd, _EPS)


def make_tracker(name: str, params: ModelParams, config: BnpConfig | None = None) -> BnpTracker:
    """Build the single-level ``ddp-mb`` (DDP-EMM) or ``dpyp-mb`` (DPY-STP) with its preset
    unless ``config`` is given."""
    if name not in ("ddp-mb", "dpyp-mb"):
        raise ValueError(f"unknown BNP tracker {name!r} (single level: expected 'ddp-mb' or 'dpyp-mb')")
    return BnpTracker(params, config if config is not None else TRACKER_PRESETS[name], name)
