r"""Calibrated existence: the probability a published track is real, learned from the run itself.

The tracker's own existence :math:`r` follows the model's odds (``P_S``, ``P_D``, the birth and
clutter weights), so it means what it says only where the scene follows the model: an
established track in its first missed scan has :math:`r \approx 0.66` on every scene, and a
track at its first detections is under-confident.  :class:`ExistenceCalibration` publishes in
its place the probability that a track **like this one** is real, learned causally from the
run's own hindsight:

* **Class** of a track-frame, from the published stream of the track's label: detected after
  ``n`` detections so far (``n = 1 ..`` :data:`DETECTED_CLASSES`, the last "or more"), or missed
  ``m`` scans in a row (``m = 1, 2,`` 3 or more) after fewer than :data:`ESTABLISHED`
  detections (young) or at least that many (established): 12 classes.
* **Outcome** of a track-frame, known in hindsight: *real* when its label is detected in two
  consecutive scans after it (one detection after a miss may be clutter in a coasting track's
  gate: it holds the outcome until the next scan), or when, within :data:`REBIRTH_SCANS` scans
  after the label ended, a new label is published inside the ended track's gate (its position
  run forward at constant velocity; chi-square :data:`GATE` on the summed position
  covariances: the object was still there and its track was re-born); *not real* when the
  label ended and no such track followed.  Until then the outcome is pending.
* **Learned model.**  Established tracks: a per-scan death hazard :math:`h` and miss rate
  :math:`\mu`, Beta posterior means with priors centred on ``1 - p_survival`` and
  ``1 - p_detect`` of weight ``hazard_weight`` scans, updated with the run's exposure
  (established track-frames), deaths (established labels that ended) and missed scans of live
  objects; an established track missed ``m`` scans in a row is alive with probability
  :math:`((1-h)\mu)^m / (((1-h)\mu)^m + h \sum_{j<m} ((1-h)\mu)^j)`.  Young tracks (fewer than
  :data:`ESTABLISHED` detections): the tracker's existence with its odds multiplied by the
  run's Mantel-Haenszel odds ratio of young outcomes against their existence
  (:meth:`ExistenceCalibration.young`).  Detected established tracks: the tracker's existence.
* **Calibrated existence** of a track of class :math:`c` whose learned model gives
  :math:`\pi`: :math:`(w\,\pi + y_c) / (w + y_c + n_c)`, the mean of a Beta prior of weight
  :math:`w` (``weight``, in track-frames) centred on :math:`\pi`, updated with the class's
  outcomes so far in the run, :math:`y_c` real and :math:`n_c` not.

The layer reads only the estimates (labels, positions, assignments, existences), so it changes
no published track, state or label: it replaces each track's ``existence`` and nothing else.
Its state (:class:`CalibrationState`) is plain arrays, part of the tracker state that snapshots
store.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, fields, replace

import numpy as np

from bnptrack.tracker.types import Estimate, TrackEstimate

#: Detected classes: after 1, 2, ..., this many or more detections.
DETECTED_CLASSES = 6
#: Missed classes per age: 1, 2, this many or more misses in a row.
MISSED_CLASSES = 3
#: Detections from which a track counts as established.
ESTABLISHED = 3
#: Number of classes.
CLASSES = DETECTED_CLASSES + 2 * MISSED_CLASSES
#: Scans after a label ends within which a new label inside its gate makes its outcome real.
REBIRTH_SCANS = 3
#: Chi-square gate (two dimensions, 99.9 %) of a re-born track about an ended one.
GATE = 13.8
#: Default prior weight (track-frames) of the learned model against a class's outcomes.
PRIOR_WEIGHT = 20.0
#: Default prior weight (scans) of the model's ``P_S`` and ``P_D`` against the run's established tracks.
HAZARD_WEIGHT = 100.0
#: Default pseudo-counts on each side of the young tracks' learned odds ratio.
ODDS_WEIGHT = 5.0

# columns of CalibrationState.rows
_N, _M, _LAST, _STAMP = range(4)
# a pending vector: class counts, then the young odds sums (1 - r, r), then established missed scans
_ODDS, _MISSES = CLASSES, CLASSES + 2
_WIDTH = CLASSES + 3


@dataclass(frozen=True)
class CalibrationState:
    r"""``counts`` (2, CLASSES): outcomes real / not real per class.  ``learned`` (5,): the
    established tracks' exposure (track-frames), deaths and missed scans of live objects, and the
    young track-frames' odds sums :math:`\sum (1 - r)` over those real and :math:`\sum r` over
    those not.  One row per label that is published, or that ended less than
    :data:`REBIRTH_SCANS` scans ago: ``labels``, ``rows`` (R, 4) int64 = detections so far,
    misses in a row, the frame and the stamp (ns) it was last published at; ``pending``
    (R, 2, CLASSES + 3) its track-frames whose outcome is pending and those held by a single
    detection after a miss (each: class counts, young odds sums, established missed scans);
    ``mean`` (R, 5), ``cov`` (R, 5, 5) its last published state."""

    counts: np.ndarray = field(default_factory=lambda: np.zeros((2, CLASSES)))
    learned: np.ndarray = field(default_factory=lambda: np.zeros(5))
    labels: tuple[str, ...] = ()
    rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))
    pending: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, _WIDTH)))
    mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 5, 5)))


@dataclass(frozen=True, kw_only=True)
class CalibrationFields:
    """The existence calibration's state inside a tracker's state: one field ``cal_<name>`` per
    field of :class:`CalibrationState` (a tracker state inherits them, so that
    :mod:`tracker.state` snapshots them with the rest; :func:`calibrate` carries them)."""

    cal_counts: np.ndarray = field(default_factory=lambda: empty("counts"))
    cal_learned: np.ndarray = field(default_factory=lambda: empty("learned"))
    cal_labels: tuple[str, ...] = ()
    cal_rows: np.ndarray = field(default_factory=lambda: empty("rows"))
    cal_pending: np.ndarray = field(default_factory=lambda: empty("pending"))
    cal_mean: np.ndarray = field(default_factory=lambda: empty("mean"))
    cal_cov: np.ndarray = field(default_factory=lambda: empty("cov"))


def empty(name: str) -> np.ndarray:
    """The empty value of :class:`CalibrationState`'s array field ``name`` (the default of
    :class:`CalibrationFields`' ``cal_<name>``): one read-only array per field, shared (the
    calibration never writes into a state's arrays)."""
    return _EMPTY[name]


def _read_only(shape: tuple, dtype=float) -> np.ndarray:
    a = np.zeros(shape, dtype=dtype)
    a.flags.writeable = False
    return a


_EMPTY = {"counts": _read_only((2, CLASSES)), "learned": _read_only((5,)), "rows": _read_only((0, 4), np.int64),
          "pending": _read_only((0, 2, _WIDTH)), "mean": _read_only((0, 5)), "cov": _read_only((0, 5, 5))}


def track_class(n, m):
    """The class of a track-frame after ``n`` detections with ``m`` misses in a row (integers or
    arrays of them)."""
    n, m = np.asarray(n), np.asarray(m)
    missed = DETECTED_CLASSES + np.where(n >= ESTABLISHED, MISSED_CLASSES, 0) + np.minimum(m, MISSED_CLASSES) - 1
    return np.where(m == 0, np.minimum(n, DETECTED_CLASSES) - 1, missed)


def gated(mean: np.ndarray, cov: np.ndarray, dt: float, pos: np.ndarray, pos_cov: np.ndarray) -> np.ndarray:
    """Whether each position ``pos`` (K, 2) (covariances ``pos_cov`` (K, 2, 2)) lies in the
    chi-square :data:`GATE` of the state ``(mean, cov)`` (``[x, vx, y, vy, turn]``) run ``dt``
    seconds forward at constant velocity."""
    F = np.array([[1.0, dt, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, dt, 0.0]])
    S = F @ cov @ F.T + pos_cov
    d = pos - F @ mean
    return np.einsum("ki,ki->k", d, np.linalg.solve(S, d[..., None])[..., 0]) <= GATE


def _may_gate(mean: np.ndarray, cov: np.ndarray, dt: np.ndarray, pos: np.ndarray, pos_cov: np.ndarray) -> np.ndarray:
    r"""For each state ``(mean[g], cov[g])`` run ``dt[g]`` seconds forward, whether any position
    ``pos`` (K, 2) may lie in its :func:`gated` gate: a necessary condition, checked for every pair
    at once, so that :func:`gated` runs only for the states it holds.  With ``d`` the difference
    and ``S`` the summed covariance, :math:`d^\top S^{-1} d \ge \lVert d\rVert^2 / \mathrm{tr}\,S`
    (S positive definite): a pair with :math:`\lVert d\rVert^2 > \chi^2\, \mathrm{tr}\,S` (a
    relative slack of 1e-6 for rounding) is outside.  Values that are not finite fail no pair."""
    if not pos.shape[0]:
        return np.zeros(mean.shape[0], dtype=bool)
    px, py = mean[:, 0] + dt * mean[:, 1], mean[:, 2] + dt * mean[:, 3]
    tr = (cov[:, 0, 0] + dt * (cov[:, 0, 1] + cov[:, 1, 0]) + dt * dt * cov[:, 1, 1]
          + cov[:, 2, 2] + dt * (cov[:, 2, 3] + cov[:, 3, 2]) + dt * dt * cov[:, 3, 3])
    d2 = (px[:, None] - pos[None, :, 0]) ** 2 + (py[:, None] - pos[None, :, 1]) ** 2
    bound = GATE * (tr[:, None] + pos_cov[None, :, 0, 0] + pos_cov[None, :, 1, 1]) * (1.0 + 1e-6)
    with np.errstate(invalid="ignore"):
        return np.any(~(d2 > bound), axis=1)


def settle(counts: np.ndarray, learned: np.ndarray, pend: np.ndarray, real: bool, deaths: int = 0) -> None:
    """Count the outcome of pending track-frames ``pend`` (pending vectors, any leading shape):
    per class; the young ones' odds sums; the established ones' missed scans as a live object's
    (``real``); and ``deaths`` established labels that ended."""
    learned[1] += deaths
    if not pend.size:
        return
    pend = pend.reshape(-1, _WIDTH).sum(axis=0)
    counts[0 if real else 1] += pend[:CLASSES]
    learned[3 if real else 4] += pend[_ODDS if real else _ODDS + 1]
    if real:
        learned[2] += pend[_MISSES]


@dataclass(frozen=True)
class ExistenceCalibration:
    """The calibration above: the model's ``p_survival`` and ``p_detect``, and the prior weights."""

    p_survival: float = 0.99
    p_detect: float = 0.98
    weight: float = PRIOR_WEIGHT
    hazard_weight: float = HAZARD_WEIGHT
    odds_weight: float = ODDS_WEIGHT

    def __post_init__(self) -> None:
        for name in ("weight", "hazard_weight", "odds_weight"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ExistenceCalibration: {name} must be > 0, got {getattr(self, name)!r}")

    def rates(self, learned: np.ndarray) -> tuple[float, float]:
        """The learned per-scan death hazard and miss rate of established tracks."""
        w, (exposure, deaths, misses) = self.hazard_weight, learned[:3].tolist()
        return ((w * (1.0 - self.p_survival) + deaths) / (w + exposure),
                (w * (1.0 - self.p_detect) + misses) / (w + exposure))

    def missed(self, learned: np.ndarray, m):
        """Probability that an established track missed ``m`` (>= 1) scans in a row is alive."""
        h, mu = self.rates(learned)
        a = (1.0 - h) * mu
        am = a ** np.asarray(m, dtype=float)
        den = am + h * (1.0 - am) / (1.0 - a)  # sum_{j<m} a^j = (1 - a^m) / (1 - a)
        # den is 0 only without a death hazard (h = 0) and without misses (mu = 0): certainly alive
        return np.divide(am, den, out=np.ones_like(am), where=den > 0)

    def young(self, learned: np.ndarray, r):
        r"""The existence ``r`` of a young track with its odds multiplied by the run's
        Mantel-Haenszel odds ratio of young outcomes against their existence,
        :math:`\kappa = (w + \sum_\text{real} (1 - r_i)) / (w + \sum_\text{not} r_i)` (``odds_weight``
        pseudo-counts on each side: :math:`\kappa = 1` without evidence)."""
        kappa = (self.odds_weight + learned[3]) / (self.odds_weight + learned[4])
        return kappa * r / (kappa * r + 1.0 - r)

    def prior(self, learned: np.ndarray, n, m, r):
        """The learned model's probability for track-frames (the centre of their class's prior)."""
        n, m, r = np.asarray(n), np.asarray(m), np.asarray(r, dtype=float)
        established = np.where(m > 0, self.missed(learned, np.maximum(m, 1)), r)
        return np.where(n >= ESTABLISHED, established, self.young(learned, r))

    def step(self, state: CalibrationState, est: Estimate) -> tuple[CalibrationState, Estimate]:
        """Settle the outcomes ``est`` decides, then publish its tracks' calibrated existence."""
        counts, learned = state.counts.copy(), state.learned.copy()
        where = {lab: i for i, lab in enumerate(state.labels)}
        src = np.array([where.get(t.label, -1) for t in est.tracks], dtype=np.int64)
        waiting = _ended(self, state, src, counts, learned, est)
        detected = {a for a in est.assignments if a is not None}
        det = np.array([t.label in detected for t in est.tracks], dtype=bool)
        r = np.array([t.existence for t in est.tracks], dtype=float)
        have = src >= 0
        n, m = np.zeros(src.size, np.int64), np.zeros(src.size, np.int64)
        n[have], m[have] = state.rows[src[have], _N], state.rows[src[have], _M]
        pend = np.zeros((src.size, 2, _WIDTH))
        pend[have] = state.pending[src[have]]
        again = det & (m == 0)  # detected twice in a row: the held and pending frames were real
        settle(counts, learned, pend[again], True)
        pend[again] = 0.0
        hold = det & (m > 0)  # one detection after a miss: hold the pending frames a scan
        if hold.any():
            pend[hold, 1] += pend[hold, 0]
            pend[hold, 0] = 0.0
        n, m = n + det, np.where(det, 0, m + 1)
        c = track_class(n, m)
        pend[np.arange(src.size), 0, c] += 1.0
        young = n < ESTABLISHED
        pend[young, 0, _ODDS] += 1.0 - r[young]
        pend[young, 0, _ODDS + 1] += r[young]
        pend[~young & (m > 0), 0, _MISSES] += 1.0
        learned[0] += np.count_nonzero(~young)
        p = (self.weight * self.prior(learned, n, m, r) + counts[0, c]) / (self.weight + counts[0, c] + counts[1, c])
        tracks = tuple(TrackEstimate(t.label, t.state, t.covariance, x, t.cluster)  # every field but existence kept
                       for t, x in zip(est.tracks, np.clip(p, 0.0, 1.0).tolist()))
        return _state(state, est, (n, m, pend), counts, learned, waiting), replace(est, tracks=tracks)


def _ended(cal: ExistenceCalibration, state: CalibrationState, src: np.ndarray, counts: np.ndarray,
           learned: np.ndarray, est: Estimate) -> np.ndarray:
    """Settle the rows of ``state`` whose label is not published in ``est``: real when a new label
    (``src`` -1) lies in the row's gate, not real once it ended more than :data:`REBIRTH_SCANS`
    scans ago; the rows still waiting."""
    gone = np.ones(len(state.labels), dtype=bool)
    gone[src[src >= 0]] = False
    gone = np.flatnonzero(gone)
    if not gone.size:
        return gone
    new = [t for t, i in zip(est.tracks, src.tolist()) if i < 0]
    pos = np.array([t.state[[0, 2]] for t in new]).reshape(-1, 2)
    pos_cov = np.array([t.covariance[np.ix_([0, 2], [0, 2])] for t in new]).reshape(-1, 2, 2)
    dt = (est.stamp_ns - state.rows[gone, _STAMP]) * 1e-9
    near = _may_gate(state.mean[gone], state.cov[gone], dt, pos, pos_cov)
    reborn = np.array([bool(may) and gated(state.mean[i], state.cov[i], t, pos, pos_cov).any()
                       for i, may, t in zip(gone.tolist(), near.tolist(), dt.tolist())], dtype=bool)
    settle(counts, learned, state.pending[gone[reborn]], True)
    expired = ~reborn & (state.rows[gone, _LAST] < est.frame - REBIRTH_SCANS)
    dead = gone[expired]
    settle(counts, learned, state.pending[dead], False, int(np.count_nonzero(state.rows[dead, _N] >= ESTABLISHED)))
    return gone[~reborn & ~expired]


def from_config(params, config) -> ExistenceCalibration | None:
    """The calibration a tracker's settings ask for (``calibration_weight``,
    ``calibration_hazard_weight``, ``calibration_odds_weight``) with the model's ``p_survival``
    and ``p_detect``; None when ``calibration_weight`` is 0."""
    if config.calibration_weight == 0:
        return None
    return ExistenceCalibration(params.p_survival, params.p_detect, config.calibration_weight,
                                config.calibration_hazard_weight, config.calibration_odds_weight)


def calibrate(calibration: ExistenceCalibration | None, state, new_state, est: Estimate):
    """A tracker's step output ``(new_state, est)`` with ``est``'s calibrated existence and the
    calibration's state carried from ``state`` to ``new_state`` (their fields ``cal_<name>`` for
    each field of :class:`CalibrationState`); unchanged when ``calibration`` is None."""
    if calibration is None:
        return new_state, est
    cal, est = calibration.step(CalibrationState(*(getattr(state, "cal_" + n) for n in _FIELDS)), est)
    out = copy.copy(new_state)  # a fresh copy nobody holds yet: its calibration fields set in place
    for n in _FIELDS:
        object.__setattr__(out, "cal_" + n, getattr(cal, n))
    return out, est


_FIELDS = tuple(f.name for f in fields(CalibrationState))


def _state(state: CalibrationState, est: Estimate, tracked: tuple, counts: np.ndarray, learned: np.ndarray,
           waiting: np.ndarray) -> CalibrationState:
    """The calibration's next state: a row per published track, then the ended rows still waiting."""
    n, m, pend = tracked
    K = len(est.tracks)
    rows = np.empty((K, 4), dtype=np.int64)
    rows[:, _N], rows[:, _M], rows[:, _LAST], rows[:, _STAMP] = n, m, est.frame, est.stamp_ns
    mean = np.array([t.state for t in est.tracks], dtype=float).reshape(K, 5)
    cov = np.array([t.covariance for t in est.tracks], dtype=float).reshape(K, 5, 5)
    return CalibrationState(counts, learned, est.labels + tuple(state.labels[i] for i in waiting.tolist()),
                            np.concatenate([rows, state.rows[waiting]]), np.concatenate([pend, state.pending[waiting]]),
                            np.concatenate([mean, state.mean[waiting]]), np.concatenate([cov, state.cov[waiting]]))
