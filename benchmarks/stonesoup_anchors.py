"""Stone Soup anchors for ``benchmarks/vs_stonesoup.py`` (needs the ``compare`` extra).

Two multi-object trackers built from Stone Soup 1.9 components, on the same physics as
bnptrack's parameter set:

* **Motion.**  Stone Soup's ``ConstantTurn`` (state ``[x, vx, y, vy, omega]``, the same
  transition as ``tracker/models/motion.py``) with its covariance replaced by bnptrack's
  discrete-time process noise :math:`Q = G G^T` (``CoordinatedTurn.Q``).  Stone Soup's own
  ``ConstantTurn.covar`` is the continuous white-noise-acceleration form (``dt^3/3``), which
  is a different model, so it is overridden (:class:`ProjectConstantTurn`).
* **Sensor.**  ``CartesianToBearingRange`` at the origin, noise ``diag(sigma_b^2, sigma_r^2)``;
  measurements converted to Stone Soup's bearing convention
  (:func:`benchmarks.anchor_convert.to_stonesoup_bearing`).
* **Filters.**  Unscented Kalman predictor/updater with bnptrack's unscented transform
  (alpha=1, beta=2, kappa=2; :data:`UKF_ALPHA`).

:class:`PhdAnchor` is a GM-PHD (``PHDUpdater``, ``GaussianMixtureHypothesiser`` over a
Mahalanobis-gated ``DistanceHypothesiser``, ``GaussianMixtureReducer``) with a
measurement-driven birth written here (Stone Soup 1.9 has no adaptive GM-PHD birth): each
measurement of the previous scan places a birth component, weighted as in Ristic et al. (2012).
:class:`JpdaAnchor` is Stone Soup's ``MultiTargetMixtureTracker`` with ``JPDA`` over a
``PDAHypothesiser`` (by default ``JPDAwithEHM``: the same exact marginals, computed by
Efficient Hypothesis Management), a ``MultiMeasurementInitiator`` and time/covariance deleters.
Both return ``[(label, position)]`` per scan.
"""

from __future__ import annotations

import datetime

import numpy as np
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.dataassociator.probability import JPDA, JPDAwithEHM
from stonesoup.deleter.error import CovarianceBasedDeleter
from stonesoup.deleter.multi import CompositeDeleter
from stonesoup.deleter.time import UpdateTimeStepsDeleter
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
from stonesoup.hypothesiser.probability import PDAHypothesiser
from stonesoup.initiator.simple import MultiMeasurementInitiator
from stonesoup.measures import Mahalanobis
from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
from stonesoup.models.measurement.nonlinear import CartesianToBearingRange
from stonesoup.models.transition.nonlinear import ConstantTurn
from stonesoup.predictor.kalman import UnscentedKalmanPredictor
from stonesoup.tracker.simple import MultiTargetMixtureTracker
from stonesoup.types.angle import Bearing
from stonesoup.types.array import CovarianceMatrix, StateVector
from stonesoup.types.detection import Detection
from stonesoup.types.state import GaussianState, TaggedWeightedGaussianState
from stonesoup.updater.kalman import UnscentedKalmanUpdater
from stonesoup.updater.pointprocess import PHDUpdater

from benchmarks.anchor_convert import (
    JpdaSettings,
    PhdSettings,
    adaptive_birth_weights,
    birth_gaussians,
    clutter_intensity,
    extract_phd,
    position,
    to_stonesoup_measurements,
)
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import Frame

__all__ = ["JpdaAnchor", "PhdAnchor", "ProjectConstantTurn", "make_anchor"]

EPOCH = datetime.datetime(2000, 1, 1)
#: Unscented transform of bnptrack (``tracker/filtering.py``) and Vo's GLMB UKF demo.  Stone
#: Soup's defaults (alpha 0.5, kappa 0) give a central weight of -3 for a 5-d state, and the
#: resulting indefinite covariances crashed both anchors (scipy "not positive definite" in the
#: PHD update; a NaN probability in JPDA's EHM) on the tuning seeds.
UKF_ALPHA, UKF_BETA, UKF_KAPPA = 1.0, 2.0, 2.0


class ProjectConstantTurn(ConstantTurn):
    """Stone Soup's coordinated-turn transition with bnptrack's process noise :math:`G G^T`."""

    def covar(self, time_interval, **kwargs):
        T = abs(time_interval.total_seconds())
        s2 = self.linear_noise_coeffs[0]
        blk = s2 * np.array([[T**4 / 4, T**3 / 2], [T**3 / 2, T**2]])
        Q = np.zeros((5, 5))
        Q[0:2, 0:2] = blk
        Q[2:4, 2:4] = blk
        Q[4, 4] = self.turn_noise_coeff * T**2
        return CovarianceMatrix(Q)


def _models(params: ModelParams):
    """Transition model, measurement model, UKF predictor and updater of ``params``."""
    transition = ProjectConstantTurn(
        linear_noise_coeffs=np.array([params.sigma_accel**2, params.sigma_accel**2]),
        turn_noise_coeff=np.deg2rad(params.sigma_turn_deg) ** 2,
    )
    R = np.diag([np.deg2rad(params.sigma_bearing_deg) ** 2, params.sigma_range**2])
    sensor = CartesianToBearingRange(ndim_state=5, mapping=(0, 2), noise_covar=R)
    predictor = UnscentedKalmanPredictor(transition, alpha=UKF_ALPHA, beta=UKF_BETA, kappa=UKF_KAPPA)
    updater = UnscentedKalmanUpdater(sensor, alpha=UKF_ALPHA, beta=UKF_BETA, kappa=UKF_KAPPA)
    return transition, sensor, predictor, updater


def _detections(frame: Frame, sensor, when: datetime.datetime) -> list[Detection]:
    """Stone Soup detections of a bnptrack frame (bearing converted, same order as ``frame.z``)."""
    zs = to_stonesoup_measurements(frame.z)
    return [Detection(StateVector([Bearing(b), r]), timestamp=when, measurement_model=sensor) for b, r in zs]


class PhdAnchor:
    """GM-PHD (UKF) with measurement-driven birth at the previous scan's measurements."""

    name = "ss-gmphd"

    def __init__(self, params: ModelParams, settings: PhdSettings):
        self.params, self.s = params, settings
        _, self.sensor, predictor, self.kf_updater = _models(params)
        base = DistanceHypothesiser(predictor, self.kf_updater, Mahalanobis(), missed_distance=settings.gate)
        self.hypothesiser = GaussianMixtureHypothesiser(base, order_by_detection=True)
        self.updater = PHDUpdater(
            self.kf_updater,
            clutter_spatial_density=clutter_intensity(params),
            prob_detection=params.p_detect,
            prob_survival=params.p_survival,
        )
        self.reducer = GaussianMixtureReducer(
            prune_threshold=settings.prune, merge_threshold=settings.merge,
            max_number_components=settings.max_components,
        )
        self.mixture: list = []
        self.births: list = []

    def _births(self, z: np.ndarray, p_assoc: np.ndarray, when: datetime.datetime) -> list:
        if z.shape[0] == 0:
            return []
        w = adaptive_birth_weights(p_assoc, self.s.birth_rate)
        mean, cov = birth_gaussians(z, self.params, self.s.birth_vel_std, self.s.birth_turn_std_deg)
        return [TaggedWeightedGaussianState(StateVector(m), CovarianceMatrix(c), weight=wi,
                                            tag=TaggedWeightedGaussianState.BIRTH, timestamp=when)
                for m, c, wi in zip(mean, cov, w) if wi > 0]

    def _association(self, hypotheses, update, known_tags: set) -> np.ndarray:
        """P(measurement came from an object already in the mixture), one per detection in
        the order the hypothesiser used (``order_by_detection``: the detection set's order)."""
        comps = list(update)
        out, i = [], 0
        for mh in hypotheses[:-1]:
            known = total = 0.0
            for h in mh:
                w = float(comps[i].weight)
                total += w
                known += w if h.prediction.tag in known_tags else 0.0
                i += 1
            out.append(known / total if total > 0 else 0.0)
        return np.asarray(out)

    def step(self, frame: Frame) -> list[tuple[str, np.ndarray]]:
        when = EPOCH + datetime.timedelta(seconds=frame.stamp_ns * 1e-9)
        dets = _detections(frame, self.sensor, when)
        detset = set(dets)
        hyps = self.hypothesiser.hypothesise(self.mixture + self.births, detset, when)
        update = self.updater.update(hyps)
        p_known = self._association(hyps, update, {c.tag for c in self.mixture})
        row = {id(d): j for j, d in enumerate(dets)}
        pa = np.zeros(len(dets))
        for d, p in zip(detset, p_known):
            pa[row[id(d)]] = p
        self.mixture = list(self.reducer.reduce(list(update)))
        self.births = self._births(np.asarray(frame.z, dtype=float).reshape(-1, 2), pa, when)
        return extract_phd([(c.tag, float(c.weight), c.state_vector) for c in self.mixture], self.s.extract)


class JpdaAnchor:
    """JPDA (UKF) with a multi-measurement initiator (Stone Soup's MultiTargetMixtureTracker)."""

    name = "ss-jpda"

    def __init__(self, params: ModelParams, settings: JpdaSettings):
        _, self.sensor, predictor, updater = _models(params)
        hyp = PDAHypothesiser(predictor, updater, clutter_spatial_density=clutter_intensity(params),
                              prob_detect=params.p_detect, prob_gate=settings.prob_gate)
        prior = GaussianState(StateVector(np.zeros(5)), CovarianceMatrix(np.diag(
            [0.0, settings.init_vel_std**2, 0.0, settings.init_vel_std**2,
             np.deg2rad(settings.init_turn_std_deg) ** 2])))
        init_assoc = GNNWith2DAssignment(
            DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=settings.init_gate))
        initiator = MultiMeasurementInitiator(
            prior_state=prior, measurement_model=self.sensor,
            deleter=UpdateTimeStepsDeleter(settings.init_delete_steps),
            data_associator=init_assoc, updater=updater, min_points=settings.min_points)
        deleter = CompositeDeleter([UpdateTimeStepsDeleter(settings.delete_steps),
                                    CovarianceBasedDeleter(settings.delete_covar_trace, mapping=[0, 2])],
                                   intersect=False)
        self.tracker = MultiTargetMixtureTracker(initiator=initiator, deleter=deleter, detector=None,
                                                 data_associator=(JPDAwithEHM if settings.ehm else JPDA)(hyp),
                                                 updater=updater)

    def step(self, frame: Frame) -> list[tuple[str, np.ndarray]]:
        when = EPOCH + datetime.timedelta(seconds=frame.stamp_ns * 1e-9)
        self.tracker.detector_iter = iter([(when, set(_detections(frame, self.sensor, when)))])
        _, tracks = next(self.tracker)
        return [(str(t.id), position(t.state_vector)) for t in tracks]


ANCHORS = ("ss-gmphd", "ss-jpda")


def make_anchor(name: str, params: ModelParams, phd: PhdSettings, jpda: JpdaSettings):
    """Build anchor ``name`` (one of :data:`ANCHORS`)."""
    if name == "ss-gmphd":
        return PhdAnchor(params, phd)
    if name == "ss-jpda":
        return JpdaAnchor(params, jpda)
    raise ValueError(f"unknown anchor {name!r}; valid anchors: {', '.join(ANCHORS)}")
