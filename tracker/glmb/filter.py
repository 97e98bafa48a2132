"""The GLMB filter: :class:`GlmbTracker` and its pure ``step(state, frame, rng)``."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from bnptrack.tracker import filtering as kf
from bnptrack.tracker.numerics import logsumexp
from bnptrack.tracker.calibration import ExistenceCalibration, calibrate, from_config
from bnptrack.tracker.cardinality import truncate_tail
from bnptrack.tracker.glmb.births import _Births, adaptive_birth_existence, measurement_state_prior
from bnptrack.tracker.glmb.config import GLMB_PRESETS, GlmbConfig, GlmbModel
from bnptrack.tracker.glmb.estimate import (_Marginals, continuity_rows, estimate_from_rows, map_cardinality_rows,
                                   marginal_label_rows, marginals)
from bnptrack.tracker.glmb.children import children, pair_table
from bnptrack.tracker.glmb.gibbs import start_missed
from bnptrack.tracker.glmb.hypotheses import (_Candidates, _Children, _Update, _log, candidate_sets, eta_matrix,
                                     prune_and_cap)
from bnptrack.tracker.glmb.starts import starts
from bnptrack.tracker.glmb.state import GlmbState
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import STATE_DIM, Estimate, Frame, frame_dt


@dataclass(frozen=True)
class GlmbTracker:
    """Joint-prediction-update GLMB filter (Vo, Vo & Hoang 2017) with Gibbs truncation.

    ``params`` is a :class:`~tracker.models.params.ModelParams` or any :class:`GlmbModel`.
    """

    params: Any
    config: GlmbConfig = GlmbConfig()
    name: str = "glmb"

    @cached_property
    def motion(self):
        return self.params.motion()

    def _motion(self, dt: float):
        """The motion model over ``dt`` (the cached one at ``dt == T``)."""
        return self.motion if dt == self.params.T else self.params.motion(dt)

    @cached_property
    def birth(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Birth components: ``r`` (B,), means (B, 5), covariances (B, 5, 5)."""
        comps = self.config.birth if self.config.birth is not None else self.params.birth
        if not comps:
            return np.zeros(0), np.zeros((0, STATE_DIM)), np.zeros((0, STATE_DIM, STATE_DIM))
        r = np.array([c.r for c in comps], dtype=float)
        mean = np.array([c.mean for c in comps], dtype=float)
        cov = np.stack([np.diag(np.square(np.asarray(c.std, dtype=float))) for c in comps])
        return r, mean, cov

    @cached_property
    def birth_model(self) -> str:
        """The birth model in use (``"auto"`` resolved: adaptive without birth regions)."""
        mode = self.config.birth_model
        if mode == "auto":
            return "static" if self.birth[0].size else "adaptive"
        return mode

    def initial_state(self) -> GlmbState:
        return GlmbState()

    # -- the step -----------------------------------------------------------------------
    def step(self, state: GlmbState, frame: Frame, rng: np.random.Generator
             ) -> tuple[GlmbState, Estimate]:
        """Process one frame; returns the new state and the frame's estimate."""
        t0 = time.perf_counter()
        if frame.frame <= state.frame:
            raise ValueError(f"frame {frame.frame} is not after the last processed frame {state.frame}")
        dt = frame_dt(state.frame, state.stamp_ns, frame.frame, frame.stamp_ns, self.params.T)
        sensor, meas, detection, log_kappa = self._sensor_models(frame)
        cands = self._candidates(state, dt, frame, sensor, detection)
        innov = self._innovation(meas, cands)
        E = self._eta(meas, innov, cands, frame, log_kappa)
        children = self._children(state, cands, E, rng)
        upd = self._update(frame, meas, innov, cands, children)
        marg = marginals(upd.state, upd.row_meas, frame.n_measurements)
        rows = self._estimate_rows(upd, marg, state.est_rows)
        est = estimate_from_rows(upd.state, upd.row_meas, marg, frame, rows)
        new = dataclasses.replace(upd.state, birth_frame=frame.frame, birth_kind=frame.kind,
                                  birth_z=frame.z.copy(), birth_sensor=frame.sensor, birth_pose=frame.pose or (),
                                  birth_R=np.zeros((0, 0)) if frame.R is None else frame.R, birth_r_u=np.clip(marg.p_used, 0.0, 1.0),
                                  est_rows=rows)
        card = marg.card  # new.cardinality(): the same hypotheses and weights
        diagnostics = {
            "n_hypotheses": float(new.n_hypotheses),
            "n_tracks": float(new.n_tracks),
            "map_cardinality": float(np.argmax(card)),
            "mean_cardinality": float(np.dot(np.arange(card.size), card)),
            "max_weight": float(np.max(marg.w)),
            "n_samples": float(children.n_samples),
            "n_births": float(cands.n_births),
            "n_adaptive_births": float(cands.n_adaptive),
            "ms": (time.perf_counter() - t0) * 1e3,
        }
        return calibrate(self.calibration, state, new, Estimate(est.frame, est.stamp_ns, est.tracks, est.assignments,
                                                                est.assignment_prob, diagnostics, truncate_tail(card)))

    @cached_property
    def calibration(self) -> ExistenceCalibration | None:
        """The published existence's calibration (``calibration_*``, :mod:`tracker.calibration`;
        None: off)."""
        return from_config(self.params, self.config)

    # -- pieces ---------------------------------------------------------------------------
    def _predict_fn(self):
        return kf.ukf_predict if self.config.filter == "ukf" else kf.ekf_predict

    @cached_property
    def _model_cache(self) -> dict[Any, tuple]:
        return {}

    def _sensor_models(self, frame: Frame) -> tuple[Any, Any, Any, float]:
        """The frame's sensor, measurement model, detection model and :math:`\\log\\kappa`,
        built once per distinct sensor set-up (name, kind, pose, R) and reused while frames
        keep it (only the last set-up is kept: a moving sensor gets new ones every frame)."""
        key = (frame.sensor, frame.kind, frame.pose, None if frame.R is None else np.asarray(frame.R).tobytes())
        hit = self._model_cache.get(key)
        if hit is None:
            sensor = self.params.frame_sensor(frame)
            log_kappa = float(self.params.clutter(frame.kind, sensor).log_intensity)
            if not math.isfinite(log_kappa):
                raise ValueError("the GLMB needs a positive, finite clutter intensity (clutter_rate > 0)")
            hit = (sensor, self.params.measurement(frame.kind, sensor), self.params.detection(frame.kind, sensor),
                   log_kappa)
            self._model_cache.clear()
            self._model_cache[key] = hit
        return hit

    def _candidates(self, state: GlmbState, dt: float, frame: Frame, sensor: Any = None,
                    detection: Any = None) -> _Candidates:
        r"""Survivors: one prediction over ``dt`` seconds (the CT model built for ``dt``),
        :math:`\bar P_S = P_S(m)^{\Delta t/T}` at the mean before the step; then births."""
        m, P = state.mean, state.cov
        log_ps = np.zeros(len(m))
        if len(m):
            log_ps = _log(self.params.survival(m, frame.kind, sensor)) * (dt / self.params.T)
            m, P = self._predict_fn()(self._motion(dt), m, P)
        b = self._births(state, frame, dt)
        labels = state.labels + b.labels
        mean = np.concatenate([m, b.mean])
        cov = np.concatenate([P, b.cov])
        log_e = np.concatenate([log_ps, _log(b.r)])
        log_not_e = np.concatenate([_log(-np.expm1(log_ps)), _log(1.0 - b.r)])
        if detection is None:
            detection = self.params.detection(frame.kind, sensor)
        pd = detection.prob(mean) if len(mean) else np.zeros(0)
        return _Candidates(labels, mean, cov, log_e, log_not_e, np.clip(pd, 0.0, 1.0), len(m),
                           b.n_adaptive)

    def _births(self, state: GlmbState, frame: Frame, dt: float) -> _Births:
        """This frame's birth Bernoullis: the static regions (labels ``"k.i"``, ``i`` the
        component) and/or the adaptive births (labels ``"k.zj"``, ``j`` the index of the
        measurement of the previous processed frame), per :attr:`birth_model`."""
        r, bm, bP = self.birth
        if dt != self.params.T and state.birth_sensor == frame.sensor:  # r per scan T: over dt, 1-(1-r)^(dt/T)
            r = -np.expm1(np.log1p(-np.minimum(r, 1.0 - 1e-12)) * (dt / self.params.T))
        static = _Births(tuple(f"{frame.frame}.{i}" for i in range(r.size)), r, bm, bP)
        if self.birth_model == "static":
            return static
        adaptive = self._adaptive_births(state, frame, dt)
        if self.birth_model == "adaptive":
            return adaptive
        return _Births(static.labels + adaptive.labels, np.concatenate([r, adaptive.r]),
                       np.concatenate([bm, adaptive.mean]), np.concatenate([bP, adaptive.cov]),
                       adaptive.n_adaptive)

    def _adaptive_births(self, state: GlmbState, frame: Frame, dt: float) -> _Births:
        r"""Reuter et al. (2014) adaptive birth: one Bernoulli per kept measurement ``z`` of
        the previous processed frame with :math:`r_B(z)` from
        :func:`adaptive_birth_existence` and the measurement-conditioned prior
        (:func:`measurement_state_prior` of the sensor's ``to_cartesian``) predicted to this
        frame with the motion model over ``dt`` (that frame is the last processed one)."""
        cfg = self.config
        idx, r = adaptive_birth_existence(state.birth_r_u, cfg.adaptive_birth_rate, cfg.birth_r_max,
                                          cfg.max_births, cfg.birth_min_share)
        if state.birth_frame < 0 or idx.size == 0:
            return _Births((), np.zeros(0), np.zeros((0, STATE_DIM)), np.zeros((0, STATE_DIM, STATE_DIM)))
        last = Frame(state.birth_frame, state.stamp_ns, state.birth_sensor, state.birth_kind, state.birth_z,
                     pose=state.birth_pose or None, R=state.birth_R if state.birth_R.size else None)
        sensor = self.params.frame_sensor(last)
        pos, pcov = self.params.measurement(state.birth_kind, sensor).to_cartesian(state.birth_z[idx])
        m, P = measurement_state_prior(pos, pcov, cfg.birth_velocity_std, np.deg2rad(cfg.birth_turn_std_deg))
        m, P = self._predict_fn()(self._motion(dt), m, P)
        labels = tuple(f"{frame.frame}.z{j}" for j in idx.tolist())
        return _Births(labels, r, m, P, idx.size)

    def _innovation(self, meas, cands: _Candidates) -> kf.Innovation:
        if self.config.filter == "ukf":
            return kf.ukf_innovation(meas, cands.mean, cands.cov)
        return kf.ekf_innovation(meas, cands.mean, cands.cov)

    def _eta(self, meas, innov: kf.Innovation, cands: _Candidates, frame: Frame, log_kappa: float) -> np.ndarray:
        M = frame.n_measurements
        if M and len(cands.mean):
            log_lik = kf.log_likelihood_matrix(meas, innov, frame.z, self.config.gate_prob)
        else:
            log_lik = np.zeros((len(cands.mean), M))
        return eta_matrix(cands.log_e, cands.log_not_e, cands.p_detect, log_lik, log_kappa)

    def _children(self, state: GlmbState, cands: _Candidates, E: np.ndarray,
                  rng: np.random.Generator) -> _Children:
        """Gibbs-sampled distinct children of every parent, duplicates merged."""
        cfg = self.config
        n_births = len(cands.labels) - cands.n_survivors
        if cfg.start == "optimal":
            cand, start, ok = starts(E, state.hyp_tracks, cands.n_survivors, n_births)
        else:
            cand = candidate_sets(state.hyp_tracks, cands.n_survivors, n_births)
            start, ok = start_missed(E, cand)
        return children(rng, E, cand, start, ok, state.log_w, cfg.max_hypotheses, cfg.chain_length)

    def _estimate_rows(self, upd: _Update, marg: _Marginals, prev_rows: np.ndarray) -> np.ndarray:
        """Table rows of this frame's estimate, by ``config.estimator``."""
        # np.isin(parent_row, prev_rows) by a lookup (parent -1: a birth, the last, False entry)
        size = max(int(prev_rows.max(initial=-1)), int(upd.parent_row.max(initial=-1))) + 2
        seen = np.zeros(size, dtype=bool)
        seen[prev_rows] = True
        continues = seen[upd.parent_row]
        if self.config.estimator == "continuity":
            return continuity_rows(upd.state, marg, continues, self.config.continuity_ratio)
        if self.config.estimator == "marginal-labels":
            return marginal_label_rows(upd.state, marg, continues, self.config.continuity_ratio)
        return map_cardinality_rows(upd.state, marg)

    def _update(self, frame: Frame, meas, innov: kf.Innovation, cands: _Candidates,
                children: _Children) -> _Update:
        """Prune and cap the children, then build the new track table from their pairs."""
        cfg = self.config
        keep = prune_and_cap(children.log_w, cfg.prune_threshold, cfg.max_hypotheses_after)
        keys = children.keys[keep]
        log_w = children.log_w[keep]
        log_w = log_w - logsumexp(log_w)
        M = frame.n_measurements
        used, hyp = pair_table(keys, len(cands.labels) * (M + 1))
        row, j = used // (M + 1), used % (M + 1)
        mean = cands.mean[row]
        cov = cands.cov[row]
        det = j > 0
        if np.any(det):
            mean[det] = kf.update_pairs(meas, innov, cands.mean, frame.z, row[det], j[det] - 1)
            cov[det] = innov.P_upd[row[det]]
        labels = tuple(map(cands.labels.__getitem__, row.tolist()))
        new = GlmbState(frame.frame, frame.stamp_ns, labels, np.ascontiguousarray(mean),
                        np.ascontiguousarray(cov), np.ascontiguousarray(hyp), log_w)
        parent = np.where(row < cands.n_survivors, row, -1).astype(np.int64)
        return _Update(new, (j - 1).astype(np.int64), parent)


def make_glmb(params: ModelParams | GlmbModel, config: GlmbConfig | None = None) -> GlmbTracker:
    """The GLMB baseline with the ``glmb`` preset unless ``config`` is given."""
    return GlmbTracker(params, config if config is not None else GLMB_PRESETS["glmb"], "glmb")
