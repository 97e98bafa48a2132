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

from dataclasses import dataclass, field, fields, replace

import numpy as np

from bnptrack.tracker.types import Estimate

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


def track_class(n: int, m: int) -> int:
    """The class of a track-frame after ``n`` detections with ``m`` misses in a row."""
    if m == 0:
        return min(n, DETECTED_CLASSES) - 1
    return DETECTED_CLASSES + (MISSED_CLASSES if n >= ESTABLISHED else 0) + min(m, MISSED_CLASSES) - 1


def gated(mean: np.ndarray, cov: np.ndarray, dt: float, pos: np.ndarray, pos_cov: np.ndarray) -> bool:
    """Whether position ``pos`` (covariance ``pos_cov``) lies in the chi-square :data:`GATE` of the
    state ``(mean, cov)`` (``[x, vx, y, vy, turn]``) run ``dt`` seconds forward at constant velocity."""
    F = np.array([[1.0, dt, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, dt, 0.0]])
    S = F @ cov @ F.T + pos_cov
    d = pos - F @ mean
    return bool(d @ np.linalg.solve(S, d) <= GATE)


def settle(counts: np.ndarray, learned: np.ndarray, pend: np.ndarray, real: bool, established: bool) -> None:
    """Count the outcome of pending track-frames ``pend`` (a pending vector, or both rows of a
    label's): per class; the young ones' odds sums; an established label's missed scans as a
    live object's (``real``), or its death."""
    pend = pend.reshape(-1, _WIDTH).sum(axis=0)
    counts[0 if real else 1] += pend[:CLASSES]
    learned[3 if real else 4] += pend[_ODDS if real else _ODDS + 1]
    if real:
        learned[2] += pend[_MISSES]
    elif established:
        learned[1] += 1.0


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

    def missed(self, learned: np.ndarray, m: int) -> float:
        """Probability that an established track missed ``m`` scans in a row is alive."""
        h, mu = self.rates(learned)
        a = (1.0 - h) * mu
        return a**m / (a**m + h * sum(a**j for j in range(m)))

    def young(self, learned: np.ndarray, r: float) -> float:
        r"""The existence ``r`` of a young track with its odds multiplied by the run's
        Mantel-Haenszel odds ratio of young outcomes against their existence,
        :math:`\kappa = (w + \sum_\text{real} (1 - r_i)) / (w + \sum_\text{not} r_i)` (``odds_weight``
        pseudo-counts on each side: :math:`\kappa = 1` without evidence)."""
        kappa = (self.odds_weight + learned[3]) / (self.odds_weight + learned[4])
        return kappa * r / (kappa * r + 1.0 - r)

    def prior(self, learned: np.ndarray, n: int, m: int, r: float) -> float:
        """The learned model's probability for a track-frame (the centre of its class's prior)."""
        if n >= ESTABLISHED:
            return self.missed(learned, m) if m else r
        return self.young(learned, r)

    def step(self, state: CalibrationState, est: Estimate) -> tuple[CalibrationState, Estimate]:
        """Settle the outcomes ``est`` decides, then publish its tracks' calibrated existence."""
        counts, learned = state.counts.copy(), state.learned.copy()
        book = {lab: [state.rows[i].tolist(), state.pending[i].copy(), state.mean[i], state.cov[i]]
                for i, lab in enumerate(state.labels)}
        live = {t.label for t in est.tracks}
        self._rebirths(book, live, counts, learned, est)
        self._expire(book, counts, learned, est.frame)
        detected = {a for a in est.assignments if a is not None}
        tracks, kept = [], {}
        for t in est.tracks:
            row, pend = book.pop(t.label, [[0, 0, -1, 0], np.zeros((2, _WIDTH))])[:2]
            n, m, r = row[_N], row[_M], float(t.existence)
            if t.label in detected:
                n, m = self._detected(counts, learned, pend, n, m)
            else:
                m += 1
            c = track_class(n, m)
            pend[0, c] += 1.0
            if n < ESTABLISHED:
                pend[0, _ODDS:_ODDS + 2] += (1.0 - r, r)
            elif m:
                pend[0, _MISSES] += 1.0
            learned[0] += n >= ESTABLISHED
            p = (self.weight * self.prior(learned, n, m, r) + counts[0, c]) / (self.weight + counts[:, c].sum())
            tracks.append(replace(t, existence=float(min(max(p, 0.0), 1.0))))
            kept[t.label] = [[n, m, est.frame, est.stamp_ns], pend, t.state, t.covariance]
        kept.update(book)  # ended, still waiting for a re-birth
        return _state(counts, learned, kept), replace(est, tracks=tuple(tracks))

    @staticmethod
    def _detected(counts, learned, pend: np.ndarray, n: int, m: int) -> tuple[int, int]:
        """A detection: after a detection it settles the held and pending track-frames as real;
        after a miss it holds the pending ones until the next scan."""
        if m == 0:
            settle(counts, learned, pend, True, n >= ESTABLISHED)
            pend[:] = 0.0
        else:
            pend[1] += pend[0]
            pend[0] = 0.0
        return n + 1, 0

    @staticmethod
    def _rebirths(book: dict, live: set, counts: np.ndarray, learned: np.ndarray, est: Estimate) -> None:
        """A new label inside an ended track's gate makes the ended track's outcomes real."""
        new = [t for t in est.tracks if t.label not in book]
        if not new:
            return
        for lab in [lab for lab in book if lab not in live]:
            row, pend, mu, P = book[lab]
            dt = (est.stamp_ns - row[_STAMP]) * 1e-9
            if any(gated(mu, P, dt, t.state[[0, 2]], t.covariance[np.ix_([0, 2], [0, 2])]) for t in new):
                settle(counts, learned, pend, True, row[_N] >= ESTABLISHED)
                del book[lab]

    @staticmethod
    def _expire(book: dict, counts: np.ndarray, learned: np.ndarray, frame: int) -> None:
        """Labels ended more than :data:`REBIRTH_SCANS` scans ago without a re-birth: not real."""
        for lab in [lab for lab, entry in book.items() if entry[0][_LAST] < frame - REBIRTH_SCANS]:
            row, pend = book.pop(lab)[:2]
            settle(counts, learned, pend, False, row[_N] >= ESTABLISHED)


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
    old = CalibrationState(*(getattr(state, "cal_" + f.name) for f in fields(CalibrationState)))
    cal, est = calibration.step(old, est)
    return replace(new_state, **{"cal_" + f.name: getattr(cal, f.name) for f in fields(cal)}), est


def _state(counts: np.ndarray, learned: np.ndarray, book: dict) -> CalibrationState:
    if not book:
        return CalibrationState(counts, learned)
    rows, pend, mean, cov = zip(*book.values())
    return CalibrationState(counts, learned, tuple(book), np.array(rows, dtype=np.int64).reshape(-1, 4),
                            np.array(pend, dtype=float).reshape(-1, 2, _WIDTH),
                            np.array(mean, dtype=float).reshape(-1, 5), np.array(cov, dtype=float).reshape(-1, 5, 5))
