"""Settings of the two-level tracker (:class:`GroupConfig`) and its presets (:data:`GROUP_PRESETS`)."""

from __future__ import annotations

from typing import Literal

import msgspec

from bnptrack.tracker.bnp.config import TRACKER_PRESETS, BnpConfig
from bnptrack.tracker.config import Fraction, NonNeg, NonNegInt, PosInt, Positive, PositiveProb, Prob, Sweeps

__all__ = ["GROUP_PRESETS", "GroupConfig"]


class GroupConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of the two-level tracker: the object level (``objects``) and the cluster level."""

    objects: BnpConfig = BnpConfig()
    """Measurement -> object level (the single-level DDP-EMM's settings)."""
    merge: Literal["exclusive", "objects"] = "exclusive"
    """How duplicate objects merge (distance ``objects.merge_distance``): "exclusive" never merges
    two objects that explain different measurements of one scan (:mod:`tracker.bnp.group_merge`;
    members of a young convoy); "objects" is the object level's own merge (as ``ddp-mb``)."""
    merge_label: Literal["oldest", "reported"] = "oldest"
    """The label a merged group of duplicates keeps (``merge = "exclusive"``): "oldest", its
    oldest member's; "reported", its oldest member's among those with existence above
    ``objects.existence_threshold`` (else the oldest's): a hypothesis too weak to be reported
    never renames a reported track (docs/trackers.md, "Identities through crossings")."""
    member_existence: Prob = 0.8
    """Objects with existence at least this take part in the object partition."""
    within_std: Positive = 3.0
    """S_w = within_std^2 I: spread (m/s) of member velocities about their cluster's theta in
    f(x | theta) (eqs. (2), (4)): the membership evidence.  Tight, as true convoys share velocity
    (10 m/s lets objects 14 m/s apart share a cluster); the sharing's
    robustness is ``share_inflation_std`` (docs/trackers.md, "Deviations, stated")."""
    share_inflation_std: NonNeg = 9.5
    """Sharing only: the pseudo-measurement's covariance is S_w + share_inflation_std^2 I +
    Cov(theta^-l); the inflation stands for the information the members already share (each
    member's estimate holds last frame's share of the others), which the Gaussian update would
    otherwise count again."""
    share_prior: Literal["flat", "H2"] = "flat"
    """Prior of the leave-one-out theta a member shares: "flat" (the NIW's kappa_0 = 0: only the
    other members inform it; a member alone shares nothing) or H_2 (a singleton's velocity is
    pulled towards H_2's mean 0 every frame: H_2 counted once per frame)."""
    share_min_info: NonNeg = 0.0
    """A member receives the velocity sharing only when its own velocity information is at least
    this factor times H's (largest velocity variance <= objects.birth_velocity_std^2 / factor;
    :mod:`tracker.bnp.group_share`: crossing pairs); 0: every member."""
    share_after: NonNegInt = 0
    """A member receives the velocity sharing only once it has sat in one cluster with at least one
    other object for this many consecutive scans
    (:func:`tracker.bnp.group_share.together_scans`: objects that have moved together, not two
    that meet at a crossing); 0: every member (off)."""
    turn_within_std_deg: NonNeg = 0.5
    """Spread (deg/s) of members' turn rates about their cluster's; > 0 shares the turn rate too
    (:func:`tracker.bnp.group_share.share_turn`), 0 does not."""
    theta_std: Positive = 30.0
    """With ``h2 = "vague"``: H_2 = N(0, theta_std^2 I), the prior of a new cluster's velocity (m/s)."""
    theta_drift_std: Positive = 2.0
    """phi: a transitioned cluster's theta random-walks with this std (m/s) per scan."""
    centroid: bool = True
    """theta also holds the cluster's centroid (membership only; never shared): members'
    positions ~ N(centroid, within_pos_std^2 I), so far-apart objects do not group."""
    within_pos_std: Positive = 20.0
    """Spread (m) per axis of members' positions about their cluster's centroid: a formation of
    radius 40 m (uniform in the disc) has 20 m per axis (not 40, the radius)."""
    centroid_std: Positive = 2000.0
    """With ``h2 = "vague"``: H_2's centroid part, N(0, centroid_std^2 I) (vague over the field)."""
    h2: Literal["vague", "birth"] = "birth"
    """H_2, the base distribution of a new cluster's theta (eqs. (5)-(6) [case3, state3], (19)):
    "vague" is N(0, theta_std^2 I) on the velocity and N(0, centroid_std^2 I) on the centroid;
    "birth" is the object level's base distribution H (:mod:`tracker.bnp.base_measure`), the
    paper's one H for both levels: velocity N(0, objects.birth_velocity_std^2 I), centroid the
    Gaussian with the mean and covariance of the uniform over the sensor's field of view
    (:func:`tracker.bnp.group_theta.fov_moments`)."""
    centroid_drift_std: Positive = 10.0
    """phi on the centroid: it moves with theta's velocity plus this random walk (m per scan)."""
    sweeps: Sweeps = 6
    """Gibbs sweeps over the object assignments per frame (the last one is kept)."""
    sharing: bool = True
    """Members' velocities take their cluster's leave-one-out theta as a pseudo-measurement."""
    share_base: Literal["state", "own"] = "state"
    """What the sharing updates: "state", the object's state, which holds every earlier frame's
    shares (the information accumulates; ``share_inflation_std`` stands for it); "own", the
    object's own, sharing-free estimate (as ``membership = "own"`` keeps it): each member's state is
    its own estimate plus this frame's share only, and a non-member's state is its own estimate."""
    membership: Literal["shared", "own"] = "shared"
    """Which velocity and position estimate of each member the object -> cluster Gibbs (eqs.
    (13)-(14) [posttheta, Gibbs]) and the clusters' theta read: "shared", the object's state,
    which holds the pseudo-measurements of its cluster's theta shared at earlier frames (the
    cluster's information counted again in its own membership test); "own", a second,
    sharing-free estimate kept per object: the object level's measurement updates without the
    sharing (:func:`tracker.bnp.group_share.own_update`; for crossing objects)."""
    alpha: Positive = 0.5
    alpha_shape: Positive = 1.0
    alpha_scale: Positive = 1.0
    infer_alpha: bool = True
    d: Fraction = 0.0
    """Pitman-Yor discount of the object partition (0 = DDP)."""
    d_shape: Positive = 1.0
    d_scale: Positive = 0.1
    infer_d: bool = False
    d_prior: Literal["gamma", "uniform"] = "gamma"
    """Prior of d: Gamma(d_shape, d_scale) (the project's reading of the paper's Gamma(1, 0.1)) or
    uniform on [0, 0.95]."""
    urn_reading: Literal["all", "occupied"] = "occupied"
    """How the Pitman-Yor discount enters the object -> cluster urn (eqs. (17)-(19), cases P1-P3;
    :func:`tracker.bnp.group_sample.urn_log_weights`): "all" subtracts d from every cluster,
    transitioned ones included, and counts them all in the new cluster's d K; "occupied" discounts
    only the clusters the other objects occupy this frame and counts only those (eq. (19)'s
    D^(l-1)); identical when d = 0."""
    hyper_forgetting: PositiveProb = 0.98
    """Per-frame forgetting of the "arrivals" and "reseat" likelihoods ("history" has none)."""
    crossing_scans: NonNegInt = 0
    """Multi-scan check of crossing tracks' labels (:mod:`tracker.bnp.identity`): the scans after
    two tracks' closest approach at which their labels are checked (0: off)."""
    crossing_before: PosInt = 2
    """Scans before the closest approach the check filters from (each track's own posterior)."""
    crossing_margin: float = 0.0
    """Nats by which the best swap must beat keeping the labels."""
    hyper_likelihood: Literal["history", "arrivals", "reseat"] = "history"
    """What (alpha_2, d) are inferred from: "history", the Pitman-Yor EPPF of the partition of
    every object that ever entered it, each counted once in its latest cluster (dead clusters
    kept); "arrivals", each object's seat once, when it enters the partition, given the members
    present then (forgetting ``hyper_forgetting``); "reseat", every frame's re-seating
    (:mod:`tracker.bnp.group_hyper`)."""


_PRESETS: dict[str, GroupConfig] = {
    # the product default: the object level's state update over every measurement an object may
    # have taken, weighted by the Rao-Blackwellised assignment probabilities (eq. (11), the
    # detections as one combined component), and velocity sharing only among objects that have
    # moved together (docs/trackers.md, "Identities through crossings"); "ddp-paper" is the
    # paper's algorithm as the single level ships it
    "ddp": GroupConfig(objects=msgspec.structs.replace(TRACKER_PRESETS["ddp-mb"], state_update="combined"),
                       share_after=12),
    "ddp-paper": GroupConfig(objects=TRACKER_PRESETS["ddp-mb"]),
    "dpyp": GroupConfig(objects=TRACKER_PRESETS["ddp-mb"], d=0.1, infer_d=True),
    # the experiments' object levels (pipeline/experiments.py): experiment 2's and 3's presets
    "ddp-proximity": GroupConfig(objects=TRACKER_PRESETS["ddp-mb-proximity"]),
    "ddp-snr": GroupConfig(objects=TRACKER_PRESETS["ddp-mb-snr"]),
}

#: The two-level trackers' presets (``--tracker ddp`` / ``dpyp``), each also under an alias
#: (``ddp-groups``, ``dpyp-groups``, ``ddp-groups-proximity``, ``ddp-groups-snr``).
GROUP_PRESETS: dict[str, GroupConfig] = {
    **_PRESETS,
    "ddp-groups": _PRESETS["ddp"],
    "ddp-groups-paper": _PRESETS["ddp-paper"],
    "dpyp-groups": _PRESETS["dpyp"],
    "ddp-groups-proximity": _PRESETS["ddp-proximity"],
    "ddp-groups-snr": _PRESETS["ddp-snr"],
}
