r"""GLMB baseline: joint prediction-update with Gibbs-sampled truncation.

Vo, Vo & Hoang, "An Efficient Implementation of the Generalized Labeled Multi-Bernoulli
Filter", IEEE TSP 65(8), 2017 (arXiv:1606.08350), Gaussian (UKF or EKF) implementation with a
labeled multi-Bernoulli birth, as in the authors' ``jointglmb`` UKF demo.  ``docs/glmb.md``
lists the equations, the caps and the measured accuracy.

The GLMB filtering density :math:`\pi(X) = \Delta(X) \sum_{I, \xi} w^{(I,\xi)}
\delta_I[\mathcal L(X)] [p^{(\xi)}]^X` is held as plain arrays (:class:`GlmbState`):

* a **track table**: one row per (label, Gaussian) -- ``labels`` (T,), ``mean`` (T, 5),
  ``cov`` (T, 5, 5); a row is one label's density :math:`p^{(\xi)}(\cdot, \ell)` under one
  association history;
* **hypotheses**: ``hyp_tracks`` (H, maxN) sorted track-table rows padded with ``-1`` and
  normalised ``log_w`` (H,).

One frame (:meth:`GlmbTracker.step`):

1. predict every table row (the candidate survivors) and append the birth components;
2. per candidate row, the log of the :math:`\eta` costs over the options *dies / missed /
   detected by* :math:`z_j` (shared by all hypotheses; chi-square gating);
3. per hypothesis, Gibbs chains over the assignment vector :math:`\gamma` of its survivors
   plus the births, started at the optimal assignment, with a number of samples
   proportional to :math:`\sqrt{w}` (the authors' allocation);
4. distinct samples become child hypotheses (weight = parent weight x product of
   :math:`\eta`), children with identical track sets are merged, pruned and capped;
5. the new track table holds the (row, measurement) pairs used by the kept children, with
   the Gaussian update computed once per pair.

The Gibbs sweeps and the linear assignments run in numba-compiled kernels on plain arrays
(``BNPTRACK_NO_JIT=1`` runs the same functions interpreted); the sweeps consume uniforms
drawn up front from ``rng`` in the order of the vectorised reference
:func:`gibbs_chains_numpy`, so the output is identical to it.

Everything random comes from the caller's ``rng``; ``step`` is a pure function.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Annotated, Any, Literal, Protocol

import msgspec
import numpy as np

from tracker import filtering as kf
from tracker.models.params import BirthComponent, ModelParams
from tracker.types import STATE_DIM, Estimate, Frame, TrackEstimate, frame_dt

try:  # the Gibbs sweeps also run interpreted (BNPTRACK_NO_JIT=1)
    from numba import njit as _njit
except ImportError:  # pragma: no cover
    _njit = None

__all__ = ["GlmbConfig", "GlmbState", "GlmbTracker", "GLMB_PRESETS", "make_glmb", "GlmbModel",
           "adaptive_birth_existence", "measurement_state_prior", "marginals",
           "map_cardinality_rows", "continuity_rows", "marginal_label_rows", "estimate_from_rows"]

OpenProb = Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)]
PosInt = Annotated[int, msgspec.Meta(ge=1)]
PosFloat = Annotated[float, msgspec.Meta(gt=0.0)]
BirthModel = Literal["auto", "static", "adaptive", "both"]
Estimator = Literal["map-cardinality", "continuity", "marginal-labels"]

#: option columns of the eta matrix: 0 = dies / not born, 1 = missed, 2 + j = detected by z_j
_DIE, _MISS, _DET = 0, 1, 2


class GlmbConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of the GLMB baseline (model physics live in ``ModelParams``)."""

    filter: Literal["ukf", "ekf"] = "ukf"
    """Gaussian approximation of the nonlinear models (UKF as in Vo's demo)."""
    gate_prob: OpenProb = 0.99999
    """Chi-square gate probability on the predicted measurement; pairs outside are impossible
    (Vo's demo uses 0.9999999)."""
    max_hypotheses: PosInt = 1000
    """Requested Gibbs samples per frame over all parent hypotheses (the demo's ``H_upd``);
    parent ``h`` gets ``round(max_hypotheses * sqrt(w_h) / sum sqrt(w))`` and at least one."""
    max_hypotheses_after: PosInt = 500
    """Cap on the number of hypotheses kept after pruning (the demo's ``H_max``)."""
    prune_threshold: Annotated[float, msgspec.Meta(ge=0.0, lt=1.0)] = 1e-15
    """Hypotheses with normalised weight at or below this are dropped (``hyp_threshold``)."""
    chain_length: PosInt = 10
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
    adaptive_birth_rate: PosFloat = 0.2
    r"""Adaptive birth: :math:`\lambda_B`, the expected number of new objects per scan, spread
    over the previous scan's measurements by how unlikely each was to be assigned."""
    birth_r_max: OpenProb = 0.5
    r"""Adaptive birth: cap :math:`r_{B,\max}` on one measurement's birth existence."""
    max_births: PosInt = 50
    """Adaptive birth: at most this many birth Bernoullis per scan (the measurements with the
    largest unassigned probability; a cap on the cost, never zero births)."""
    birth_min_share: Annotated[float, msgspec.Meta(ge=0.0, lt=1.0)] = 1e-3
    """Adaptive birth: a measurement whose birth existence is below this fraction of the
    largest one of its scan gets no Bernoulli (relative, so it cannot remove every birth)."""
    birth_velocity_std: PosFloat = 20.0
    """Adaptive birth: std of the zero-mean velocity prior per axis, m/s."""
    birth_turn_std_deg: PosFloat = 6.0
    """Adaptive birth: std of the zero-mean turn-rate prior, deg/s (Vo's birth components)."""
    estimator: Estimator = "continuity"
    """``"map-cardinality"``: the best hypothesis of the MAP cardinality (Vo's demo);
    ``"continuity"``: the MAP-cardinality hypothesis that continues the most of the last
    estimate's tracks among those within ``continuity_ratio`` of the best
    (:func:`continuity_rows`); ``"marginal-labels"``: the MAP-cardinality number of labels
    with the largest marginal existence, each with its best association history
    (:func:`marginal_label_rows`)."""
    continuity_ratio: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 0.5
    """``continuity`` / ``marginal-labels``: an estimate that continues the previous one is
    kept while its weight is at least this fraction of the best alternative's."""


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


def _empty_hyps() -> np.ndarray:
    return np.zeros((1, 0), dtype=np.int64)


@dataclass(frozen=True)
class GlmbState:
    """The GLMB density after ``frame`` (snapshot with :mod:`tracker.state`).

    Track table: ``labels`` (T,), ``mean`` (T, 5), ``cov`` (T, 5, 5).  Hypotheses:
    ``hyp_tracks`` (H, maxN) int64 sorted table rows padded with ``-1``; ``log_w`` (H,)
    normalised log weights.  The initial state is the single empty hypothesis of weight 1.
    ``birth_*``: the last frame's measurements and their assignment probabilities, from
    which the next frame's adaptive births are built.
    """

    frame: int = -1
    stamp_ns: int = 0
    labels: tuple[str, ...] = ()
    mean: np.ndarray = field(default_factory=lambda: np.zeros((0, STATE_DIM)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, STATE_DIM, STATE_DIM)))
    hyp_tracks: np.ndarray = field(default_factory=_empty_hyps)
    log_w: np.ndarray = field(default_factory=lambda: np.zeros(1))
    birth_frame: int = -1
    """Frame of ``birth_z`` (the last processed frame; ``-1``: none)."""
    birth_kind: str = "bearing_range"
    birth_sensor: str = ""
    birth_pose: tuple[float, ...] = ()
    """The last frame's sensor, pose (``()``: none) and ``R`` (``(0, 0)``: none)."""
    birth_R: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    birth_z: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """The last frame's measurements ``(M, d)``: the adaptive births of the next frame."""
    birth_r_u: np.ndarray = field(default_factory=lambda: np.zeros(0))
    r"""``(M,)`` :math:`r_U(z)`: posterior probability that ``birth_z[m]`` was assigned to a
    track (sum of the weights of the hypotheses that use it)."""
    est_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """Table rows reported by the last estimate (the ``marginal-labels`` estimator follows
    their association histories)."""

    @property
    def n_tracks(self) -> int:
        return len(self.labels)

    @property
    def n_hypotheses(self) -> int:
        return int(self.log_w.shape[0])

    def cardinality(self) -> np.ndarray:
        """Cardinality distribution ``(maxN + 1,)``: :math:`\\rho(n) = \\sum_{|I|=n} w^{(I)}`."""
        n = np.sum(self.hyp_tracks >= 0, axis=1)
        return np.bincount(n, weights=np.exp(self.log_w), minlength=self.hyp_tracks.shape[1] + 1)


# --------------------------------------------------------------------------------------
# Per-frame intermediate data
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Candidates:
    """Predicted survivors (rows ``0..T-1``, the old table rows) then births (``T..T+B-1``)."""

    labels: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    log_e: np.ndarray  # log P_S (survivors, over the gap) or log r_B (births)
    log_not_e: np.ndarray  # log(1 - P_S) or log(1 - r_B)
    p_detect: np.ndarray
    n_survivors: int
    n_adaptive: int = 0

    @property
    def n_births(self) -> int:
        return len(self.labels) - self.n_survivors


@dataclass(frozen=True)
class _Children:
    """Distinct child hypotheses as sorted pair keys ``row * (M + 1) + j`` (j = 0 missed,
    1..M measurement j-1), padded with ``-1``, and their log weights (unnormalised)."""

    keys: np.ndarray
    log_w: np.ndarray
    n_samples: int


@dataclass(frozen=True)
class _Update:
    """The new GLMB plus per-row data of this frame: the measurement index (or -1) and the
    previous table row it continues (or -1 for a birth)."""

    state: GlmbState
    row_meas: np.ndarray
    parent_row: np.ndarray


# --------------------------------------------------------------------------------------
# Pure array helpers
# --------------------------------------------------------------------------------------


def _log(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.log(x)


def _logsumexp(a: np.ndarray) -> float:
    top = float(np.max(a))
    return top + math.log(float(np.sum(np.exp(a - top)))) if math.isfinite(top) else top


def group_logsumexp(values: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """``out[g] = log sum_{i: groups[i] = g} exp(values[i])`` (vectorised)."""
    top = np.full(n_groups, -np.inf)
    np.maximum.at(top, groups, values)
    safe = np.where(np.isfinite(top), top, 0.0)
    sums = np.bincount(groups, weights=np.exp(values - safe[groups]), minlength=n_groups)
    return safe + _log(sums)


def eta_matrix(log_e: np.ndarray, log_not_e: np.ndarray, p_detect: np.ndarray,
               log_lik: np.ndarray, log_kappa: float) -> np.ndarray:
    r"""Log costs :math:`\log\eta_i(j)` of every candidate ``(N, M + 2)``.

    Column 0 (:math:`j = -1`, dies / not born): :math:`1 - e_i`; column 1 (:math:`j = 0`,
    missed): :math:`e_i (1 - P_D)`; column ``2 + m`` (detected by :math:`z_m`):
    :math:`e_i P_D\, g(z_m \mid \cdot) / \kappa(z_m)`, where :math:`e_i = \bar P_S` for a
    survivor and :math:`r_B` for a birth, :math:`g` the (gated) Gaussian predictive likelihood.
    """
    log_pd = _log(p_detect)
    out = np.empty((log_e.shape[0], log_lik.shape[1] + 2))
    out[:, _DIE] = log_not_e
    out[:, _MISS] = log_e + _log(1.0 - p_detect)
    out[:, _DET:] = (log_e + log_pd)[:, None] + log_lik - log_kappa
    return out


def candidate_sets(hyp_tracks: np.ndarray, n_survivors: int, n_births: int) -> np.ndarray:
    """Candidate rows of every parent ``(H, maxN + B)``: its survivors then all births, -1 pad."""
    H, width = hyp_tracks.shape
    births = np.broadcast_to(n_survivors + np.arange(n_births), (H, n_births))
    cand = np.concatenate([hyp_tracks, births], axis=1)
    # move the -1 padding of the survivors to the end, keeping order
    order = np.argsort(cand < 0, axis=1, kind="stable")
    return np.take_along_axis(cand, order, axis=1)


def allocate_samples(log_w: np.ndarray, total: int) -> np.ndarray:
    r"""Requested samples per parent: :math:`\max(1, \mathrm{round}(N \sqrt{w_h} /
    \sum_h \sqrt{w_h}))` (the authors' square-root allocation)."""
    s = np.exp(0.5 * (log_w - np.max(log_w)))
    return np.maximum(1, np.round(total * s / s.sum())).astype(np.int64)


def start_optimal(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Optimal assignment of each parent (max sum of log eta, distinct measurements).

    Returns the options ``(H, width)`` (-1 on padding) and a feasibility mask ``(H,)``; a
    parent without any feasible assignment has zero-weight children only.  Where every
    candidate's individually best option uses a different measurement, that is the optimum;
    the other parents are solved by linear assignment (:func:`_assign`).
    """
    valid = cand >= 0
    best = np.argmax(E, axis=1)
    out = np.where(valid, best[np.where(valid, cand, 0)], -1)
    det = np.where(out >= _DET, out, -1 - np.arange(out.shape[1]))  # distinct fillers
    srt = np.sort(det, axis=1)
    clash = np.any(srt[:, 1:] == srt[:, :-1], axis=1)
    ok = np.all(np.isfinite(E[np.where(valid, cand, 0), np.maximum(out, 0)]) | ~valid, axis=1)
    hard = np.flatnonzero(clash | ~ok)
    if hard.size:
        out[hard], ok[hard] = _assign(E, cand[hard])
    return out, ok


def _assign(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_assign_dense` on the candidates that have a measurement in their gate only:
    the others (e.g. most adaptive births) cannot compete for a measurement, so their best
    option is their best of dies/missed whatever the rest does (same result, smaller
    problems)."""
    valid = cand >= 0
    safe = np.where(valid, cand, 0)
    gated = valid & np.isfinite(E[:, _DET:]).any(axis=1)[safe]
    Ec = E[safe]
    no_det = np.where(Ec[..., _MISS] >= Ec[..., _DIE], _MISS, _DIE)
    best_no = np.take_along_axis(Ec, no_det[..., None], axis=-1)[..., 0]
    out = np.where(valid, no_det, -1)
    ok = np.all(np.isfinite(best_no) | ~valid | gated, axis=1)
    order = np.argsort(~gated, axis=1, kind="stable")
    width = int(gated.sum(axis=1).max(initial=0))
    if width == 0:
        return out, ok
    order = order[:, :width]
    sub = np.where(np.take_along_axis(gated, order, axis=1), np.take_along_axis(cand, order, axis=1), -1)
    sub_out, sub_ok = _assign_dense(E, sub)
    hh, ii = np.nonzero(sub >= 0)
    out[hh, order[hh, ii]] = sub_out[hh, ii]
    return out, ok & sub_ok


def _assign_dense(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best options of each parent by linear assignment on the cost matrix
    ``[-log eta(detections) | diag(-max(log eta(dies), log eta(missed)))]`` (padding rows
    take their own dummy column at no cost), all parents in one call of the compiled
    :func:`_lsap_kernel` (scipy's algorithm).  Returns options ``(H, width)`` and
    feasibility ``(H,)``."""
    H, width = cand.shape
    M = E.shape[1] - _DET
    valid = cand >= 0
    Ec = E[np.where(valid, cand, 0)]  # (H, width, M + 2)
    no_det = np.where(Ec[..., _MISS] >= Ec[..., _DIE], _MISS, _DIE)
    best_no = np.take_along_axis(Ec, no_det[..., None], axis=-1)[..., 0]
    cost = np.full((H, width, M + width), np.inf)
    cost[:, :, :M] = np.where(valid[..., None], -Ec[..., _DET:], np.inf)
    diag = np.arange(width)
    cost[:, diag, M + diag] = np.where(valid, -best_no, 0.0)
    out = np.where(valid, no_det, -1)
    # width <= M + width columns: every row is assigned and the row indices are 0..width-1
    col = np.full((H, width), M, dtype=np.int64)
    solved = np.zeros(H, dtype=bool)
    _lsap_batch(cost, col, solved)
    hh, ii = np.nonzero(solved[:, None] & (col < M))
    out[hh, ii] = _DET + col[hh, ii]
    ok = solved & np.all(np.isfinite(np.take_along_axis(cost, col[..., None], axis=2)[..., 0]), axis=1)
    return out, ok


def _lsap_kernel(cost: np.ndarray, col: np.ndarray, solved: np.ndarray) -> None:  # pragma: no cover
    """Minimum-cost assignment of every row of each ``cost[h]`` (rows <= columns, +inf =
    forbidden): the shortest augmenting path algorithm (Crouse 2016) exactly as
    ``scipy.optimize.linear_sum_assignment`` implements it, batched over ``h`` and compiled
    with numba.  Writes ``col[h]`` (the column of each row) and ``solved[h]`` (False when
    no finite assignment exists; ``col[h]`` is then left unchanged)."""
    H, nr, nc = cost.shape
    u = np.empty(nr)
    v = np.empty(nc)
    spc = np.empty(nc)
    path = np.empty(nc, dtype=np.int64)
    col4row = np.empty(nr, dtype=np.int64)
    row4col = np.empty(nc, dtype=np.int64)
    SR = np.empty(nr, dtype=np.bool_)
    SC = np.empty(nc, dtype=np.bool_)
    remaining = np.empty(nc, dtype=np.int64)
    for h in range(H):
        u[:] = 0.0
        v[:] = 0.0
        path[:] = -1
        col4row[:] = -1
        row4col[:] = -1
        feasible = True
        for cur in range(nr):
            # augmenting path from row cur
            min_val = 0.0
            i = cur
            n_rem = nc
            for it in range(nc):
                remaining[it] = nc - it - 1
            SR[:] = False
            SC[:] = False
            spc[:] = np.inf
            sink = -1
            while sink == -1:
                index = -1
                lowest = np.inf
                SR[i] = True
                for it in range(n_rem):
                    j = remaining[it]
                    r = min_val + cost[h, i, j] - u[i] - v[j]
                    if r < spc[j]:
                        path[j] = i
                        spc[j] = r
                    if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                        lowest = spc[j]
                        index = it
                min_val = lowest
                if min_val == np.inf:
                    break
                j = remaining[index]
                if row4col[j] == -1:
                    sink = j
                else:
                    i = row4col[j]
                SC[j] = True
                n_rem -= 1
                remaining[index] = remaining[n_rem]
            if sink < 0:
                feasible = False
                break
            u[cur] += min_val
            for i in range(nr):
                if SR[i] and i != cur:
                    u[i] += min_val - spc[col4row[i]]
            for j in range(nc):
                if SC[j]:
                    v[j] -= min_val - spc[j]
            j = sink
            while True:
                i = path[j]
                row4col[j] = i
                tmp = col4row[i]
                col4row[i] = j
                j = tmp
                if i == cur:
                    break
        if feasible:
            for i in range(nr):
                col[h, i] = col4row[i]
            solved[h] = True


if _njit is not None and os.environ.get("BNPTRACK_NO_JIT") != "1":
    _lsap_batch = _njit(cache=True, nogil=True)(_lsap_kernel)
else:  # pragma: no cover - numba missing or disabled: same code, interpreted
    _lsap_batch = _lsap_kernel


def start_missed(E: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each candidate at its best of dies/missed (Vo's demo starts all missed)."""
    valid = cand >= 0
    Ec = E[np.where(valid, cand, 0)]
    opt = np.where(Ec[..., _MISS] >= Ec[..., _DIE], _MISS, _DIE)
    best = np.take_along_axis(Ec, opt[..., None], axis=-1)[..., 0]
    ok = np.all(np.isfinite(best) | ~valid, axis=1)
    return np.where(valid, opt, -1), ok


def _draw(rng: np.random.Generator, p: np.ndarray) -> np.ndarray:
    """One categorical draw per row of the unnormalised probabilities ``p`` (rows > 0)."""
    cdf = np.cumsum(p, axis=1)
    u = rng.random(p.shape[0]) * cdf[:, -1]
    idx = np.count_nonzero(cdf <= u[:, None], axis=1)
    over = idx >= p.shape[1]  # u rounded up to the total: take the last positive entry
    if np.any(over):
        idx[over] = p.shape[1] - 1 - np.argmax(p[over, ::-1] > 0, axis=1)
    return idx


def _gibbs_kernel(P: np.ndarray, cand: np.ndarray, start: np.ndarray, length: np.ndarray,
                  u: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Lockstep sweeps of :func:`gibbs_chains` on plain arrays (compiled with numba).

    ``u`` holds the uniforms in the order the vectorised sweep consumed them (sweep, slot,
    chain); ``out`` receives all starts, then the active prefix after each sweep.  Each draw
    is ``count(cdf <= u * cdf[-1])`` over the unblocked row of ``P`` (the last positive entry
    when ``u`` rounds up to the total), exactly as :func:`_draw`.
    """
    C, width = cand.shape
    K = P.shape[1]
    gamma = start.copy()
    taken = np.zeros((C, K), dtype=np.bool_)
    for c in range(C):
        for i in range(width):
            if gamma[c, i] >= 2:
                taken[c, gamma[c, i]] = True
            out[c, i] = gamma[c, i]
    cdf = np.empty(K)
    row = C
    pos = 0
    n_sweeps = 0
    for c in range(C):
        if length[c] > n_sweeps:
            n_sweeps = length[c]
    for s in range(n_sweeps):
        k = 0
        for c in range(C):
            if length[c] > s:
                k += 1
        for i in range(width):
            for c in range(k):
                r = cand[c, i]
                if r < 0:
                    continue
                taken[c, gamma[c, i]] = False
                acc = 0.0
                for j in range(K):
                    acc += P[r, j] * (0.0 if taken[c, j] else 1.0)
                    cdf[j] = acc
                x = u[pos] * cdf[K - 1]
                pos += 1
                new = 0
                for j in range(K):
                    if cdf[j] <= x:
                        new += 1
                if new >= K:  # u rounded up to the total: take the last positive entry
                    for j in range(K - 1, -1, -1):
                        if P[r, j] * (0.0 if taken[c, j] else 1.0) > 0:
                            new = j
                            break
                if new >= 2:
                    taken[c, new] = True
                gamma[c, i] = new
        for c in range(k):
            for i in range(width):
                out[row, i] = gamma[c, i]
            row += 1


if _njit is not None and os.environ.get("BNPTRACK_NO_JIT") != "1":
    _gibbs_sweeps = _njit(cache=True, nogil=True)(_gibbs_kernel)
else:  # pragma: no cover - numba missing or disabled: same code, interpreted
    _gibbs_sweeps = _gibbs_kernel


def gibbs_chains(rng: np.random.Generator, E: np.ndarray, cand: np.ndarray,
                 start: np.ndarray, length: np.ndarray) -> np.ndarray:
    r"""Run Gibbs chains in lockstep; returns every visited state ``(S, width)``.

    Chain ``c`` has candidates ``cand[c]`` (-1 padded), starts at ``start[c]`` and makes
    ``length[c]`` sweeps; ``length`` must be non-increasing (active chains are a prefix).
    The output holds all starts, then the active chains' states after each sweep.  One sweep
    updates each candidate ``i`` in turn from (Algorithm 1)

    .. math:: p(\gamma_i = j \mid \gamma_{\bar i}) \propto \eta_i(j)\,
              \big(1 - 1[j > 0,\ j \in \{\gamma_{1:i-1}, \gamma_{i+1:n}\}]\big)

    (distinct measurements; "dies" and "missed" are never blocked).  The sweeps run in
    :func:`_gibbs_kernel` (numba) on uniforms drawn up front from ``rng`` in the order of
    :func:`gibbs_chains_numpy`, which gives identical samples.
    """
    C, width = cand.shape
    length = np.asarray(length, dtype=np.int64)
    if C == 0:
        return np.zeros((0, width), dtype=np.int64)
    P = np.exp(E - np.max(E, axis=1, keepdims=True)) if E.size else np.ones_like(E)
    n_draws = int(np.dot(length, np.count_nonzero(cand >= 0, axis=1)))
    u = rng.random(n_draws)
    out = np.empty((C + int(length.sum()), width), dtype=np.int64)
    _gibbs_sweeps(np.ascontiguousarray(P, dtype=np.float64), np.ascontiguousarray(cand, dtype=np.int64),
                  np.ascontiguousarray(start, dtype=np.int64), length, u, out)
    return out


def gibbs_chains_numpy(rng: np.random.Generator, E: np.ndarray, cand: np.ndarray,
                       start: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Vectorised-numpy reference of :func:`gibbs_chains` (same samples, slower)."""
    C, width = cand.shape
    # conditionals only involve one row of eta: scale each row by its maximum once
    P = np.exp(E - np.max(E, axis=1, keepdims=True)) if E.size else np.ones_like(E)
    gamma = start.copy()
    taken = np.zeros((C, E.shape[1]), dtype=bool)
    rc, cc = np.nonzero(gamma >= _DET)
    taken[rc, gamma[rc, cc]] = True
    slot_chains = [np.flatnonzero(cand[:, i] >= 0) for i in range(width)]
    samples = [gamma.copy()]
    for s in range(int(length.max(initial=0))):
        k = int(np.count_nonzero(length > s))
        for i in range(width):
            ch = slot_chains[i]
            ch = ch[: np.searchsorted(ch, k)]
            if ch.size == 0:
                continue
            taken[ch, gamma[ch, i]] = False
            new = _draw(rng, P[cand[ch, i]] * ~taken[ch])
            taken[ch, new] = new >= _DET
            gamma[ch, i] = new
        samples.append(gamma[:k].copy())
    return np.concatenate(samples, axis=0)


def split_chains(n_req: np.ndarray, chain_length: int) -> tuple[np.ndarray, np.ndarray]:
    """Gibbs chains for per-parent requests: parent ``p``'s start is one sample and its other
    ``n_req[p] - 1`` sweeps are split into near-equal chains of at most ``chain_length``
    sweeps.  Returns ``(chain_parent, length)`` sorted by non-increasing length."""
    n_chains = np.maximum(1, -(-(n_req - 1) // chain_length))
    parent = np.repeat(np.arange(n_req.size), n_chains)
    sweeps = np.repeat(n_req - 1, n_chains)
    per = np.repeat(n_chains, n_chains)
    pos = np.arange(parent.size) - np.repeat(np.cumsum(n_chains) - n_chains, n_chains)
    length = sweeps // per + (pos < sweeps % per)
    order = np.argsort(-length, kind="stable")
    return parent[order], length[order]


def sample_chains(length: np.ndarray) -> np.ndarray:
    """Chain index of each row of :func:`gibbs_chains`' output (all starts, then the active
    prefix after each sweep)."""
    sweeps = [np.arange(np.count_nonzero(length > s)) for s in range(int(length.max(initial=0)))]
    return np.concatenate([np.arange(length.size)] + sweeps)


def assignment_log_eta(E: np.ndarray, cand: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    r""":math:`\sum_i \log \eta_i(\gamma_i)` of each assignment (padding ignored)."""
    valid = cand >= 0
    return np.where(valid, E[np.where(valid, cand, 0), np.where(valid, gamma, 0)], 0.0).sum(axis=1)


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct rows of a 2-D int array (lexicographic order) and the inverse index."""
    if a.shape[0] == 0:
        return a, np.zeros(0, dtype=np.int64)
    if a.shape[1] == 0:
        return a[:1], np.zeros(a.shape[0], dtype=np.int64)
    order = np.lexsort(a.T[::-1])
    s = a[order]
    new = np.concatenate([[True], np.any(s[1:] != s[:-1], axis=1)])
    inv = np.empty(a.shape[0], dtype=np.int64)
    inv[order] = np.cumsum(new) - 1
    return s[new], inv


def child_keys(cand: np.ndarray, gamma: np.ndarray, n_meas: int) -> np.ndarray:
    """Sorted pair keys ``row * (M + 1) + j`` of each sample's existing labels, -1 padded.

    ``j = gamma - 1``: 0 missed, ``1..M`` measurement ``j - 1``; dead / not-born candidates
    and padding are dropped.
    """
    alive = (cand >= 0) & (gamma >= _MISS)
    keys = np.where(alive, cand * (n_meas + 1) + (gamma - 1), np.iinfo(np.int64).max)
    keys = np.sort(keys, axis=1)
    width = int(alive.sum(axis=1).max(initial=0))
    keys = keys[:, :width]
    return np.where(keys == np.iinfo(np.int64).max, -1, keys)


def merge_children(cand: np.ndarray, gamma: np.ndarray, log_w: np.ndarray, n_meas: int) -> _Children:
    """Children as pair-key sets; zero-weight ones dropped, identical sets merged (their
    weights summed: different parents can produce the same child, e.g. when the tracks
    that tell them apart die)."""
    finite = np.isfinite(log_w)
    keys, inv = unique_rows(child_keys(cand[finite], gamma[finite], n_meas))
    return _Children(keys, group_logsumexp(log_w[finite], inv, keys.shape[0]), int(log_w.size))


def prune_and_cap(log_w: np.ndarray, threshold: float, cap: int) -> np.ndarray:
    """Indices of hypotheses kept: normalised weight above ``threshold``, best ``cap``."""
    w = np.exp(log_w - _logsumexp(log_w))
    keep = np.flatnonzero(w > threshold)
    if keep.size == 0:
        keep = np.array([int(np.argmax(log_w))])
    if keep.size > cap:
        keep = keep[np.argsort(-log_w[keep], kind="stable")[:cap]]
    return np.sort(keep)


def adaptive_birth_existence(r_u: np.ndarray, rate: float, r_max: float, max_births: int,
                             min_share: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Existence of the adaptive births (Reuter, Vo, Vo & Dietmayer 2014, "The labeled
    multi-Bernoulli filter", adaptive birth procedure):

    .. math:: r_B(z) = \min\Big(r_{B,\max},\ \lambda_B \frac{1 - r_U(z)}{\sum_{z'} (1 - r_U(z'))}\Big)

    for the measurements ``z`` of the previous scan, :math:`r_U(z)` the posterior probability
    that ``z`` was assigned to a track.  Bounded: only the ``max_births`` measurements with
    the largest :math:`r_B` (ties: lower index), and none whose :math:`r_B` is below
    ``min_share`` times the largest (so the set is empty only when every measurement was
    surely assigned).  Returns the kept measurement indices (increasing) and their
    :math:`r_B`.
    """
    unassigned = np.clip(1.0 - np.asarray(r_u, dtype=float), 0.0, 1.0)
    total = float(unassigned.sum())
    if total <= 0.0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    r = np.minimum(r_max, rate * unassigned / total)
    order = np.argsort(-r, kind="stable")[:max_births]
    keep = np.sort(order[(r[order] >= min_share * r[order[0]]) & (r[order] > 0.0)])
    return keep.astype(np.int64), r[keep]


def measurement_state_prior(pos: np.ndarray, pos_cov: np.ndarray, velocity_std: float,
                            turn_std: float) -> tuple[np.ndarray, np.ndarray]:
    """State ``(M, 5)`` and covariance ``(M, 5, 5)`` of objects seen at ``pos`` ``(M, 2)`` with
    covariance ``pos_cov`` ``(M, 2, 2)`` (the sensor's inverse model): zero-mean velocity with
    std ``velocity_std`` per axis and zero-mean turn rate with std ``turn_std``, independent."""
    n = pos.shape[0]
    mean = np.zeros((n, STATE_DIM))
    mean[:, 0], mean[:, 2] = pos[:, 0], pos[:, 1]
    cov = np.zeros((n, STATE_DIM, STATE_DIM))
    ix = np.ix_(np.arange(n), [0, 2], [0, 2])
    cov[ix] = pos_cov
    cov[:, 1, 1] = cov[:, 3, 3] = velocity_std**2
    cov[:, 4, 4] = turn_std**2
    return mean, cov


@dataclass(frozen=True)
class _Births:
    """Birth Bernoullis of one frame: labels, existence ``r`` (B,), Gaussians."""

    labels: tuple[str, ...]
    r: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    n_adaptive: int = 0


@dataclass(frozen=True)
class _Marginals:
    """Per-frame marginals of the updated GLMB (shared by the estimators and the births)."""

    w: np.ndarray  # (H,) hypothesis weights
    h_idx: np.ndarray  # (P,) hypothesis of each (hypothesis, slot) entry
    rows: np.ndarray  # (P,) its table row
    label_id: np.ndarray  # (T,) index of each row's label in the sorted distinct labels
    n_labels: int
    existence: np.ndarray  # (L,) r(l) = sum_{I contains l} w(I)
    p_used: np.ndarray  # (M,) r_U(z_m) = sum_{h uses z_m} w_h
    pair_p: np.ndarray  # (L * M,) weight of the hypotheses assigning z_m to label l


# --------------------------------------------------------------------------------------
# The tracker
# --------------------------------------------------------------------------------------


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
        sensor = self.params.frame_sensor(frame)
        meas = self.params.measurement(frame.kind, sensor)
        cands = self._candidates(state, dt, frame, sensor)
        innov = self._innovation(meas, cands)
        E = self._eta(meas, innov, cands, frame)
        children = self._children(state, cands, E, rng)
        upd = self._update(frame, meas, innov, cands, children)
        marg = marginals(upd.state, upd.row_meas, frame.n_measurements)
        rows = self._estimate_rows(upd, marg, state.est_rows)
        est = estimate_from_rows(upd.state, upd.row_meas, marg, frame, rows)
        new = dataclasses.replace(upd.state, birth_frame=frame.frame, birth_kind=frame.kind,
                                  birth_z=frame.z.copy(), birth_sensor=frame.sensor, birth_pose=frame.pose or (),
                                  birth_R=np.zeros((0, 0)) if frame.R is None else frame.R, birth_r_u=np.clip(marg.p_used, 0.0, 1.0),
                                  est_rows=rows)
        card = new.cardinality()
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
        return new, Estimate(est.frame, est.stamp_ns, est.tracks, est.assignments,
                             est.assignment_prob, diagnostics)

    # -- pieces ---------------------------------------------------------------------------
    def _predict_fn(self):
        return kf.ukf_predict if self.config.filter == "ukf" else kf.ekf_predict

    def _candidates(self, state: GlmbState, dt: float, frame: Frame, sensor: Any = None) -> _Candidates:
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
        pd = self.params.detection(frame.kind, sensor).prob(mean) if len(mean) else np.zeros(0)
        return _Candidates(labels, mean, cov, log_e, log_not_e, np.clip(pd, 0.0, 1.0), len(m),
                           b.n_adaptive)

    def _births(self, state: GlmbState, frame: Frame, dt: float) -> _Births:
        """This frame's birth Bernoullis: the static regions (labels ``"k.i"``, ``i`` the
        component) and/or the adaptive births (labels ``"k.zj"``, ``j`` the index of the
        measurement of the previous processed frame), per :attr:`birth_model`."""
        r, bm, bP = self.birth
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

    def _eta(self, meas, innov: kf.Innovation, cands: _Candidates, frame: Frame) -> np.ndarray:
        M = frame.n_measurements
        if M and len(cands.mean):
            log_lik = kf.log_likelihood_matrix(meas, innov, frame.z, self.config.gate_prob)
        else:
            log_lik = np.zeros((len(cands.mean), M))
        log_kappa = float(self.params.clutter(frame.kind, self.params.frame_sensor(frame)).log_intensity)
        if not math.isfinite(log_kappa):
            raise ValueError("the GLMB needs a positive, finite clutter intensity (clutter_rate > 0)")
        return eta_matrix(cands.log_e, cands.log_not_e, cands.p_detect, log_lik, log_kappa)

    def _children(self, state: GlmbState, cands: _Candidates, E: np.ndarray,
                  rng: np.random.Generator) -> _Children:
        """Gibbs-sampled distinct children of every parent, duplicates merged."""
        cfg = self.config
        cand = candidate_sets(state.hyp_tracks, cands.n_survivors, len(cands.labels) - cands.n_survivors)
        start, ok = (start_optimal if cfg.start == "optimal" else start_missed)(E, cand)
        parents = np.flatnonzero(ok)
        if parents.size == 0:
            raise RuntimeError("GLMB: no parent hypothesis has a feasible assignment")
        cand, start, log_w = cand[parents], start[parents], state.log_w[parents]
        chain_parent, length = split_chains(allocate_samples(log_w, cfg.max_hypotheses), cfg.chain_length)
        samples = gibbs_chains(rng, E, cand[chain_parent], start[chain_parent], length)
        owner = chain_parent[sample_chains(length)]
        uniq, _ = unique_rows(np.column_stack([owner, samples]))
        p_idx, gamma = uniq[:, 0], uniq[:, 1:]
        log_w = log_w[p_idx] + assignment_log_eta(E, cand[p_idx], gamma)
        return merge_children(cand[p_idx], gamma, log_w, E.shape[1] - _DET)

    def _estimate_rows(self, upd: _Update, marg: _Marginals, prev_rows: np.ndarray) -> np.ndarray:
        """Table rows of this frame's estimate, by ``config.estimator``."""
        continues = np.isin(upd.parent_row, prev_rows)
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
        log_w = log_w - _logsumexp(log_w)
        used = np.unique(keys[keys >= 0])
        M = frame.n_measurements
        row, j = used // (M + 1), used % (M + 1)
        mean = cands.mean[row].copy()
        cov = cands.cov[row].copy()
        det = j > 0
        if np.any(det):
            mean[det] = kf.update_pairs(meas, innov, cands.mean, frame.z, row[det], j[det] - 1)
            cov[det] = innov.P_upd[row[det]]
        # strip trailing all-padding columns; map keys to new rows (sorted keys -> sorted rows)
        width = int(np.sum(keys >= 0, axis=1).max(initial=0))
        keys = keys[:, :width]
        hyp = np.where(keys >= 0, np.searchsorted(used, keys), -1).astype(np.int64)
        labels = tuple(cands.labels[i] for i in row.tolist())
        new = GlmbState(frame.frame, frame.stamp_ns, labels, np.ascontiguousarray(mean),
                        np.ascontiguousarray(cov), np.ascontiguousarray(hyp), log_w)
        parent = np.where(row < cands.n_survivors, row, -1).astype(np.int64)
        return _Update(new, (j - 1).astype(np.int64), parent)


def marginals(st: GlmbState, row_meas: np.ndarray, n_meas: int) -> _Marginals:
    r"""Label existences :math:`r(\ell) = \sum_{I \ni \ell} w(I)`, measurement use
    :math:`r_U(z) = \sum_{h \text{ uses } z} w_h` and label-measurement pair weights of an
    updated GLMB (``row_meas``: the measurement of each table row this frame, or -1)."""
    w = np.exp(st.log_w)
    hyp = st.hyp_tracks
    if st.n_tracks:
        uniq, label_id = np.unique(np.array(st.labels, dtype=object), return_inverse=True)
        n_labels = uniq.size
    else:
        n_labels, label_id = 0, np.zeros(0, dtype=np.int64)
    label_id = np.asarray(label_id, dtype=np.int64).reshape(-1)
    h_idx, slot = np.nonzero(hyp >= 0)
    rows = hyp[h_idx, slot]
    lab_of = label_id[rows]
    existence = np.bincount(lab_of, weights=w[h_idx], minlength=n_labels)
    meas_of = row_meas[rows]
    det = meas_of >= 0
    p_used = np.bincount(meas_of[det], weights=w[h_idx[det]], minlength=n_meas)
    pair_p = np.bincount(lab_of[det] * n_meas + meas_of[det], weights=w[h_idx[det]],
                         minlength=n_labels * n_meas) if n_meas else np.zeros(0)
    return _Marginals(w, h_idx, rows, label_id, n_labels, existence, p_used, pair_p)


def _map_cardinality(st: GlmbState, w: np.ndarray) -> tuple[int, np.ndarray]:
    """MAP cardinality and the cardinality of each hypothesis."""
    n = np.sum(st.hyp_tracks >= 0, axis=1)
    return int(np.argmax(np.bincount(n, weights=w))), n


def map_cardinality_rows(st: GlmbState, mg: _Marginals) -> np.ndarray:
    """Vo's ``extract_estimates``: the MAP cardinality :math:`\\hat n`, then the rows of the
    highest-weight hypothesis with :math:`\\hat n` labels."""
    n_map, n = _map_cardinality(st, mg.w)
    best = int(np.argmax(np.where(n == n_map, st.log_w, -np.inf)))
    return st.hyp_tracks[best][st.hyp_tracks[best] >= 0].astype(np.int64)


def continuity_rows(st: GlmbState, mg: _Marginals, continues: np.ndarray, ratio: float) -> np.ndarray:
    r"""Label-consistent MAP extraction: among the hypotheses with the MAP cardinality
    :math:`\hat n` whose weight is at least ``ratio`` times the best of them, the one whose
    rows continue the most of the rows the previous estimate reported (``continues`` (T,):
    the row's parent was reported), ties broken by weight.  With ``ratio = 1`` this is
    :func:`map_cardinality_rows`; below 1 the estimate keeps following its own association
    histories (and so its labels) unless another labelling is more than ``1 / ratio`` times
    as likely -- a streaming, hysteresis form of Vo's track-based extraction.  The reported
    set is always one hypothesis (no two labels on one object)."""
    n_map, n = _map_cardinality(st, mg.w)
    log_w = np.where(n == n_map, st.log_w, -np.inf)
    cand = np.flatnonzero(log_w >= np.max(log_w) + math.log(ratio))
    hyp = st.hyp_tracks[cand]
    cont = np.sum((hyp >= 0) & continues[np.maximum(hyp, 0)], axis=1)
    h = cand[np.lexsort((-st.log_w[cand], -cont))[0]]
    return st.hyp_tracks[h][st.hyp_tracks[h] >= 0].astype(np.int64)


def marginal_label_rows(st: GlmbState, mg: _Marginals, continues: np.ndarray, ratio: float) -> np.ndarray:
    r"""Label-marginal extraction: the MAP cardinality :math:`\hat n`, then the :math:`\hat n`
    labels with the largest existence :math:`r(\ell)` (ties: label order); each label's state
    is one of its rows (association histories): the row with the largest weight
    :math:`\sum_{h \ni \text{row}} w_h`, except that a row continuing the row the previous
    estimate reported for the label (``continues`` (T,)) is preferred if its weight is at least
    ``ratio`` times that.  Per-label choices: two labels can report the same object when the
    posterior is split between labellings.  Returns the rows, one per label."""
    n_map, _ = _map_cardinality(st, mg.w)
    if n_map == 0:
        return np.zeros(0, dtype=np.int64)
    chosen = np.zeros(mg.n_labels, dtype=bool)
    chosen[np.argsort(-mg.existence, kind="stable")[:n_map]] = True
    row_w = np.bincount(mg.rows, weights=mg.w[mg.h_idx], minlength=st.n_tracks)
    top = np.zeros(mg.n_labels)
    np.maximum.at(top, mg.label_id, row_w)
    keep = continues & (row_w >= ratio * top[mg.label_id])
    score = row_w + 2.0 * keep  # row weights are <= 1: continuing rows first
    order = np.lexsort((-score, mg.label_id))
    first = np.concatenate([[True], mg.label_id[order][1:] != mg.label_id[order][:-1]])
    best = order[first]  # one row per label, in label order
    return np.sort(best[chosen[mg.label_id[best]]]).astype(np.int64)


def estimate_from_rows(st: GlmbState, row_meas: np.ndarray, mg: _Marginals, frame: Frame,
                       rows: np.ndarray) -> Estimate:
    """The estimate made of the table rows ``rows`` (one per label): their Gaussians, the
    labels' marginal existence, and as ``assignments`` the measurements those rows used
    (with the pair's posterior probability; other measurements: ``None`` with the clutter
    probability :math:`1 - r_U(z)`)."""
    tracks = tuple(
        TrackEstimate(st.labels[r], st.mean[r].copy(), st.cov[r].copy(),
                      float(min(1.0, mg.existence[mg.label_id[r]])))
        for r in rows.tolist()
    )
    M = frame.n_measurements
    assignments: list[str | None] = [None] * M
    probs = [float(np.clip(1.0 - mg.p_used[m], 0.0, 1.0)) for m in range(M)]
    for r in rows.tolist():
        m = int(row_meas[r])
        if m >= 0:
            assignments[m] = st.labels[r]
            probs[m] = float(np.clip(mg.pair_p[mg.label_id[r] * M + m], 0.0, 1.0))
    return Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assignments), tuple(probs))


def make_glmb(params: ModelParams | GlmbModel, config: GlmbConfig | None = None) -> GlmbTracker:
    """The GLMB baseline with the ``glmb`` preset unless ``config`` is given."""
    return GlmbTracker(params, config if config is not None else GLMB_PRESETS["glmb"], "glmb")
