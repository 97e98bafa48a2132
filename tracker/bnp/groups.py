r"""The paper's two-level DDP: measurements -> objects -> motion clusters (``ddp``, ``dpyp``;
aliases ``ddp-groups``, ``dpyp-groups``).

:class:`GroupTracker` wraps a :class:`tracker.bnp.filter.BnpTracker` (the measurement ->
object level: its clusters are objects, its customers measurements; its merge of duplicates is
replaced by one that never merges two objects of one scan, :mod:`tracker.bnp.group_merge`) and
adds the object -> cluster level of the paper's Algorithm 1 (``docs/trackers.md``, "Two-level model"):

* **Clusters** are groups of objects that share motion.  A cluster's parameter
  :math:`\theta_c` is the velocity :math:`(v_x, v_y)` its members share (eqs. (2), (4)
  [state1, state2]: :math:`f(x_\ell \mid \theta^*)`, here :math:`v_\ell \sim \mathcal N(\theta_c, S_w)`
  with the known within-group spread :math:`S_w` = ``within_std**2 I``) and, for membership
  only, the group's centroid (members' positions :math:`\sim \mathcal N(c, \sigma_p^2 I)`,
  ``within_pos_std``; never shared).
* **Base distribution** :math:`H_2`, Gaussian on each part: the conjugate equivalent of the
  paper's :math:`\mathrm{NIW}(\mu_0, 0, \nu, I)` (Sec. 6) once the within-group covariance is
  known (fixed instead of drawn from the inverse-Wishart part).  By default (``h2 = "birth"``)
  it is the object level's base distribution, the paper's one :math:`H`: velocity
  :math:`\mathcal N(0, 20^2 I)` and the centroid with the moments of the uniform over the field
  of view; ``"vague"`` approaches :math:`\kappa_0 = 0` by large variances (30 m/s, 2 km).
* **Transition** of a cluster (Algorithm 1, step 2): it transitions iff it had at least one
  member (:math:`v^*_c \ge 1`, :math:`\lambda_c = 1`), with cardinality :math:`v^*_c` = its
  number of objects at the previous frame; :math:`\theta` moves by the kernel
  :math:`\varphi` (eq. (8) [HH]): the velocity random-walks (``theta_drift_std``), the
  centroid moves with it (plus ``centroid_drift_std``).
* **Object -> cluster assignment** (eqs. (1), (3), (5) [case1-case3]; Pitman-Yor (17)-(19)):
  collapsed Gibbs (eqs. (13)-(14) [posttheta, Gibbs]) over the member objects' labels given
  their estimates; weights: a cluster already chosen :math:`\propto n_c + v^*_c - d`, a
  transitioned one not yet chosen :math:`\propto v^*_c`, a new one
  :math:`\propto \alpha_2 + d K`, K the clusters the other objects occupy (``urn_reading``
  "occupied"; "all" discounts the transitioned ones too and counts them in K); likelihood the conjugate predictive, e.g.
  :math:`\mathcal N(v_\ell; \hat\theta_c^{-\ell}, \Sigma_c^{-\ell} + P_{v,\ell} + S_w)`.
* :math:`(\alpha_2, d)` on a grid with Gamma priors; likelihood: the Pitman-Yor EPPF of the
  partition's whole history (eq. (20) [condd]; :mod:`tracker.bnp.group_hyper`).
* **Sharing** (eq. (2) [state1]: :math:`F_\theta` depends on the cluster's :math:`\theta`):
  each member's velocity takes a Kalman pseudo-measurement of its cluster's leave-one-out
  :math:`\theta` (the other current members, flat prior: the NIW's :math:`\kappa_0 = 0`; a
  member alone shares nothing) with covariance :math:`S_w + \mathrm{Cov}(\theta_c^{-\ell})`,
  moment-matched over the last sweep's full conditional of its label (:func:`share_velocity`);
  its turn rate takes the other members' (:func:`share_turn`); both before the next prediction.

The state (:class:`GroupState`) is flat plain data (the inner tracker's fields plus the
cluster level), so :mod:`tracker.state` snapshots it exactly.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from functools import cached_property, lru_cache
from typing import Literal

import msgspec
import numpy as np

from bnptrack.tracker import filtering as kf
from bnptrack.tracker._numerics import jit
from bnptrack.tracker.bnp.config import TRACKER_PRESETS, BnpConfig
from bnptrack.tracker.bnp.birth_tracker import LearnedBirthState, LearnedBirthTracker
from bnptrack.tracker.bnp.clusters import _Clusters
from bnptrack.tracker.bnp.filter import BnpState, BnpTracker, _cardinality
from bnptrack.tracker.bnp.group_fma import dot2, gemv2, sum2
from bnptrack.tracker.bnp.group_hyper import arrivals_loglik_grid, eppf_grid, size_factor, update_history
from bnptrack.tracker.bnp.group_merge import label_arrays, merge_exclusive
from bnptrack.tracker.bnp.group_partition import _inv_into, _move, gated_kernel
from bnptrack.tracker.bnp.group_share import informed, own_update, restrict
from bnptrack.tracker.bnp.urn import ALPHA_GRID, D_GRID, frame_loglik_grid, grid_mean, log_gamma_prior
from bnptrack.tracker.config import Fraction, NonNeg, PosInt, Positive, PositiveProb, Prob
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, frame_dt


_VEL = np.array([1, 3])
_POS = np.array([0, 2])


class GroupConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of the two-level tracker: the object level (``objects``) and the cluster level."""

    objects: BnpConfig = BnpConfig()
    """Measurement -> object level (the single-level DDP-EMM's settings)."""
    merge: Literal["exclusive", "objects"] = "exclusive"
    """How duplicate objects merge (distance ``objects.merge_distance``): "exclusive" never merges
    two objects that explain different measurements of one scan (:mod:`tracker.bnp.group_merge`;
    members of a young convoy); "objects" is the object level's own merge (as ``ddp-mb``)."""
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
    turn_within_std_deg: NonNeg = 0.5
    """Spread (deg/s) of members' turn rates about their cluster's; > 0 shares the turn rate too
    (:func:`share_turn`), 0 does not."""
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
    (:func:`fov_moments`)."""
    centroid_drift_std: Positive = 10.0
    """phi on the centroid: it moves with theta's velocity plus this random walk (m per scan)."""
    sweeps: PosInt = 6
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
    :func:`urn_log_weights`): "all" subtracts d from every cluster, transitioned ones included, and
    counts them all in the new cluster's d K; "occupied" discounts only the clusters the other
    objects occupy this frame and counts only those (eq. (19)'s D^(l-1)); identical when d = 0."""
    hyper_forgetting: PositiveProb = 0.98
    """Per-frame forgetting of the "arrivals" and "reseat" likelihoods ("history" has none)."""
    hyper_likelihood: Literal["history", "arrivals", "reseat"] = "history"
    """What (alpha_2, d) are inferred from: "history", the Pitman-Yor EPPF of the partition of
    every object that ever entered it, each counted once in its latest cluster (dead clusters
    kept); "arrivals", each object's seat once, when it enters the partition, given the members
    present then (forgetting ``hyper_forgetting``); "reseat", every frame's re-seating
    (:mod:`tracker.bnp.group_hyper`)."""


_PRESETS: dict[str, GroupConfig] = {
    "ddp": GroupConfig(objects=TRACKER_PRESETS["ddp-mb"]),
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
    "dpyp-groups": _PRESETS["dpyp"],
    "ddp-groups-proximity": _PRESETS["ddp-proximity"],
    "ddp-groups-snr": _PRESETS["ddp-snr"],
}


@dataclass(frozen=True)
class GroupState:
    """The inner :class:`BnpState`'s fields (one row per object) plus the cluster level.

    ``cluster`` (N,) is each object's cluster id (-1: not in the partition); ``group_ids``
    (G,), ``group_mean`` (G, 2), ``group_cov`` (G, 2, 2), ``group_count`` (G,) = v* hold the
    clusters that transition to the next frame (posterior of theta given all members).
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
    cluster: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    group_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    group_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    group_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    group_count: np.ndarray = field(default_factory=lambda: np.zeros(0))
    group_pos_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    group_pos_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    alpha2: float = 0.5
    d2: float = 0.0
    hyper2_loglik: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    next_group: int = 0
    counted: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(N,) the cluster id in which each object is counted in the partition's history (-1: never)."""
    hist_total: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(G,) objects ever counted in each of ``group_ids`` (the live clusters)."""
    dead_k: int = 0
    """Clusters of the history that have died (no longer transition)."""
    dead_n: int = 0
    """Objects counted in them."""
    dead_factor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(D,) their sum_j log (1-d)^(n_j - 1) (rising factorial) on the tracker's d grid."""
    birth_pos: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_pos)
    """The object level's recorded births (:class:`~tracker.bnp.birth_tracker.LearnedBirthState`;
    empty unless ``objects.learn_births`` / ``objects.learn_birth_velocity``), and below."""
    birth_cov: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_cov)
    birth_weight: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_weight)
    birth_loglik: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_loglik)
    birth_vel_stats: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_vel_stats)
    own_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    """(N, 5) each object's own estimate, without the sharing (``membership = "own"``; empty
    otherwise, and in snapshots that lack it: then every object starts from its state)."""
    own_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 5, 5)))
    """(N, 5, 5) its covariance."""

    def inner(self) -> BnpState:
        return BnpState(*[getattr(self, n) for n in _INNER_FIELDS])

    def inner_learned(self) -> LearnedBirthState:
        """The object level's state with its recorded births (``objects.learn_births``)."""
        return LearnedBirthState(*[getattr(self, n) for n in _LEARNED_FIELDS])


#: :class:`BnpState`'s fields in order (the first fields of :class:`GroupState`).
_INNER_FIELDS = tuple(f.name for f in fields(BnpState))
#: :class:`LearnedBirthState`'s fields in order: the above, then the ``birth_*`` memory.
_LEARNED_FIELDS = tuple(f.name for f in fields(LearnedBirthState))
_BIRTH_FIELDS = _LEARNED_FIELDS[len(_INNER_FIELDS):]


# -- conjugate Gaussian algebra on 2-vectors (closed-form 2x2) --------------------------------
def inv2(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of ``(..., 2, 2)`` matrices."""
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    inv = np.empty_like(A)
    inv[..., 0, 0], inv[..., 1, 1] = A[..., 1, 1], A[..., 0, 0]
    inv[..., 0, 1], inv[..., 1, 0] = -A[..., 0, 1], -A[..., 1, 0]
    return inv / det[..., None, None], det


@lru_cache(maxsize=32)
def _inv2_of_bytes(raw: bytes) -> np.ndarray:
    return inv2(np.frombuffer(raw).reshape(2, 2))[0]


def inv2_const(A: np.ndarray) -> np.ndarray:
    """:func:`inv2`'s inverse of one 2x2 matrix that repeats from frame to frame (a prior's
    covariance), remembered by its bytes: the same numbers without recomputing them."""
    return _inv2_of_bytes(np.ascontiguousarray(A, dtype=float).tobytes()).copy()


@lru_cache(maxsize=32)
def _information_of_bytes(cov_raw: bytes | None, mean_raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    h_lam = _FLAT_INFORMATION * np.eye(2) if cov_raw is None else _inv2_of_bytes(cov_raw).copy()
    return h_lam, h_lam @ np.frombuffer(mean_raw).copy()


def prior_information(h_cov: np.ndarray | None, h_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H_2's part in information form, ``(h_lam, h_lam @ h_mean)`` with ``h_lam`` =
    :func:`inv2_const` of ``h_cov`` (``None``: the flat prior's ``_FLAT_INFORMATION * I``);
    remembered by the bytes (the same priors every frame).  The arrays are shared: read only."""
    cov_raw = None if h_cov is None else np.ascontiguousarray(h_cov, dtype=float).tobytes()
    return _information_of_bytes(cov_raw, np.ascontiguousarray(h_mean, dtype=float).tobytes())


def theta_posterior(m0: np.ndarray, C0: np.ndarray, v: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Posterior of :math:`\theta` given prior :math:`\mathcal N(m_0, C_0)` and members
    :math:`v_j \sim \mathcal N(\theta, R_j)` (``v`` (n, 2), ``R`` (n, 2, 2)):
    :math:`\Lambda = C_0^{-1} + \sum_j R_j^{-1}`, mean :math:`\Lambda^{-1}(C_0^{-1} m_0 + \sum_j R_j^{-1} v_j)`."""
    C0i, _ = inv2(C0)
    Ri, _ = inv2(R)
    lam = C0i + Ri.sum(axis=0)
    eta = C0i @ m0 + np.einsum("nij,nj->i", Ri, v)
    cov, _ = inv2(lam)
    return cov @ eta, cov


def urn_log_weights(n: np.ndarray, v_star: np.ndarray, alpha: float, d: float,
                    occupied: bool = False) -> np.ndarray:
    r"""Log prior weights of one object's options: each table then a new one (eqs. (case1)-(case3),
    Pitman-Yor (eq1)-(eq3)).  ``occupied`` False (reading "all"): table :math:`c` weighs
    :math:`n_c + v^*_c - d` (D1/P1 if chosen this frame, D2/P2 if only transitioned), new
    :math:`\alpha + d K`, K = tables with :math:`n_c + v^*_c > 0`.  ``occupied`` True (reading
    "occupied"): the discount acts on the tables the other objects occupy this frame only: a
    chosen table :math:`n_c + v^*_c - d` (eq. (17)), a transitioned one not yet chosen
    :math:`v^*_c` (eq. (18) without its discount), new :math:`\alpha + d D^{(\ell-1)}` with
    :math:`D^{(\ell-1)}` = tables with :math:`n_c > 0`, "the clusters used by the previous objects"
    (eq. (19) as written).  Both sum to :math:`\sum n + \sum v^* + \alpha`.
    Tables with :math:`n_c + v^*_c = 0` get weight 0."""
    occ = (n + v_star) > 0
    if occupied:
        chosen = n > 0
        w = np.where(chosen, n + v_star - d, np.where(occ, v_star, 0.0))
        new = alpha + d * chosen.sum()
    else:
        w = np.where(occ, n + v_star - d, 0.0)
        new = alpha + d * occ.sum()
    with np.errstate(divide="ignore"):
        return np.log(np.append(w, new))


@dataclass(frozen=True)
class Shares:
    """The last sweep's conditionals: object ``obj[p]`` joins an option with probability ``w[p]``,
    whose theta, given the option's other members, is N(``mu[p]``, ``cov[p]``)."""

    obj: np.ndarray  # (P,)
    w: np.ndarray  # (P,)
    mu: np.ndarray  # (P, 2)
    cov: np.ndarray  # (P, 2, 2)

    @staticmethod
    def empty() -> "Shares":
        return Shares(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2, 2)))


@dataclass(frozen=True)
class Block:
    """One independent 2-vector part of theta: members ``v`` (L, 2) ~ N(theta, ``R`` (L, 2, 2));
    transitioned clusters' priors N(``prior_mean`` (G, 2), ``prior_cov`` (G, 2, 2)); H_2's part
    N(``h_mean``, ``h_cov``)."""

    v: np.ndarray
    R: np.ndarray
    prior_mean: np.ndarray
    prior_cov: np.ndarray
    h_mean: np.ndarray
    h_cov: np.ndarray


def _option_logw(n, v_star, alpha, d, logw, occupied=False) -> None:
    """Urn weights (:func:`urn_log_weights`) of every table; the first empty table stands for "new"."""
    K = 0
    for t in range(n.size):
        if occupied:
            K += 1 if n[t] > 0 else 0
        else:
            K += 1 if n[t] + v_star[t] > 0 else 0
    free = -1
    for t in range(n.size):
        load = n[t] + v_star[t]
        if load > 0:
            logw[t] = np.log(v_star[t]) if occupied and n[t] == 0 else np.log(load - d)
        elif free < 0:
            free = t
            logw[t] = np.log(alpha + d * K)
        else:
            logw[t] = -np.inf


def _draw(logw, w, u) -> int:
    """The option of uniform ``u`` given log weights ``logw`` (T,); ``w`` (T,) receives the
    normalised weights.  The numbers of ``w = exp(logw - max); w /= w.sum()`` and of
    ``min(searchsorted(cumsum(w), u, "right"), T - 1)``, in loops without temporaries
    (``sum`` and ``cumsum`` add in index order from the first entry)."""
    T = logw.size
    top = logw[0]
    for t in range(1, T):
        if logw[t] > top:
            top = logw[t]
    total = 0.0
    for t in range(T):
        w[t] = np.exp(logw[t] - top)
        total += w[t]
    for t in range(T):
        w[t] = w[t] / total
    acc = 0.0
    for t in range(T):
        acc += w[t]
        if acc > u:
            return t
    return T - 1


def _partition_kernel(v, R, lam0, eta0, h_lam, h_eta, v_star, z, alpha, d, u, rec_p, rec_mu, rec_cov,
                      occupied=False) -> None:
    """Collapsed Gibbs sweeps over ``z`` in place (numba-compiled when available); ``occupied``:
    the urn's reading (:func:`urn_log_weights`).

    ``v`` (P, L, 2), ``R`` (P, L, 2, 2): the members' parts; ``lam0``/``eta0`` (P, T, 2, 2)/(P, T, 2):
    the tables' priors; ``u`` (S, L) uniforms.  The last sweep's conditionals go to ``rec_p``
    (L, T); part 0's theta given the table's *other current members* and H_2 (``h_lam``,
    ``h_eta``: information form), not the transitioned prior, which carries object l's own past,
    goes to ``rec_mu`` (L, T, 2), ``rec_cov`` (L, T, 2, 2).
    """
    P, L, T = v.shape[0], v.shape[1], lam0.shape[1]
    n = np.zeros(T)
    lam, eta = lam0.copy(), eta0.copy()
    Ri = np.empty((P, L, 2, 2))
    Riv = np.empty((P, L, 2))
    for p in range(P):
        for l in range(L):
            _inv_into(R[p, l], Ri[p, l])
            gemv2(Ri[p, l], v[p, l], Riv[p, l])  # = Ri @ v (BLAS's rounding: group_fma)
    for l in range(L):
        _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, 1.0)
    logw = np.empty(T)
    cov = np.empty((2, 2))
    Si = np.empty((2, 2))
    # each table's theta posterior (cov, mu) per part, recomputed only when its members change:
    # the same operations on the same values as computing it for every object
    t_cov = np.empty((P, T, 2, 2))
    t_mu = np.empty((P, T, 2))
    fresh = np.zeros(T, dtype=np.bool_)
    A = np.empty((2, 2))
    r = np.empty(2)
    Sir = np.empty(2)
    B = np.empty((2, 2))
    e = np.empty(2)
    w = np.empty(T)
    S = u.shape[0]
    for s in range(S):
        for l in range(L):
            _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, -1.0)
            fresh[z[l]] = False
            _option_logw(n, v_star, alpha, d, logw, occupied)
            for t in range(T):
                if logw[t] == -np.inf:
                    continue
                if not fresh[t]:
                    for p in range(P):
                        _inv_into(lam[p, t], cov)
                        gemv2(cov, eta[p, t], t_mu[p, t])  # = cov @ eta, into place
                        t_cov[p, t] = cov
                    fresh[t] = True
                for p in range(P):
                    for i in range(2):  # t_cov + R and v - mu, into buffers
                        r[i] = v[p, l, i] - t_mu[p, t, i]
                        for j in range(2):
                            A[i, j] = t_cov[p, t, i, j] + R[p, l, i, j]
                    det = _inv_into(A, Si)
                    gemv2(Si, r, Sir)  # = Si @ r, into a buffer
                    logw[t] += -0.5 * dot2(r, Sir) - 0.5 * np.log(det) - np.log(2.0 * np.pi)
                    if p == 0 and s == S - 1:
                        for i in range(2):  # lam - lam0 + h_lam, eta - eta0 + h_eta entry by entry
                            e[i] = eta[0, t, i] - eta0[0, t, i] + h_eta[i]
                            for j in range(2):
                                B[i, j] = lam[0, t, i, j] - lam0[0, t, i, j] + h_lam[i, j]
                        _inv_into(B, rec_cov[l, t])
                        gemv2(rec_cov[l, t], e, rec_mu[l, t])
            k = _draw(logw, w, u[s, l])
            while w[k] == 0.0:  # never land on an impossible table through round-off
                k -= 1
            z[l] = k
            if s == S - 1:
                rec_p[l] = w
            _move(lam, eta, n, lam0, eta0, Ri, Riv, z[l], l, 1.0)
            fresh[z[l]] = False


_option_logw = jit(_option_logw)
_draw = jit(_draw)
_partition_kernel = jit(_partition_kernel)


def theta_sums(R: np.ndarray, v: np.ndarray, slot: np.ndarray, n_used: int, h_lam: np.ndarray,
               h_eta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Posterior mean ``(n_used, 2)`` and covariance ``(n_used, 2, 2)`` of each used cluster's
    block of theta: ``lam = h_lam + sum R_l^-1``, ``eta = h_eta + sum R_l^-1 v_l`` over the
    members ``l`` of the cluster ``slot[l]`` (in member order), ``cov = lam^-1``, ``mean = cov eta``.
    The 2x2 inverses as :func:`tracker.bnp.groups.inv2` (entries over the determinant), the
    products as ``np.einsum`` (from 0.0, in index order)."""
    lam = np.empty((n_used, 2, 2))
    eta = np.empty((n_used, 2))
    for g in range(n_used):  # entry by entry: a slice assignment compiles numba's string code
        for i in range(2):
            eta[g, i] = h_eta[i]
            for j in range(2):
                lam[g, i, j] = h_lam[i, j]
    for l in range(R.shape[0]):
        a, b, c, d = R[l, 0, 0], R[l, 0, 1], R[l, 1, 0], R[l, 1, 1]
        det = a * d - b * c
        i00, i01, i10, i11 = d / det, -b / det, -c / det, a / det
        g = slot[l]
        lam[g, 0, 0] += i00
        lam[g, 0, 1] += i01
        lam[g, 1, 0] += i10
        lam[g, 1, 1] += i11
        eta[g, 0] += 0.0 + i00 * v[l, 0] + i01 * v[l, 1]
        eta[g, 1] += 0.0 + i10 * v[l, 0] + i11 * v[l, 1]
    cov = np.empty((n_used, 2, 2))
    mean = np.empty((n_used, 2))
    for g in range(n_used):
        a, b, c, d = lam[g, 0, 0], lam[g, 0, 1], lam[g, 1, 0], lam[g, 1, 1]
        det = a * d - b * c
        cov[g, 0, 0], cov[g, 0, 1], cov[g, 1, 0], cov[g, 1, 1] = d / det, -b / det, -c / det, a / det
        mean[g, 0] = 0.0 + cov[g, 0, 0] * eta[g, 0] + cov[g, 0, 1] * eta[g, 1]
        mean[g, 1] = 0.0 + cov[g, 1, 0] * eta[g, 0] + cov[g, 1, 1] * eta[g, 1]
    return mean, cov


theta_sums = jit(theta_sums)


def _table_priors(prior_cov, prior_mean, h_lam, h_eta, lam0, eta0) -> None:  # pragma: no cover - compiled
    """Each table's prior in information form into ``lam0`` (T, 2, 2) and ``eta0`` (T, 2): the
    G transitioned tables' (2x2 inverses as :func:`inv2`, products as ``np.einsum``: from 0.0
    in index order), then H_2's (``h_lam``, ``h_eta``) for the new ones."""
    G = prior_cov.shape[0]
    for g in range(G):
        a, b, c, d = prior_cov[g, 0, 0], prior_cov[g, 0, 1], prior_cov[g, 1, 0], prior_cov[g, 1, 1]
        det = a * d - b * c
        i00, i01, i10, i11 = d / det, -b / det, -c / det, a / det
        lam0[g, 0, 0], lam0[g, 0, 1], lam0[g, 1, 0], lam0[g, 1, 1] = i00, i01, i10, i11
        eta0[g, 0] = 0.0 + i00 * prior_mean[g, 0] + i01 * prior_mean[g, 1]
        eta0[g, 1] = 0.0 + i10 * prior_mean[g, 0] + i11 * prior_mean[g, 1]
    for t in range(G, lam0.shape[0]):  # entry by entry: a slice assignment compiles numba's string code
        for i in range(2):
            eta0[t, i] = h_eta[i]
            for j in range(2):
                lam0[t, i, j] = h_lam[i, j]


def _collect_shares(rec_p, rec_mu, rec_cov, min_p):  # pragma: no cover - compiled
    """The options with conditional probability above ``min_p`` (row-major, as ``np.nonzero``), their
    weights normalised per object (sums in index order from 0.0, as ``np.bincount``), thetas."""
    L, T = rec_p.shape
    count = 0
    for l in range(L):
        for t in range(T):
            if rec_p[l, t] > min_p:
                count += 1
    obj = np.empty(count, dtype=np.int64)
    w = np.empty(count)
    mu = np.empty((count, 2))
    cov = np.empty((count, 2, 2))
    k = 0
    for l in range(L):
        first, total = k, 0.0
        for t in range(T):
            if rec_p[l, t] > min_p:
                obj[k], w[k], mu[k], cov[k] = l, rec_p[l, t], rec_mu[l, t], rec_cov[l, t]
                total += rec_p[l, t]
                k += 1
        for j in range(first, k):
            w[j] = w[j] / total
    return obj, w, mu, cov


def _compact(z, G, T):  # pragma: no cover - compiled
    """``z`` with the new tables (``>= G``) renumbered ``G, G + 1, ...`` in increasing order."""
    used = np.zeros(T, dtype=np.bool_)
    for l in range(z.size):
        used[z[l]] = True
    remap = np.arange(T)
    k = G
    for t in range(G, T):
        if used[t]:
            remap[t] = k
            k += 1
    out = np.empty(z.size, dtype=np.int64)
    for l in range(z.size):
        out[l] = remap[z[l]]
    return out


def _transition_kernel(z, ids, v0, R0, hl0, he0, v1, R1, hl1, he1, n_blocks):  # pragma: no cover - compiled
    """:meth:`GroupTracker._transition_out` compiled: the tables used by ``z`` in increasing order
    (``np.unique``), their ids ``ids[used]`` and member counts (float), and each block's theta
    posterior (:func:`theta_sums`; zeros for an absent second block)."""
    n_tab = 0
    for l in range(z.size):
        n_tab = max(n_tab, z[l] + 1)
    count_of = np.zeros(n_tab, dtype=np.int64)
    for l in range(z.size):
        count_of[z[l]] += 1
    pos = np.full(n_tab, -1, dtype=np.int64)
    n_used = np.int64(0)  # not 0: a literal start compiles theta_sums once more for n_used = Literal[int](0)
    for t in range(n_tab):
        if count_of[t] > 0:
            pos[t] = n_used
            n_used += 1
    g_ids, count = np.empty(n_used, dtype=np.int64), np.empty(n_used)
    for t in range(n_tab):
        if count_of[t] > 0:
            g_ids[pos[t]], count[pos[t]] = ids[t], count_of[t]
    slot = np.empty(z.size, dtype=np.int64)
    for l in range(z.size):
        slot[l] = pos[z[l]]
    m0, c0 = theta_sums(R0, v0, slot, n_used, hl0, he0)
    if n_blocks == 1:
        return g_ids, count, m0, c0, np.zeros((n_used, 2)), np.zeros((n_used, 2, 2))
    m1, c1 = theta_sums(R1, v1, slot, n_used, hl1, he1)
    return g_ids, count, m0, c0, m1, c1


_table_priors = jit(_table_priors)
_transition_kernel = jit(_transition_kernel)
_compact = jit(_compact)
_collect_shares = jit(_collect_shares)


#: H_2's velocity mean (read only).
_ZERO2 = np.zeros(2)
_ZERO2.flags.writeable = False

#: Information (1/m^2 s^-2) of the flat prior on a shared theta (kappa_0 = 0): an option with no
#: other member gives a pseudo-measurement of covariance ~1e10, i.e. no sharing.
_FLAT_INFORMATION = 1e-10


#: :func:`sample_partition`'s kernels: the full scan of every table per move (the reference),
#: the incremental urn state without the gate, and the gated kernel (the default;
#: :mod:`tracker.bnp.group_partition`).  All three draw the same sample bit for bit.
PARTITION_KERNELS = ("scan", "urn", "gated")


def sample_partition(rng: np.random.Generator, blocks: list[Block], v_star: np.ndarray, alpha: float, d: float,
                     init: np.ndarray, sweeps: int, flat_share: bool = False,
                     occupied: bool = False, kernel: str = "gated", stats: np.ndarray | None = None
                     ) -> tuple[np.ndarray, Shares]:
    """Collapsed Gibbs over object -> cluster assignments (eq. (Gibbs), theta integrated out).

    theta is the product of independent ``blocks`` (velocity first; optionally the centroid);
    transitioned clusters have cardinality ``v_star`` (G,); ``init`` (L,): start table
    (< G transitioned, -1 new).  Each object's conditional is the urn weight
    (:func:`urn_log_weights`) times the conjugate predictive of each block.  Returns the last
    sample (table indices, ``>= G`` for new clusters, compacted) and the last sweep's
    conditionals with the first block's leave-one-out theta given the other current members
    (prior H_2, or flat if ``flat_share``: the paper's kappa_0 = 0; :class:`Shares`).
    ``occupied``: the urn's reading of eqs. (17)-(19) (:func:`urn_log_weights`).  ``kernel``:
    one of :data:`PARTITION_KERNELS` (the same numbers; "gated" is the fast one).  ``stats``: an
    int64 array (2,) that receives the number of moves and of tables scored (added to; the "urn"
    and "gated" kernels), or None.
    """
    if kernel not in PARTITION_KERNELS:
        raise ValueError(f"sample_partition: unknown kernel {kernel!r} "
                         f"(expected one of {', '.join(PARTITION_KERNELS)})")
    parts = []
    for b in blocks:  # each block's arrays as they are (views allowed), H_2's part in information form
        parts += [np.ascontiguousarray(b.v, dtype=float), np.asarray(b.R, dtype=float), b.prior_cov, b.prior_mean,
                  *prior_information(b.h_cov, b.h_mean)]
    if len(blocks) == 1:
        parts += parts  # the second block's slot, unused (n_blocks = 1)
    h_lam, h_eta = prior_information(None if flat_share else blocks[0].h_cov, blocks[0].h_mean)
    u = rng.random((sweeps, blocks[0].v.shape[0]))
    counts = np.zeros(2, dtype=np.int64) if stats is None else stats
    z, *shares = _sample(PARTITION_KERNELS.index(kernel), parts[:12], len(blocks), h_lam, h_eta,
                         np.asarray(v_star, dtype=float), np.asarray(init, dtype=np.int64), float(alpha), float(d),
                         u, bool(occupied), counts)
    return z, Shares(*shares)


def _sample(mode, parts, n_blocks, s_lam, s_eta, v_star, init, alpha, d, u, occupied, stats):
    """:func:`sample_partition`'s compiled steps with the kernel ``mode`` (the index of
    :data:`PARTITION_KERNELS`): the inputs (:func:`_sample_setup`; ``parts``: the two blocks'
    six arrays), the sweeps, the sample compacted (:func:`_compact`).  The sweeps: ``mode`` 0,
    the reference, :func:`_partition_kernel` then :func:`_collect_shares` (compiled only when
    used); 1, 2: :func:`tracker.bnp.group_partition.gated_kernel` without, with the gate,
    counting into ``stats``.  ``s_lam``/``s_eta``: the shared theta's prior.  Calls from
    Python, not one kernel calling the others: numba optimises a kernel's callees again inside
    each compiled caller, so a wrapper kernel costs a first run seconds of compilation for
    microseconds per frame."""
    v, R, lam0, eta0, z, seated = _sample_setup(*parts, n_blocks, v_star, init)
    L, T = z.size, seated.size
    if mode == 0:
        rec_p, rec_mu, rec_cov = np.zeros((L, T)), np.zeros((L, T, 2)), np.zeros((L, T, 2, 2))
        _partition_kernel(v, R, lam0, eta0, s_lam, s_eta, seated, z, alpha, d, u, rec_p, rec_mu, rec_cov, occupied)
        obj, w, mu, cov = _collect_shares(rec_p, rec_mu, rec_cov, 1e-4)
    else:
        obj, w, mu, cov = gated_kernel(v, R, lam0, eta0, s_lam, s_eta, seated, z, alpha, d, u, occupied, mode == 2,
                                       1e-4, stats)
    return _compact(z, v_star.size, T), obj, w, mu, cov


def _sample_setup(v0, R0, pc0, pm0, hl0, he0, v1, R1, pc1, pm1, hl1, he1, n_blocks, v_star, init):  # pragma: no cover
    """The sweeps' inputs: the blocks' members stacked ``(P, L, 2)``, ``(P, L, 2, 2)``; the
    tables' priors (:func:`_table_priors`); the start (``init``, -1: a new table of its own);
    the tables' seated counts (``v_star``, then zeros)."""
    L, G = v0.shape[0], v_star.size
    T = G + L
    v = np.empty((n_blocks, L, 2))
    R = np.empty((n_blocks, L, 2, 2))
    lam0, eta0 = np.empty((n_blocks, T, 2, 2)), np.empty((n_blocks, T, 2))
    for p in range(n_blocks):
        vb, Rb = (v0, R0) if p == 0 else (v1, R1)
        for l in range(L):
            for i in range(2):
                v[p, l, i] = vb[l, i]
                for j in range(2):
                    R[p, l, i, j] = Rb[l, i, j]
        if p == 0:
            _table_priors(pc0, pm0, hl0, he0, lam0[0], eta0[0])
        else:
            _table_priors(pc1, pm1, hl1, he1, lam0[1], eta0[1])
    z = np.empty(L, dtype=np.int64)
    for l in range(L):
        z[l] = init[l] if init[l] >= 0 else G + l
    seated = np.zeros(T)
    for t in range(G):  # not seated[:G] = v_star: a slice assignment compiles numba's string code
        seated[t] = v_star[t]
    return v, R, lam0, eta0, z, seated


_sample_setup = jit(_sample_setup)


def share_velocity(mean: np.ndarray, cov: np.ndarray, shares: Shares, S_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Each member's state given the others' assignments: a Kalman pseudo-measurement of its velocity
    per option, moment-matched over the options.

    Option :math:`o` of object :math:`\ell` (weight :math:`w_o`, the Gibbs conditional of eq.
    (Gibbs)): the pseudo-measurement :math:`y = \hat\theta_o^{-\ell}` of :math:`H x = (v_x, v_y)`
    with covariance :math:`S_w + \mathrm{Cov}(\theta_o^{-\ell})`.  Since the weight already
    carries :math:`\mathcal N(\hat v_\ell; \hat\theta_o^{-\ell}, \mathrm{Cov}(\theta_o^{-\ell}) + P_{v,\ell} + S_w)`,
    the mixture is the exact conditional :math:`p(x_\ell \mid \text{others})`.  A new
    cluster's option (prior :math:`H_2`, vague) barely moves the state.  ``mean`` (L, 5), ``cov`` (L, 5, 5).
    """
    if shares.obj.size == 0:
        return mean, cov
    return _share_velocity_kernel(mean, cov, shares.obj, S_w, shares.mu, shares.cov, shares.w)


def _share_velocity_kernel(mean, cov, o, S_w, s_mu, s_cov, w):  # pragma: no cover - compiled
    """:func:`share_velocity`'s gains compiled, as its numpy code computed them: ``P = cov[o]``,
    ``PHt = P[:, :, _VEL]``, ``Si = inv2(P_vv + S_w + s_cov)`` (:func:`inv2`: entries over the
    determinant), ``K = PHt @ Si`` and ``KHP = K @ PHt'`` (numpy's stacked matmul: each entry
    :func:`tracker.bnp.group_fma.sum2`); then :func:`_share_moments`."""
    Q = o.size
    m, P = np.empty((Q, 5)), np.empty((Q, 5, 5))
    K, KHP = np.empty((Q, 5, 2)), np.empty((Q, 5, 5))
    A, Si = np.empty((2, 2)), np.empty((2, 2))
    vel = (1, 3)
    for q in range(Q):
        for i in range(5):  # not m[q] = mean[o[q]]: a slice assignment compiles numba's string code
            m[q, i] = mean[o[q], i]
            for j in range(5):
                P[q, i, j] = cov[o[q], i, j]
        for i in range(2):
            for j in range(2):
                A[i, j] = (P[q, vel[i], vel[j]] + S_w[i, j]) + s_cov[q, i, j]
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        Si[0, 0], Si[1, 1] = A[1, 1] / det, A[0, 0] / det
        Si[0, 1], Si[1, 0] = -A[0, 1] / det, -A[1, 0] / det
        for i in range(5):
            for j in range(2):
                K[q, i, j] = sum2(P[q, i, 1], Si[0, j], P[q, i, 3], Si[1, j])
        for i in range(5):
            for j in range(5):
                KHP[q, i, j] = sum2(K[q, i, 0], P[q, j, 1], K[q, i, 1], P[q, j, 3])
    return _share_moments(mean.shape[0], m, P, K, KHP, s_mu, w, o)


def _share_moments(N, m, P, K, KHP, s_mu, w, o):  # pragma: no cover - compiled
    """:func:`share_velocity`'s update and moment match after its gains ``K`` (Q, 5, 2) and
    ``KHP`` = K (P H')' (Q, 5, 5): ``mu = m + K (s_mu - H m)`` (the product as ``np.einsum``:
    from 0.0 in index order), ``Pu = P - KHP``; the mixture's mean and covariance per object,
    added in option order (``np.add.at``), then symmetrised.  Returns ``(N, 5)``, ``(N, 5, 5)``."""
    Q = o.size
    mu = np.empty((Q, 5))
    for q in range(Q):
        d0, d1 = s_mu[q, 0] - m[q, 1], s_mu[q, 1] - m[q, 3]
        for i in range(5):
            mu[q, i] = m[q, i] + (0.0 + K[q, i, 0] * d0 + K[q, i, 1] * d1)
    new_mean = np.zeros((N, 5))
    for q in range(Q):
        for i in range(5):
            new_mean[o[q], i] += w[q] * mu[q, i]
    new_cov = np.zeros((N, 5, 5))
    dev = np.empty(5)
    for q in range(Q):
        for i in range(5):
            dev[i] = mu[q, i] - new_mean[o[q], i]
        for i in range(5):
            for j in range(5):
                new_cov[o[q], i, j] += w[q] * ((P[q, i, j] - KHP[q, i, j]) + dev[i] * dev[j])
    sym = np.empty((N, 5, 5))
    for n in range(N):
        for i in range(5):
            for j in range(5):
                sym[n, i, j] = 0.5 * (new_cov[n, i, j] + new_cov[n, j, i])
    return new_mean, sym


_share_moments = jit(_share_moments)
_share_velocity_kernel = jit(_share_velocity_kernel)


def share_turn(mean: np.ndarray, cov: np.ndarray, omega: np.ndarray, var: np.ndarray, z: np.ndarray,
               within_var: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Each member's turn rate takes its cluster's leave-one-out turn rate as a pseudo-measurement.

    The members of a cluster share one turn rate (``groups`` scene; part of theta in eq. (2)
    [state1]); given the sample ``z``, member :math:`\ell`'s pseudo-measurement of :math:`x_4` is the
    information-weighted mean of the *other* members' turn rates ``omega`` (variances ``var``,
    flat prior), variance :math:`1/\sum_{j \ne \ell} \mathrm{var}_j^{-1}` + ``within_var``.
    A member alone takes none.  ``mean`` (L, 5), ``cov`` (L, 5, 5)."""
    if z.size < 2:
        return mean, cov
    new_mean, new_cov, shared = _share_turn_kernel(mean, cov, omega, var, z, float(within_var))
    return (new_mean, new_cov) if shared else (mean, cov)


def _share_turn_kernel(mean, cov, omega, var, z, within_var):  # pragma: no cover - compiled
    """:func:`share_turn` compiled: the information sums per cluster added in member order from
    0.0 (``np.bincount``), then each member with other members' information (> 0) updated as a
    scalar Kalman step on ``x_4``, its covariance symmetrised.  The third output: any updated."""
    L = z.size
    info, im = np.empty(L), np.empty(L)
    n_tables = 0
    for l in range(L):
        info[l] = 1.0 / var[l]
        im[l] = info[l] * omega[l]
        n_tables = max(n_tables, z[l] + 1)
    s_i, s_m = np.zeros(n_tables), np.zeros(n_tables)
    for l in range(L):
        s_i[z[l]] += info[l]
        s_m[z[l]] += im[l]
    out_mean, out_cov = mean.copy(), cov.copy()
    K, Pu = np.empty(5), np.empty((5, 5))
    shared = False
    for l in range(L):
        tot_i = s_i[z[l]] - info[l]
        if not tot_i > 0:
            continue
        shared = True
        y = (s_m[z[l]] - im[l]) / tot_i
        r = 1.0 / tot_i + within_var
        for i in range(5):
            K[i] = cov[l, i, 4] / (cov[l, 4, 4] + r)
            out_mean[l, i] = mean[l, i] + K[i] * (y - mean[l, 4])
        for i in range(5):
            for j in range(5):
                Pu[i, j] = cov[l, i, j] - K[i] * cov[l, 4, j]
        for i in range(5):
            for j in range(5):
                out_cov[l, i, j] = 0.5 * (Pu[i, j] + Pu[j, i])
    return out_mean, out_cov, shared


_share_turn_kernel = jit(_share_turn_kernel)


def fov_moments(detection, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance (2, 2) of the uniform distribution over ``detection``'s field of
    view (:meth:`tracker.models.clutter.Detection.visible`), on an ``n`` x ``n`` grid of cell
    centres over the square of half-side ``range_max`` about the sensor.  A pure function of a
    frozen ``detection``: remembered (:func:`_fov_moments`; every run of an experiment builds a
    tracker, and the grid costs some 8 ms), copies returned."""
    mean, cov = _fov_moments(detection, n)
    return mean.copy(), cov.copy()


@lru_cache(maxsize=16)
def _fov_moments(detection, n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fov_moments` computed (the arrays are shared: callers copy)."""
    r = detection.range_max
    g = (np.arange(n) + 0.5) / n * 2.0 * r - r
    X, Y = np.meshgrid(detection.sensor_x + g, detection.sensor_y + g, indexing="ij")
    x = np.zeros((X.size, 4))
    x[:, 0], x[:, 2] = X.ravel(), Y.ravel()
    inside = detection.visible(x)
    pts = x[inside][:, [0, 2]]
    return pts.mean(axis=0), np.cov(pts.T, bias=True)


def _rows_of(values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``values[rows]`` as int64 with -1 where ``rows`` is -1 (an object not in the last state)."""
    out = np.full(rows.size, -1, dtype=np.int64)
    have = rows >= 0
    out[have] = values[rows[have]]
    return out


@dataclass(frozen=True)
class GroupTracker:
    """Two-level DDP-EMM (``config.d == 0`` and not ``infer_d``) or DPY-STP tracker."""

    params: ModelParams
    config: GroupConfig = GroupConfig()
    name: str = "ddp"

    @cached_property
    def objects(self) -> BnpTracker:
        """The object level; with ``merge == "exclusive"`` its own merge is off (done in :meth:`_merge`)."""
        cfg = self.config
        objects = msgspec.structs.replace(cfg.objects, merge_distance=0.0) if cfg.merge == "exclusive" else cfg.objects
        learned = objects.learn_births or objects.learn_birth_velocity
        return (LearnedBirthTracker if learned else BnpTracker)(self.params, objects, self.name)

    @cached_property
    def learns_births(self) -> bool:
        return isinstance(self.objects, LearnedBirthTracker)

    @cached_property
    def alpha_grid(self) -> np.ndarray:
        return ALPHA_GRID if self.config.infer_alpha else np.array([self.config.alpha])

    @cached_property
    def d_grid(self) -> np.ndarray:
        return D_GRID if self.config.infer_d else np.array([self.config.d])

    @cached_property
    def S_w(self) -> np.ndarray:
        return self.config.within_std**2 * np.eye(2)

    @cached_property
    def S_share(self) -> np.ndarray:
        """The sharing pseudo-measurement's part of its covariance (``S_w`` plus the inflation)."""
        return self.S_w + self.config.share_inflation_std**2 * np.eye(2)

    @cached_property
    def h_cov(self) -> np.ndarray:
        """H_2's velocity covariance (:attr:`GroupConfig.h2`)."""
        std = self.config.objects.birth_velocity_std if self.config.h2 == "birth" else self.config.theta_std
        return std**2 * np.eye(2)

    @cached_property
    def h_pos(self) -> tuple[np.ndarray, np.ndarray]:
        """H_2's centroid mean and covariance (:attr:`GroupConfig.h2`)."""
        if self.config.h2 == "birth":
            return fov_moments(self.params.detection())
        return np.zeros(2), self.config.centroid_std**2 * np.eye(2)

    def initial_state(self) -> GroupState:
        inner = self.objects.initial_state()
        grid = np.zeros((self.alpha_grid.size, self.d_grid.size))
        return GroupState(**{f.name: getattr(inner, f.name) for f in fields(type(inner))},
                          alpha2=self.config.alpha, d2=self.config.d, hyper2_loglik=grid)

    def step(self, state: GroupState, frame: Frame, rng: np.random.Generator) -> tuple[GroupState, Estimate]:
        """One frame: the object level's step, then the object partition, theta, (alpha_2, d), sharing."""
        t0 = time.perf_counter()
        # scan periods since the last frame, from the stamps as the object level predicts
        # (tracker.types.frame_dt): frame numbers x T for regular frames, bit for bit
        steps = self.periods_since(state, frame)
        inner, est = self.objects.step(state.inner_learned() if self.learns_births else state.inner(), frame, rng)
        kept = None
        if self.config.merge == "exclusive":
            inner, est, kept = self._merge(inner, est)
        members = np.flatnonzero(inner.existence >= self.config.member_existence)
        src = self._previous_rows(state, inner.labels)  # each object's row in the last state (-1: new)
        init_ids = _rows_of(state.cluster, src[members])
        own = self._own(state, inner, steps, src) if self._keeps_own else None
        base = (inner.mean, inner.cov) if own is None or self.config.share_base == "state" else own
        mean, cov = base[0].copy(), base[1].copy()
        m_mean, m_cov = mean[members], cov[members]  # the members' states (copies; the blocks' views)
        read = None if own is None else (own if self.config.membership == "own" else (inner.mean, inner.cov))
        blocks = self._blocks(state, steps, *((m_mean, m_cov) if read is None else (read[0][members], read[1][members])))
        z, shares = self._partition(rng, state, blocks, init_ids)
        if self.config.sharing and members.size:
            m_mean, m_cov = self._share(m_mean, m_cov, shares)
        if self.config.turn_within_std_deg > 0 and members.size:
            m_mean, m_cov = share_turn(m_mean, m_cov, base[0][members, 4], base[1][members, 4, 4], z,
                                       self._turn_within_var)
        if members.size:
            mean[members], cov[members] = m_mean, m_cov
        ids, next_group = self._ids(state, z)
        cluster = np.full(len(inner.labels), -1, dtype=np.int64)
        cluster[members] = ids[z]
        g_ids, g_count, (g_mean, g_cov), (p_mean, p_cov) = self._transition_out(blocks, z, ids)
        hist = self._history(state, inner.labels, members, ids[z], g_ids, src)
        alpha2, d2, hyper2 = self._hyper(state, z, init_ids < 0, hist)
        new_state = GroupState(inner.frame, inner.stamp_ns, inner.labels, mean, cov, inner.existence,
                               inner.popularity, inner.alpha, inner.d, inner.hyper_loglik, cluster, g_ids,
                               g_mean, g_cov, g_count, p_mean, p_cov, alpha2, d2, hyper2, next_group, *hist,
                               *(getattr(inner, n) for n in _BIRTH_FIELDS if self.learns_births),
                               **({} if own is None else {"own_mean": own[0], "own_cov": own[1]}))
        return new_state, self._estimate(new_state, est, t0, kept)

    # -- pieces ---------------------------------------------------------------------------
    def _merge(self, inner: BnpState, est: Estimate) -> tuple[BnpState, Estimate, list | None]:
        """The object level's duplicates merged without merging objects of one scan
        (:func:`tracker.bnp.group_merge.merge_exclusive`); the estimate's tracks re-read at the
        object level's threshold and its assignments renamed to the merged labels."""
        obj = self.config.objects
        c = _Clusters(inner.labels, inner.mean, inner.cov, inner.existence, inner.popularity)
        arrays = label_arrays(inner.labels, est.assignments, est.assignment_prob, 0.5, inner.frame)
        merged, renamed = merge_exclusive(c, obj.merge_distance, None, arrays)
        if not renamed:
            return inner, est, None
        inner = replace(inner, labels=merged.labels, mean=merged.mean, cov=merged.cov,
                        existence=merged.existence, popularity=merged.popularity)
        # the tracks re-read at the threshold: their labels and existences (the states are the
        # cluster level's, read by _estimate)
        kept = [(inner.labels[i], r) for i, r in enumerate(inner.existence.tolist()) if r > obj.existence_threshold]
        assignments = tuple(renamed.get(a, a) if a is not None else None for a in est.assignments)
        diag = dict(est.diagnostics, n_clusters=float(len(inner.labels)), n_tracks=float(len(kept)))
        return inner, Estimate(est.frame, est.stamp_ns, (), assignments, est.assignment_prob, diag,
                               _cardinality(inner.existence)), kept

    @staticmethod
    def _previous_rows(state: GroupState, labels: tuple[str, ...]) -> np.ndarray:
        """Each of ``labels``' row in ``state`` (-1: not there; a label twice in ``state``: its last row)."""
        row = {lab: i for i, lab in enumerate(state.labels)}
        return np.array([row.get(lab, -1) for lab in labels], dtype=np.int64)

    @cached_property
    def _keeps_own(self) -> bool:
        """Whether each object's own estimate is kept (``membership`` or ``share_base`` "own")."""
        return self.config.membership == "own" or self.config.share_base == "own"

    def _own(self, state: GroupState, inner: BnpState, steps: float, src: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""Each object's own estimate (``membership = "own"``), rows of ``inner``: the object level's
        posterior where the object's state never took a share (new objects, and rows whose state
        equals their own estimate); else its own last estimate predicted over ``steps`` scan
        periods by the object level's filter and updated with the measurement information the object
        level's update added to the shared prediction (:func:`tracker.bnp.group_share.own_update`)."""
        own_mean, own_cov = inner.mean.copy(), inner.cov.copy()
        if state.own_mean.shape[0] != len(state.labels):  # no own estimates (first frame, older snapshot)
            return own_mean, own_cov
        have = np.flatnonzero(src >= 0)
        rows = src[have]
        apart = (np.any(state.own_mean[rows] != state.mean[rows], axis=1)
                 | np.any(state.own_cov[rows] != state.cov[rows], axis=(1, 2)))
        if not apart.any():
            return own_mean, own_cov
        have, rows = have[apart], rows[apart]
        dt = steps * self.params.T
        motion = self.objects.motion if dt == self.params.T else self.params.motion(dt)
        predict = kf.ukf_predict if self.config.objects.filter == "ukf" else kf.ekf_predict
        m, P = predict(motion, np.concatenate([state.mean[rows], state.own_mean[rows]]),
                       np.concatenate([state.cov[rows], state.own_cov[rows]]))  # shared rows, then own
        K = rows.size
        own_mean[have], own_cov[have] = own_update((m[:K], P[:K]), (inner.mean[have], inner.cov[have]),
                                                   (m[K:], P[K:]))
        return own_mean, own_cov

    @cached_property
    def _turn_within_var(self) -> float:
        return np.deg2rad(self.config.turn_within_std_deg) ** 2

    def periods_since(self, state: GroupState, frame: Frame) -> float:
        r"""Scan periods :math:`\Delta t / T` since the last frame (1 before the first)."""
        T = self.params.T
        n = 1 if state.frame < 0 else frame.frame - state.frame
        dt = frame_dt(state.frame, state.stamp_ns, frame.frame, frame.stamp_ns, T)
        return n if dt == n * T else dt / T

    def _blocks(self, state: GroupState, steps: float, mean: np.ndarray, cov: np.ndarray) -> list[Block]:
        r"""theta's parts with the transitioned clusters' priors moved by :math:`\varphi`: the velocity
        random-walks (``theta_drift_std``); the centroid moves with the velocity (and ``centroid_drift_std``)."""
        cfg = self.config
        dt = steps * self.params.T
        vel_drift, pos_within, pos_drift = self._phi_terms(steps)
        # strided slices (1::2 = _VEL, 0::2 = _POS on the first four entries): the same numbers as
        # fancy indexing, one copy fewer
        vel = Block(mean[:, 1:4:2], cov[:, 1:4:2, 1:4:2] + self.S_w, state.group_mean,
                    state.group_cov + vel_drift, _ZERO2, self.h_cov)
        if not cfg.centroid:
            return [vel]
        pos = Block(mean[:, 0:3:2], cov[:, 0:3:2, 0:3:2] + pos_within, state.group_pos_mean + dt * state.group_mean,
                    state.group_pos_cov + dt**2 * state.group_cov + pos_drift, *self.h_pos)
        return [vel, pos]

    @cached_property
    def _phi_memo(self) -> dict:
        return {}

    def _phi_terms(self, steps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_blocks`' constant matrices for ``steps`` scan periods (remembered; read only):
        theta's random walk ``steps theta_drift_std^2 I``, the members' spread about the centroid
        ``within_pos_std^2 I`` and the centroid's walk ``steps centroid_drift_std^2 I``."""
        hit = self._phi_memo.get(steps)
        if hit is None:
            cfg, eye = self.config, np.eye(2)
            hit = (steps * cfg.theta_drift_std**2 * eye, cfg.within_pos_std**2 * eye,
                   steps * cfg.centroid_drift_std**2 * eye)
            if len(self._phi_memo) < 64:
                self._phi_memo[steps] = hit
        return hit

    def _share(self, mean: np.ndarray, cov: np.ndarray, shares: Shares) -> tuple[np.ndarray, np.ndarray]:
        """:func:`share_velocity` to the members with enough velocity information (``share_min_info``)."""
        keep = informed(cov, self.config.objects.birth_velocity_std**2, self.config.share_min_info)
        if keep.all():
            return share_velocity(mean, cov, shares, self.S_share)
        rows, obj = restrict(shares.obj, keep)
        mean, cov = mean.copy(), cov.copy()
        if keep.any():
            sub = Shares(obj, shares.w[rows], shares.mu[rows], shares.cov[rows])
            mean[keep], cov[keep] = share_velocity(mean[keep], cov[keep], sub, self.S_share)
        return mean, cov

    def _partition(self, rng, state: GroupState, blocks: list[Block], init_ids) -> tuple[np.ndarray, Shares]:
        """Object -> cluster Gibbs (:func:`sample_partition`) warm-started at last frame's clusters."""
        slot = {int(g): i for i, g in enumerate(state.group_ids.tolist())}
        init = np.array([slot.get(int(g), -1) for g in init_ids], dtype=np.int64)
        if init.size == 0:
            return np.zeros(0, dtype=np.int64), Shares.empty()
        return sample_partition(rng, blocks, state.group_count, state.alpha2, state.d2, init, self.config.sweeps,
                                flat_share=self.config.share_prior == "flat",
                                occupied=self.config.urn_reading == "occupied")

    def _ids(self, state: GroupState, z: np.ndarray) -> tuple[np.ndarray, int]:
        """Cluster id of each table: a transitioned one keeps its id, a new one takes the next."""
        G = state.group_ids.size
        n_new = int(z.max()) - G + 1 if z.size and z.max() >= G else 0
        ids = np.concatenate([state.group_ids, state.next_group + np.arange(n_new)]).astype(np.int64)
        return ids, state.next_group + n_new

    def _transition_out(self, blocks: list[Block], z, ids) -> tuple:
        """Clusters with members (v* >= 1) and each block's theta posterior (prior H_2, information
        form summed over the members: :func:`theta_posterior`, vectorised) for the next frame."""
        parts = []
        for b in blocks:  # compiled: theta_posterior's sums over each cluster's members, vectorised
            parts += [np.ascontiguousarray(b.v), b.R, *prior_information(b.h_cov, b.h_mean)]  # one layout: one compile
        g_ids, count, *moments = _transition_kernel(z, ids, *(parts * 2)[:8], len(blocks))
        return g_ids, count, moments[:2], moments[2:]

    def _history(self, state: GroupState, labels: tuple[str, ...], members: np.ndarray, member_ids: np.ndarray,
                 g_ids: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int, int, np.ndarray]:
        """The partition of every object ever in it (:func:`tracker.bnp.group_hyper.update_history`):
        the members' counts moved to their clusters; clusters that no longer transition folded into
        the dead clusters' sufficient statistics.  ``rows``: each label's row in ``state``
        (:meth:`_previous_rows`, computed when not given).  Returns the state's history fields."""
        if rows is None:
            rows = self._previous_rows(state, labels)
        counted = _rows_of(state.counted, rows)
        totals = dict(zip(state.group_ids.tolist(), state.hist_total.tolist()))
        counted = update_history(counted, members, member_ids, totals)
        live = set(g_ids.tolist())
        dead = np.array([t for c, t in totals.items() if c not in live and t > 0], dtype=np.int64)
        factor = state.dead_factor if state.dead_factor.size else np.zeros(self.d_grid.size)
        if dead.size:
            factor = factor + size_factor(self.d_grid, dead)
        hist_total = np.array([totals[g] for g in g_ids.tolist()], dtype=np.int64)
        return counted, hist_total, state.dead_k + dead.size, state.dead_n + int(dead.sum()), factor

    def _history_loglik(self, hist: tuple) -> np.ndarray:
        """The Pitman-Yor EPPF (:func:`tracker.bnp.group_hyper.eppf_grid`) of the history on the grid."""
        _, total, dead_k, dead_n, dead_factor = hist
        factor = dead_factor + size_factor(self.d_grid, total)
        return eppf_grid(self.alpha_grid[:, None], self.d_grid[None, :], int(total.size + dead_k),
                         int(total.sum() + dead_n), factor)

    def _hyper(self, state: GroupState, z: np.ndarray, arrived: np.ndarray, hist: tuple
               ) -> tuple[float, float, np.ndarray]:
        """(alpha_2, d) on the grid given the object partition: the EPPF of its whole history
        (:meth:`_history_loglik`), the arrivals' Pitman-Yor predictive
        (:func:`tracker.bnp.group_hyper.arrivals_loglik_grid`) or the re-seating
        (:func:`tracker.bnp.urn.frame_loglik_grid`); ``arrived``: members new to the partition."""
        cfg = self.config
        if not cfg.infer_alpha and not cfg.infer_d:
            return state.alpha2, state.d2, state.hyper2_loglik
        if cfg.hyper_likelihood == "history":
            return self._history_hyper(hist)
        if cfg.hyper_likelihood == "arrivals":
            hyper = cfg.hyper_forgetting * state.hyper2_loglik + arrivals_loglik_grid(
                self.alpha_grid[:, None], self.d_grid[None, :], z, arrived)
        else:
            hyper = cfg.hyper_forgetting * state.hyper2_loglik + self._reseat_loglik(state, z)
        return self._grid_posterior(hyper)

    def _grid_posterior(self, hyper: np.ndarray) -> tuple[float, float, np.ndarray]:
        """Posterior means of (alpha_2, d) on the grid given the log-likelihood ``hyper`` and the priors."""
        log_post = hyper + self._alpha_log_prior[:, None]
        if self._d_log_prior is not None:
            log_post = log_post + self._d_log_prior[None, :]
        alpha, d = grid_mean(log_post, self.alpha_grid, self.d_grid)
        return alpha, d, hyper

    @cached_property
    def _alpha_log_prior(self) -> np.ndarray:
        """alpha_2's Gamma prior on the grid plus log alpha (the grid is uniform in log alpha)."""
        cfg = self.config
        return log_gamma_prior(self.alpha_grid, cfg.alpha_shape, cfg.alpha_scale) + np.log(self.alpha_grid)

    @cached_property
    def _d_log_prior(self) -> np.ndarray | None:
        cfg = self.config
        if cfg.infer_d and cfg.d_prior == "gamma":
            return log_gamma_prior(np.maximum(self.d_grid, 1e-12), cfg.d_shape, cfg.d_scale)
        return None

    @cached_property
    def _history_memo(self) -> dict:
        """The last history's key and result (:meth:`_history_hyper`)."""
        return {}

    def _history_hyper(self, hist: tuple) -> tuple[float, float, np.ndarray]:
        """(alpha_2, d, log-likelihood) from the history's EPPF (:meth:`_history_loglik`).  The
        history changes only when an object joins or leaves a cluster: a frame whose history
        equals the last one's (live cluster totals, dead clusters' statistics) reuses its result,
        which is a pure function of them."""
        _, total, dead_k, dead_n, dead_factor = hist
        key = (total.tobytes(), int(dead_k), int(dead_n), np.asarray(dead_factor).tobytes())
        memo = self._history_memo
        hit = memo.get("last")
        if hit is not None and hit[0] == key:
            alpha, d, hyper = hit[1]
            return alpha, d, hyper.copy()
        alpha, d, hyper = self._grid_posterior(self._history_loglik(hist))
        memo["last"] = (key, (alpha, d, hyper.copy()))
        return alpha, d, hyper

    def _reseat_loglik(self, state: GroupState, z: np.ndarray) -> np.ndarray:
        """Every member's seat of this frame counted (objects as customers, clusters as tables)."""
        G = state.group_ids.size
        counts = np.bincount(z[z < G], minlength=G) if G else np.zeros(0, dtype=int)
        n_new = int(np.unique(z[z >= G]).size)
        return frame_loglik_grid(self.alpha_grid[:, None], self.d_grid[None, :],
                                 mass=float(state.group_count.sum()), d_bar=float(G), n_object=float(z.size),
                                 n_new=n_new, seated_popularity=state.group_count, seated_counts=counts)

    def _estimate(self, state: GroupState, est: Estimate, t0: float, kept: list | None = None) -> Estimate:
        """The tracks (``kept``: labels and existences re-read by :meth:`_merge`, else the object
        level's) with the cluster level's states and their clusters; each track's state and
        covariance are rows of one fresh copy."""
        row = {lab: i for i, lab in enumerate(state.labels)}
        kept = [(t.label, t.existence) for t in est.tracks] if kept is None else kept
        idx = np.array([row[lab] for lab, _ in kept], dtype=np.int64)
        # rows of the copies as views (list(): one pass in C, not an index per track)
        mean, cov, cluster = list(state.mean[idx]), list(state.cov[idx]), state.cluster[idx].tolist()
        tracks = [TrackEstimate(lab, m, P, r, None if g < 0 else g)
                  for (lab, r), m, P, g in zip(kept, mean, cov, cluster)]
        diag = dict(est.diagnostics)
        diag.update(alpha2=state.alpha2, d2=state.d2, n_groups=float(state.group_ids.size),
                    ms=(time.perf_counter() - t0) * 1e3)
        # the object level's distribution (recomputed by _merge when it merged): the group level
        # moves states, not existences
        return Estimate(est.frame, est.stamp_ns, tuple(tracks), est.assignments, est.assignment_prob, diag,
                        est.cardinality_pmf)


def make_group_tracker(name: str, params: ModelParams, config: GroupConfig | None = None) -> GroupTracker:
    """Build the two-level ``ddp`` or ``dpyp`` (or a name of :data:`GROUP_PRESETS`, e.g. the alias
    ``ddp-groups``) with its preset unless ``config`` is given."""
    if name not in GROUP_PRESETS:
        raise ValueError(f"unknown two-level tracker {name!r} (expected one of {', '.join(GROUP_PRESETS)})")
    return GroupTracker(params, config if config is not None else GROUP_PRESETS[name], name)
