"""Settings of the DDP-EMM / DPY-STP trackers (:class:`BnpConfig`) and their named presets."""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from bnptrack.tracker.config import Fraction, NonNeg, NonNegInt, OpenProb, PosInt, Positive, PositiveProb, Prob, Sweeps


class BnpConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of the DDP-EMM / DPY-STP trackers (model physics live in ``ModelParams``)."""

    sweeps: Sweeps = 30
    """Gibbs sweeps per chain and frame (including burn-in)."""
    burn_in: NonNegInt = 5
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
    calibration_weight: NonNeg = 20.0
    """Prior weight (track-frames) of the learned model in the published, calibrated existence
    (:mod:`tracker.calibration`); 0 publishes the model's existence (the one
    ``existence_threshold`` reads) unchanged."""
    calibration_hazard_weight: Positive = 100.0
    """Prior weight (scans) of ``p_survival`` and ``p_detect`` in the calibration's learned death
    hazard and miss rate of established tracks."""
    calibration_odds_weight: Positive = 5.0
    """Pseudo-counts on each side of the calibration's learned odds ratio of young tracks.  The
    three weights were chosen on ``random`` and ``vo2017`` without regions, seeds 101-120
    (``weight`` among 2 / 5 / 20, ``hazard`` among 50 / 100 / 200, ``odds`` among 1 / 2 / 5)."""
    prune_threshold: Prob = 1e-3
    """Clusters whose existence is below ``min(prune_threshold, birth_prune_fraction * p_birth)``
    are dropped; ``p_birth`` is the probability that a measurement far from every cluster
    opens a new one (``BnpTracker.birth_probability``).  Tying the floor to ``p_birth`` means
    no fixed threshold can stop births, however dense the clutter."""
    birth_prune_fraction: OpenProb = 0.1
    """A cluster is kept while its existence is at least this fraction of ``p_birth``: a
    newborn survives its birth frame, and is dropped after a missed first re-detection."""
    max_clusters: PosInt = 100_000
    """Memory guard, not a model setting: at most this many clusters are kept (highest
    existence first).  Far above any scene's object count (clutter-born tentative clusters
    included); when it bites, the step's diagnostics report ``clusters_capped`` (> 0) and one
    warning is logged (once per process)."""
    popularity_decay: Fraction = 0.0
    """rho: v <- max(1, rho * v + (1 - rho) * n_k).  0 carries the last frame's cardinality
    (the paper's v*_{l,k|k-1}); for point objects v = 1 whatever rho is."""
    state_update: Literal["best-permutation", "mixture", "combined"] = "best-permutation"
    """How a cluster's Gaussian takes its measurements: moment-matched over every measurement
    it may have taken ("mixture", JPDA-like), or over "missed" and the one measurement it takes
    in the most probable one-to-one assignment ("best-permutation", JPDA*), which keeps two
    clusters that share a gate from coalescing; "combined": as "mixture", with the updates by
    the measurements it may have taken as one component (their probability-weighted mean, the
    updated covariance; no spread among them), so that a dense scene's many small assignment
    probabilities do not widen every gate (docs/trackers.md, "Identities through crossings")."""
    merge_distance: NonNeg = 9.0
    """Clusters whose position-velocity states are within this squared Mahalanobis distance
    (summed covariances) and whose existences sum to at most 1 are one object split over
    exclusive hypotheses: they are merged (existences added).  0 disables merging."""
    birth_velocity_std: Positive = 20.0
    """Base distribution H (uniform part): velocity std (m/s) per axis of a new cluster.  20:
    chosen on ``random`` and ``vo2017`` seeds 101-120, near the
    per-axis RMS speed of objects moving at 5-40 m/s in any direction (17 m/s); a narrower
    prior predicts a newborn's second detection more sharply (docs/trackers.md, "Births
    anywhere")."""
    birth_turn_std_deg: Positive = 3.0
    """Base distribution H (uniform part): turn-rate std (deg/s) of a new cluster."""
    alpha: Positive = 0.1
    """Initial concentration alpha (kept fixed if ``infer_alpha`` is false)."""
    alpha_shape: Positive = 1.0
    alpha_scale: Positive = 0.1
    """alpha ~ Gamma(shape, scale): the paper's Gamma(1, 0.1), 0.1 read as the scale."""
    infer_alpha: bool = True
    d: Fraction = 0.0
    """Pitman-Yor discount (0 = DDP-EMM)."""
    d_shape: Positive = 1.0
    d_scale: Positive = 0.1
    """d ~ Gamma(shape, scale) truncated to [0, 1)."""
    infer_d: bool = False
    hyper_estimate: Literal["mean", "sample"] = "mean"
    """What the next frame's urn uses of the grid posterior of (alpha, d): its mean
    (Rao-Blackwellised over the hyperparameter) or one draw (a plain Gibbs step)."""
    hyper_forgetting: PositiveProb = 0.98
    """Past frames' hyperparameter log-likelihood is multiplied by this each frame."""
    birth_lag: Annotated[int, msgspec.Meta(ge=0, le=50)] = 4
    """The hyperparameter likelihood counts the new clusters of frame ``k - birth_lag`` by their
    existence at frame ``k`` (fixed-lag smoothing): at its birth frame a new object's
    measurement is 'new' with probability ~ alpha / lambda_c, so counting that frame's sample
    would drive alpha towards 0 (see docs/trackers.md).  0 counts the current sample."""
    urn_normaliser: bool = True
    """Weight every object assignment by the urn normaliser ``g_m = (alpha+V)/(alpha+V+M_o)``
    of the paper's eq. (1).  False: ``g_m = 1``, the point-object model (docs/trackers.md,
    "Births anywhere")."""
    extended: bool = False
    """Allow several measurements per object per frame (case D1/P1); off for point objects."""
    learn_births: bool = False
    """Learn where objects appear: the base distribution becomes the Polya-urn posterior
    predictive H_k = E[alpha_H/(alpha_H+W)] H + E[1/(alpha_H+W)] sum_i w_i kappa(x; b_i) over the
    births recorded so far (:mod:`tracker.bnp.birth_memory`; docs/trackers.md, "Births anywhere").
    Off by default (measured: docs/results.md, section 6)."""
    learn_birth_velocity: bool = False
    """Learn the newborn's per-axis velocity variance from the recorded births' velocities
    (conjugate inverse-gamma update; :func:`tracker.bnp.birth_memory.velocity_variance`)."""
    birth_memory_forgetting: PositiveProb = 0.99
    """Recorded births' weights (and alpha_H's log-likelihood) are multiplied by this per scan."""
    birth_kernel_std: NonNeg = 50.0
    """Metres: the extent of an entry point, added (as s^2 I) to each recorded birth position's
    own uncertainty in its kernel kappa.  50 chosen on ``vo2017`` without regions, seeds 101-120,
    among 10 / 25 / 50 / 100 / 200 (docs/trackers.md, "Births anywhere")."""
    birth_memory_lag: Annotated[int, msgspec.Meta(ge=1, le=50)] = 4
    """A cluster is recorded as a birth this many frames after it was born, with its existence
    then as its weight."""
    birth_alpha_min: Annotated[float, msgspec.Meta(ge=0.1, le=1000.0)] = 0.1
    """The learned base distribution's concentration alpha_H (in births) has a log-uniform prior
    on [birth_alpha_min, 1000] (:data:`tracker.bnp.birth_memory.ALPHA_H_GRID`)."""
    birth_velocity_strength: Positive = 5.0
    """Pseudo-births of the learned velocity variance's prior (at ``birth_velocity_std``)."""

    def __post_init__(self) -> None:
        if self.burn_in >= self.sweeps:
            raise ValueError(f"burn_in ({self.burn_in}) must be smaller than sweeps ({self.sweeps})")


#: The single-level trackers' presets (``--tracker ddp-mb`` / ``dpyp-mb``; the names ``ddp``,
#: ``dpyp``, ``ddp-proximity``, ``ddp-snr`` select the two-level tracker's presets,
#: :data:`tracker.bnp.group_config.GROUP_PRESETS`).
TRACKER_PRESETS: dict[str, BnpConfig] = {
    # Experiment 1 (DDP-EMM vs GLMB): alpha ~ Gamma(1, 0.1).
    "ddp-mb": BnpConfig(),
    # Experiments 4-5 (DPY-STP): alpha and d ~ Gamma(1, 0.1), both inferred.
    "dpyp-mb": BnpConfig(d=0.1, infer_d=True),
    # Experiment 2 (close proximity): alpha ~ Gamma(1, 0.3).
    "ddp-mb-proximity": BnpConfig(alpha_scale=0.3),
    # Experiment 3 (varying SNR): alpha ~ Gamma(1, 0.2).  Range-only tracks cannot be localised
    # (position is known up to a rotation about the sensor), so they keep losing their
    # measurements to new clusters; counting the current sample's new clusters (birth_lag = 0)
    # keeps alpha high enough to re-open them (docs/trackers.md, "Births").
    "ddp-mb-snr": BnpConfig(alpha_scale=0.2, birth_lag=0),
}
