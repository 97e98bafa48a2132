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
from dataclasses import dataclass, fields, replace
from functools import cached_property

import msgspec
import numpy as np

from bnptrack.tracker import filtering as kf
from bnptrack.tracker.bnp.birth_tracker import LearnedBirthTracker
from bnptrack.tracker.bnp.clusters import _Clusters
from bnptrack.tracker.bnp.filter import BnpState, BnpTracker, _cardinality
from bnptrack.tracker.bnp.group_config import GROUP_PRESETS, GroupConfig
from bnptrack.tracker.bnp.group_hyper import GroupHyper
from bnptrack.tracker.bnp.group_merge import label_arrays, merge_exclusive
from bnptrack.tracker.bnp.group_sample import Block, Shares, sample_partition
from bnptrack.tracker.bnp.group_share import (informed, own_update, restrict, share_turn, share_velocity,
                                               together_scans)
from bnptrack.tracker.bnp.group_state import _BIRTH_FIELDS, GroupState, _rows_of, previous_rows
from bnptrack.tracker.bnp import identity
from bnptrack.tracker.calibration import ExistenceCalibration, calibrate, from_config
from bnptrack.tracker.bnp.group_theta import _ZERO2, _transition_kernel, fov_moments, prior_information
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, frame_dt

__all__ = ["GROUP_PRESETS", "GroupConfig", "GroupState", "GroupTracker", "make_group_tracker"]


_VEL = np.array([1, 3])
_POS = np.array([0, 2])


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
        objects = msgspec.structs.replace(cfg.objects, calibration_weight=0.0)
        objects = msgspec.structs.replace(objects, merge_distance=0.0) if cfg.merge == "exclusive" else objects
        learned = objects.learn_births or objects.learn_birth_velocity
        return (LearnedBirthTracker if learned else BnpTracker)(self.params, objects, self.name)

    @cached_property
    def learns_births(self) -> bool:
        return isinstance(self.objects, LearnedBirthTracker)

    @cached_property
    def hyper(self) -> GroupHyper:
        """The cluster level's (alpha_2, d): their grid, priors and the partition's history."""
        return GroupHyper(self.config)

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

    def warm_up_kernels(self) -> None:
        """Compile the velocity sharing's kernel on a one-member dummy (:func:`tracker.registry.warm_up`):
        with ``share_after`` a few warm-up frames never seat two objects together that long."""
        if self.config.sharing and self.config.share_after > 0:
            shares = Shares(np.zeros(1, dtype=np.int64), np.ones(1), np.zeros((1, 2)), np.eye(2)[None].copy())
            share_velocity(np.zeros((1, 5)), np.eye(5)[None].copy(), shares, self.S_share)

    def initial_state(self) -> GroupState:
        inner = self.objects.initial_state()
        grid = np.zeros((self.hyper.alpha_grid.size, self.hyper.d_grid.size))
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
        src = previous_rows(state, inner.labels)  # each object's row in the last state (-1: new)
        init_ids = _rows_of(state.cluster, src[members])
        own = self._own(state, inner, steps, src) if self._keeps_own else None
        base = (inner.mean, inner.cov) if own is None or self.config.share_base == "state" else own
        mean, cov = base[0].copy(), base[1].copy()
        m_mean, m_cov = mean[members], cov[members]  # the members' states (copies; the blocks' views)
        read = None if own is None else (own if self.config.membership == "own" else (inner.mean, inner.cov))
        blocks = self._blocks(state, steps, *((m_mean, m_cov) if read is None else (read[0][members], read[1][members])))
        z, shares = self._partition(rng, state, blocks, init_ids)
        ids, next_group = self._ids(state, z)
        together = None
        if self.config.share_after > 0 or self.config.crossing_scans > 0:
            previous = _rows_of(state.together, src[members]) if state.together.size == len(state.labels) else None
            together = together_scans(ids[z], init_ids, previous)
        if self.config.sharing and members.size:
            m_mean, m_cov = self._share(m_mean, m_cov, shares, together)
        if self.config.turn_within_std_deg > 0 and members.size:
            m_mean, m_cov = share_turn(m_mean, m_cov, base[0][members, 4], base[1][members, 4, 4], z,
                                       self._turn_within_var)
        if members.size:
            mean[members], cov[members] = m_mean, m_cov
        cluster = np.full(len(inner.labels), -1, dtype=np.int64)
        cluster[members] = ids[z]
        g_ids, g_count, (g_mean, g_cov), (p_mean, p_cov) = self._transition_out(blocks, z, ids)
        hist = self.hyper.history(state, inner.labels, members, ids[z], g_ids, src)
        alpha2, d2, hyper2 = self.hyper.posterior(state, z, init_ids < 0, hist)
        new_state = GroupState(inner.frame, inner.stamp_ns, inner.labels, mean, cov, inner.existence,
                               inner.popularity, inner.alpha, inner.d, inner.hyper_loglik, cluster, g_ids,
                               g_mean, g_cov, g_count, p_mean, p_cov, alpha2, d2, hyper2, next_group, *hist,
                               *(getattr(inner, n) for n in _BIRTH_FIELDS if self.learns_births),
                               **({} if own is None else {"own_mean": own[0], "own_cov": own[1]}))
        if together is not None:
            full = np.zeros(len(inner.labels), dtype=np.int64)
            full[members] = together
            new_state = replace(new_state, together=full)
        if self.config.crossing_scans > 0:
            info = self._information(state, inner, steps, src)
            new_state, est, kept = identity.check_labels(state, new_state, src, own, info, est, kept, self.config,
                                                         self._predict)
        return calibrate(self.calibration, state, new_state, self._estimate(new_state, est, t0, kept))

    @cached_property
    def calibration(self) -> ExistenceCalibration | None:
        """The published existence's calibration (``objects.calibration_*``, :mod:`tracker.calibration`;
        None: off).  The object level's own is off: the tracks are published here."""
        return from_config(self.params, self.config.objects)

    # -- pieces ---------------------------------------------------------------------------
    def _merge(self, inner: BnpState, est: Estimate) -> tuple[BnpState, Estimate, list | None]:
        """The object level's duplicates merged without merging objects of one scan
        (:func:`tracker.bnp.group_merge.merge_exclusive`); the estimate's tracks re-read at the
        object level's threshold and its assignments renamed to the merged labels."""
        obj = self.config.objects
        c = _Clusters(inner.labels, inner.mean, inner.cov, inner.existence, inner.popularity)
        arrays = label_arrays(inner.labels, est.assignments, est.assignment_prob, 0.5, inner.frame)
        reported = obj.existence_threshold if self.config.merge_label == "reported" else None
        merged, renamed = merge_exclusive(c, obj.merge_distance, None, arrays, reported)
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

    def _information(self, state: GroupState, inner: BnpState, steps: float, src: np.ndarray) -> tuple:
        """The measurement information (:func:`tracker.bnp.identity.measurement_information`) the
        object level's update gave each row of ``inner`` (zeros for a new object)."""
        have = np.flatnonzero(src >= 0)
        lam, eta = np.zeros_like(inner.cov), np.zeros_like(inner.mean)
        if have.size:
            m_s, P_s = self._predict(state.mean[src[have]], state.cov[src[have]], steps * self.params.T)
            lam[have], eta[have] = identity.measurement_information(m_s, P_s, inner.mean[have], inner.cov[have])
        return lam, eta

    def _predict(self, m: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The object level's prediction of the rows ``(m, P)`` over ``dt`` seconds."""
        motion = self.objects.motion if dt == self.params.T else self.params.motion(dt)
        predict = kf.ukf_predict if self.config.objects.filter == "ukf" else kf.ekf_predict
        return predict(motion, m, P)

    @cached_property
    def _keeps_own(self) -> bool:
        """Whether each object's own estimate is kept (``membership`` or ``share_base`` "own", or
        the crossing check)."""
        cfg = self.config
        return cfg.membership == "own" or cfg.share_base == "own" or cfg.crossing_scans > 0

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
        # shared rows, then own
        m, P = self._predict(np.concatenate([state.mean[rows], state.own_mean[rows]]),
                             np.concatenate([state.cov[rows], state.own_cov[rows]]), steps * self.params.T)
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

    def _share(self, mean: np.ndarray, cov: np.ndarray, shares: Shares, together: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """:func:`share_velocity` to the members with enough velocity information (``share_min_info``)
        and, with ``share_after``, that have sat with another object for that many scans (``together``)."""
        keep = informed(cov, self.config.objects.birth_velocity_std**2, self.config.share_min_info)
        if together is not None:
            keep &= together >= self.config.share_after
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
        form summed over the members: :func:`tracker.bnp.group_theta.theta_posterior`, vectorised)
        for the next frame."""
        parts = []
        for b in blocks:  # compiled: theta_posterior's sums over each cluster's members, vectorised
            parts += [np.ascontiguousarray(b.v), b.R, *prior_information(b.h_cov, b.h_mean)]  # one layout: one compile
        g_ids, count, *moments = _transition_kernel(z, ids, *(parts * 2)[:8], len(blocks))
        return g_ids, count, moments[:2], moments[2:]

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
