r"""Calibrated existence: the probability a published track is real, learned from the run itself.

The tracker's own existence :math:`r` follows the model's odds (``P_S``, ``P_D``, the birth and
clutter weights), so it means what it says only where the scene follows the model: an
established track in its first missed scan has :math:`r \approx 0.66` on every scene, and a
track at its first detections is under-confident.  :class:`ExistenceCalibration` publishes in
its place the posterior mean of the rate at which tracks **like this one** turn out real in this
run, learned causally from the run's own hindsight:

* **Class** of a track-frame, from the published stream of the track's label: detected after
  ``n`` detections so far (``n = 1 ..`` :data:`DETECTED_CLASSES`, the last "or more"), or missed
  ``m`` scans in a row (``m = 1, 2,`` 3 or more) after fewer than :data:`ESTABLISHED`
  detections (young) or at least that many (established): 12 classes.
* **Outcome** of a track-frame, known in hindsight: *real* when its label is detected again, or
  when, within :data:`REBIRTH_SCANS` scans after the label ended, a new label is published
  inside the ended track's gate (its position run forward at constant velocity; chi-square
  :data:`GATE` on the summed position covariances: the object was still there and its track
  was re-born); *not real* when the label ended and no such track followed.  A track-frame's
  outcome is pending until one of these.
* **Calibrated existence** of a track of class :math:`c` with the tracker's existence :math:`r`:
  :math:`(w\,r + y_c) / (w + y_c + n_c)`, the mean of a Beta prior of weight :math:`w` (``weight``,
  in track-frames) centred on :math:`r`, updated with the class's outcomes so far in the run,
  :math:`y_c` real and :math:`n_c` not.

The layer reads only the estimates (labels, positions, assignments, existences), so it changes
no published track, state or label: it replaces each track's ``existence`` and nothing else.
Its state (:class:`CalibrationState`) is plain arrays, part of the tracker state that snapshots
store.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from bnptrack.tracker.types import Estimate

#: Detected classes: after 1, 2, ..., this many or more detections.
DETECTED_CLASSES = 6
#: Missed classes per age: 1, 2, this many or more misses in a row.
MISSED_CLASSES = 3
#: Detections from which a missed track counts as established.
ESTABLISHED = 3
#: Number of classes.
CLASSES = DETECTED_CLASSES + 2 * MISSED_CLASSES
#: Scans after a label ends within which a new label inside its gate makes its outcome real.
REBIRTH_SCANS = 3
#: Chi-square gate (two dimensions, 99.9 %) of a re-born track about an ended one.
GATE = 13.8
#: Default prior weight (track-frames) of the tracker's existence against the run's outcomes.
PRIOR_WEIGHT = 20.0
#: Default prior weight (scans) of the model's ``P_S`` and ``P_D`` against the run's established tracks.
HAZARD_WEIGHT = 200.0

# columns of CalibrationState.rows
_N, _M, _LAST, _STAMP = range(4)


@dataclass(frozen=True)
class CalibrationState:
    """``counts`` (2, CLASSES): outcomes real / not real per class.  One row per label that is
    published, or that ended less than :data:`REBIRTH_SCANS` scans ago: ``labels``, ``rows``
    (R, 4) int64 = detections so far, misses in a row, the frame and the stamp (ns) it was last
    published at; ``mean`` (R, 5), ``cov`` (R, 5, 5) its last published
    state."""

    counts: np.ndarray = field(default_factory=lambda: np.zeros((2, CLASSES)))
    hazard: np.ndarray = field(default_factory=lambda: np.zeros(3))
    labels: tuple[str, ...] = ()
    rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))
    mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 5, 5)))


def track_class(n: int, m: int) -> int:
    """The class of a track-frame after ``n`` detections with ``m`` misses in a row."""
    if m == 0:
        return min(n, DETECTED_CLASSES) - 1
    return DETECTED_CLASSES + (MISSED_CLASSES if n >= ESTABLISHED else 0) + min(m, MISSED_CLASSES) - 1


def pending_classes(n: int, m: int) -> list[int]:
    """The classes of a label's track-frames whose outcome is pending: its last detected frame
    (when it has one) and the misses since."""
    out = [track_class(n, 0)] if n > 0 else []
    return out + [track_class(n, j) for j in range(1, m + 1)]


def gated(mean: np.ndarray, cov: np.ndarray, dt: float, pos: np.ndarray, pos_cov: np.ndarray) -> bool:
    """Whether position ``pos`` (covariance ``pos_cov``) lies in the chi-square :data:`GATE` of the
    state ``(mean, cov)`` (``[x, vx, y, vy, turn]``) run ``dt`` seconds forward at constant velocity."""
    F = np.array([[1.0, dt, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, dt, 0.0]])
    S = F @ cov @ F.T + pos_cov
    d = pos - F @ mean
    return bool(d @ np.linalg.solve(S, d) <= GATE)


@dataclass(frozen=True)
class ExistenceCalibration:
    """The calibration above with prior weight ``weight`` (track-frames)."""

    p_survival: float = 0.99
    p_detect: float = 0.98
    weight: float = PRIOR_WEIGHT
    hazard_weight: float = HAZARD_WEIGHT

    def __post_init__(self) -> None:
        for name in ("weight", "hazard_weight"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ExistenceCalibration: {name} must be > 0, got {getattr(self, name)!r}")

    def rates(self, hazard: np.ndarray) -> tuple[float, float]:
        """The learned per-scan death hazard and miss rate of established tracks: Beta posterior
        means, priors centred on ``1 - p_survival`` and ``1 - p_detect`` with weight
        ``hazard_weight`` scans, updated with the run's exposure, deaths and missed scans."""
        w, (exposure, deaths, misses) = self.hazard_weight, hazard.tolist()
        return ((w * (1.0 - self.p_survival) + deaths) / (w + exposure),
                (w * (1.0 - self.p_detect) + misses) / (w + exposure))

    def missed(self, hazard: np.ndarray, m: int) -> float:
        r"""Probability that an established track missed ``m`` scans in a row exists, with the
        learned hazard :math:`h` and miss rate :math:`\mu`: alive :math:`((1-h)\mu)^m` against
        died in one of the scans, :math:`\sum_{j<m} ((1-h)\mu)^j h`."""
        h, mu = self.rates(hazard)
        a = (1.0 - h) * mu
        return a**m / (a**m + h * sum(a**j for j in range(m)))

    def step(self, state: CalibrationState, est: Estimate) -> tuple[CalibrationState, Estimate]:
        """Settle the outcomes ``est`` decides, then publish its tracks' calibrated existence."""
        counts, hazard = state.counts.copy(), state.hazard.copy()
        book = {lab: (row.tolist(), state.mean[i], state.cov[i]) for i, (lab, row) in
                enumerate(zip(state.labels, state.rows))}
        detected = {a for a in est.assignments if a is not None}
        live = {t.label for t in est.tracks}
        self._rebirths(book, live, counts, hazard, est)
        self._expire(book, counts, hazard, est.frame)
        tracks, labels = [], []
        for t in est.tracks:
            (n, m, _last, _stamp), _m, _P = book.pop(t.label, ([0, 0, -1, 0], None, None))
            if t.label in detected:
                settle(counts, hazard, n, m, True)
                n, m = n + 1, 0
            else:
                m += 1
            hazard[0] += n >= ESTABLISHED
            c = track_class(n, m)
            prior = self.missed(hazard, m) if m and n >= ESTABLISHED else float(t.existence)
            r = (self.weight * prior + counts[0, c]) / (self.weight + counts[:, c].sum())
            tracks.append(replace(t, existence=min(max(r, 0.0), 1.0)))
            labels.append((t.label, [n, m, est.frame, est.stamp_ns], t.state, t.covariance))
        labels += [(lab, row, mu, P) for lab, (row, mu, P) in book.items()]  # ended, still waiting
        return _state(counts, hazard, labels), replace(est, tracks=tuple(tracks))

    @staticmethod
    def _rebirths(book: dict, live: set, counts: np.ndarray, hazard: np.ndarray, est: Estimate) -> None:
        """A new label inside an ended track's gate makes the ended track's pending outcomes real."""
        new = [t for t in est.tracks if t.label not in book]
        if not new:
            return
        for lab in [lab for lab in book if lab not in live]:
            row, mu, P = book[lab]
            dt = (est.stamp_ns - row[_STAMP]) * 1e-9
            if any(gated(mu, P, dt, t.state[[0, 2]], t.covariance[np.ix_([0, 2], [0, 2])]) for t in new):
                settle(counts, hazard, row[_N], row[_M], True)
                del book[lab]

    @staticmethod
    def _expire(book: dict, counts: np.ndarray, hazard: np.ndarray, frame: int) -> None:
        """Labels ended more than :data:`REBIRTH_SCANS` scans ago without a re-birth: not real."""
        for lab in [lab for lab, (row, _mu, _P) in book.items() if row[_LAST] < frame - REBIRTH_SCANS]:
            row = book.pop(lab)[0]
            settle(counts, hazard, row[_N], row[_M], False)


def settle(counts: np.ndarray, hazard: np.ndarray, n: int, m: int, real: bool) -> None:
    """Count the outcome of a label's pending track-frames (``n`` detections, ``m`` misses since);
    for an established label, its misses as an alive object's (``real``) or its death."""
    np.add.at(counts[0 if real else 1], pending_classes(n, m), 1.0)
    if n >= ESTABLISHED and m > 0:
        hazard[2 if real else 1] += m if real else 1


def _state(counts: np.ndarray, hazard: np.ndarray, labels: list) -> CalibrationState:
    if not labels:
        return CalibrationState(counts, hazard)
    labs, rows, mean, cov = zip(*labels)
    return CalibrationState(counts, hazard, tuple(labs), np.array(rows, dtype=np.int64).reshape(-1, 4),
                            np.array(mean, dtype=float).reshape(-1, 5), np.array(cov, dtype=float).reshape(-1, 5, 5))
