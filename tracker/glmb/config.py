"""GLMB settings (:class:`GlmbConfig`), its presets and the model protocol it needs."""

from __future__ import annotations

from typing import Any, Literal, Protocol

import msgspec
import numpy as np

from bnptrack.tracker.config import Fraction, Hypotheses, NonNeg, OpenProb, PosInt, Positive, PositiveProb, Sweeps
from bnptrack.tracker.models.params import BirthComponent
from bnptrack.tracker.types import Frame


BirthModel = Literal["auto", "static", "adaptive", "both"]


Estimator = Literal["map-cardinality", "continuity", "marginal-labels"]


class GlmbConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of the GLMB baseline (model physics live in ``ModelParams``)."""

    filter: Literal["ukf", "ekf"] = "ukf"
    """Gaussian approximation of the nonlinear models (UKF as in Vo's demo)."""
    gate_prob: OpenProb = 0.99999
    """Chi-square gate probability on the predicted measurement; pairs outside are impossible
    (Vo's demo uses 0.9999999)."""
    max_hypotheses: Hypotheses = 1000
    """Requested Gibbs samples per frame over all parent hypotheses (the demo's ``H_upd``);
    parent ``h`` gets ``round(max_hypotheses * sqrt(w_h) / sum sqrt(w))`` and at least one."""
    max_hypotheses_after: Hypotheses = 500
    """Cap on the number of hypotheses kept after pruning (the demo's ``H_max``)."""
    prune_threshold: Fraction = 1e-15
    """Hypotheses with normalised weight at or below this are dropped (``hyp_threshold``)."""
    chain_length: Sweeps = 10
    """Maximum Gibbs sweeps per chain: a parent's request is split into parallel chains of at
    most this many sweeps, all started at the same point (short-chain multi-simulation)."""
    start: Literal["optimal", "missed"] = "optimal"
    """Chain start: the optimal assignment (linear assignment, so each parent's best child is
    always kept) or every candidate at its best of dies/missed (Vo's demo: all missed)."""
    birth: list[BirthComponent] | None = None
    """Static labeled multi-Bernoulli birth regions; ``None`` uses the parameter set's
    ``birth`` list (``[]``: none)."""
    birth_model: BirthModel = "auto"
    """``"static"``: the birth regions only; ``"adaptive"``: measurement-driven births only
    (Reuter et al. 2014); ``"both"``; ``"auto"``: ``"adaptive"`` when there are no birth
    regions, else ``"static"`` (``docs/glmb.md`` measures the choice)."""
    adaptive_birth_rate: Positive = 0.2
    r"""Adaptive birth: :math:`\lambda_B`, the expected number of new objects per scan, spread
    over the previous scan's measurements by how unlikely each was to be assigned."""
    birth_r_max: OpenProb = 0.5
    r"""Adaptive birth: cap :math:`r_{B,\max}` on one measurement's birth existence."""
    max_births: PosInt = 50
    """Adaptive birth: at most this many birth Bernoullis per scan (the measurements with the
    largest unassigned probability; a cap on the cost, never zero births)."""
    birth_min_share: Fraction = 1e-3
    """Adaptive birth: a measurement whose birth existence is below this fraction of the
    largest one of its scan gets no Bernoulli (relative, so it cannot remove every birth)."""
    birth_velocity_std: Positive = 20.0
    """Adaptive birth: std of the zero-mean velocity prior per axis, m/s."""
    birth_turn_std_deg: Positive = 6.0
    """Adaptive birth: std of the zero-mean turn-rate prior, deg/s (Vo's birth components)."""
    estimator: Estimator = "continuity"
    """``"map-cardinality"``: the best hypothesis of the MAP cardinality (Vo's demo);
    ``"continuity"``: the MAP-cardinality hypothesis that continues the most of the last
    estimate's tracks among those within ``continuity_ratio`` of the best
    (:func:`continuity_rows`); ``"marginal-labels"``: the MAP-cardinality number of labels
    with the largest marginal existence, each with its best association history
    (:func:`marginal_label_rows`)."""
    continuity_ratio: PositiveProb = 0.5
    """``continuity`` / ``marginal-labels``: an estimate that continues the previous one is
    kept while its weight is at least this fraction of the best alternative's."""
    calibration_weight: NonNeg = 20.0
    """Prior weight (track-frames) of the learned model in the published, calibrated existence
    (:mod:`tracker.calibration`, the same layer and defaults as ``ddp``'s); 0 publishes the
    GLMB's marginal existence of each label unchanged."""
    calibration_hazard_weight: Positive = 100.0
    """Prior weight (scans) of ``p_survival`` and ``p_detect`` in the calibration's learned death
    hazard and miss rate of established tracks."""
    calibration_odds_weight: Positive = 5.0
    """Pseudo-counts on each side of the calibration's learned odds ratio of young tracks."""


GLMB_PRESETS: dict[str, GlmbConfig] = {"glmb": GlmbConfig()}


class GlmbModel(Protocol):
    """What the GLMB needs from a model set (``ModelParams`` satisfies it; tests inject others).

    ``motion(dt)`` (the transition over ``dt`` seconds, ``T`` by default) and ``measurement(kind)`` follow the protocol of :mod:`tracker.filtering`;
    ``clutter(kind).log_intensity`` is :math:`\\log\\kappa(z)` (uniform clutter);
    ``frame_sensor(frame)`` resolves the frame's sensor (pose, field of view, noise), which the
    model factories take as ``sensor``; ``detection(kind).prob(x)`` and ``survival(x, kind)`` map ``(N, 5)`` states to ``(N,)``.
    Adaptive births also need ``measurement(kind).to_cartesian(Z) -> (pos (M, 2), cov (M, 2, 2))``.
    """

    birth: list[BirthComponent]
    T: float
    """The scan period: survival ``survival(x)`` is per ``T`` (over ``dt``: its power ``dt/T``)."""

    def motion(self, dt: float | None = None) -> Any: ...
    def frame_sensor(self, frame: Frame) -> Any: ...
    def measurement(self, kind: str, sensor: Any = None) -> Any: ...
    def clutter(self, kind: str, sensor: Any = None) -> Any: ...
    def detection(self, kind: str, sensor: Any = None) -> Any: ...
    def survival(self, x: np.ndarray, kind: str, sensor: Any = None) -> np.ndarray: ...
