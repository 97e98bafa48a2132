"""The running scores of a run as frames arrive: :class:`RunScorer` (OSPA, OSPA(2) and GOSPA of
each frame, the one scorer of ``bnptrack track``, the pipeline's sink and experiments) and
:class:`ScoreTally` (their running means).  The metrics themselves are :mod:`sinks.metrics`;
this module computes each frame's cut-off distance matrix once and shares it between them.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from itertools import chain
from typing import Any

import msgspec
import numpy as np

from bnptrack.sinks.metric_checks import check_alpha, optimal_assignment
from bnptrack.sinks.metrics import (OSPA2_WINDOW, OSPA_C, OSPA_P, GospaResult, OspaResult, _cutoff_distances,
                                    _gospa_from_pairs, _gospa_unchecked, _ospa_unchecked, _root, ospa)
from bnptrack.tracker.types import POSITION_INDEX, Estimate, Frame, display_name

__all__ = ["RunScorer", "ScoreTally", "RunScores"]


class RunScores(msgspec.Struct, frozen=True, kw_only=True):
    """A run's scores so far (:meth:`ScoreTally.totals`; ``sink.json``'s ``scores``): means
    over the frames with truth (``None`` without truth)."""

    frames: int = 0
    frames_scored: int = 0
    ospa: float | None = None
    ospa2: float | None = None
    cardinality_error: float | None = None
    #: the number of tracks of the last frame, and their display names
    tracks: int = 0
    names: tuple[str, ...] = ()
    #: distinct labels reported so far
    labels: int | None = None
    last_ospa: float | None = None
    c: float = OSPA_C
    p: float = OSPA_P
    ospa2_window: int | None = OSPA2_WINDOW


class RunScorer:
    """Per-frame OSPA and OSPA(2) of a run (and GOSPA on request), computed as frames arrive.

    ``update(frame, estimate)`` returns ``{"ospa": OspaResult | None, "ospa2": float | None}``
    (``None`` for a frame without truth), ready to pass to :meth:`sinks.rerun_sink.RerunSink.log`;
    with ``gospa_alpha`` set, also ``"gospa"``: :func:`gospa` (truth, estimate) with that
    alpha.  OSPA is :func:`ospa` of (truth positions, estimated positions); OSPA(2) at frame k
    is :func:`ospa2` over the last ``window`` frames, the value :func:`ospa2_series` gives at k
    for the whole run, bit for bit.

    It runs on the tracker's thread of ``bnptrack track --rrd`` for every frame and on every
    frame of a Monte Carlo study, so each frame's cut-off distance matrix is computed once
    (:func:`_euclidean`) and serves three times: OSPA and GOSPA share its optimal assignment,
    and the OSPA(2) window (:class:`_TrackWindow`) keeps it as the per-scan base distances of
    every (estimated, true) label pair of that scan.  The public functions' checks run only for
    a scan with a non-finite position, where they raise.  ``compiled=True`` builds the window's
    terms with one compiled kernel (:mod:`sinks._score_window`, numba: for processes that have
    it loaded, e.g. the Monte Carlo runner's) instead of some twenty numpy calls, bit for bit.
    """

    def __init__(self, c: float = OSPA_C, p: float = OSPA_P, window: int = OSPA2_WINDOW,
                 q: float = 1.0, gospa_alpha: float | None = None, compiled: bool = False) -> None:
        self.c, self.p, self.q, self.window = float(c), float(p), float(q), int(window)
        self.alpha = None if gospa_alpha is None else check_alpha(gospa_alpha)
        self._tracks = _TrackWindow(self.window, self.c, self.q, compiled)

    def update(self, frame: Frame, estimate: Estimate) -> dict[str, Any]:
        """The frame's scores (``bnptrack track``, the sink stage and experiments all score
        through this method)."""
        est = _positions(estimate)
        truth = frame.truth
        if truth is None:
            self._tracks.append(estimate.labels, (), np.empty((0, est.shape[0])))
            return {"ospa": None, "ospa2": None} | ({} if self.alpha is None else {"gospa": None})
        true = truth.positions
        if not (np.isfinite(est).all() and np.isfinite(true).all()):
            ospa(true, est, c=self.c, p=self.p)  # raises, naming the bad position
        D = _cutoff_distances(true, est, self.c)  # (truth, estimate)
        self._tracks.append(estimate.labels, tuple(truth.ids), D)
        o2 = _ospa_unchecked(self._tracks.distances(), self.c, self.p).total
        if self.alpha is None:
            return {"ospa": _ospa_unchecked(D, self.c, self.p), "ospa2": float(o2)}
        o, g = _ospa_gospa(D, self.c, self.p, self.alpha)
        return {"ospa": o, "ospa2": float(o2), "gospa": g}


def _positions(estimate: Estimate) -> np.ndarray:
    """``estimate.positions`` (``(N, 2)``) without a fancy-indexed row per track and a stack."""
    x, y = POSITION_INDEX
    return np.array([(t.state[x], t.state[y]) for t in estimate.tracks], dtype=float).reshape(-1, 2)


def _ospa_gospa(D: np.ndarray, c: float, p: float, alpha: float) -> tuple[OspaResult, GospaResult]:
    """:func:`_ospa_unchecked` and :func:`_gospa_unchecked` of one truth-by-estimate matrix
    from one optimal assignment: both solve it on ``D ** p`` (OSPA on the transpose when there
    are more true points, which :func:`scipy.optimize.linear_sum_assignment` does internally
    for the tall matrix anyway), so the pairs and every sum are those of the two functions."""
    m, n = D.shape
    if m == 0 or n == 0:
        return _ospa_unchecked(D, c, p), _gospa_unchecked(D, c, p, alpha)
    tall = m > n
    cost = (D.T if tall else D) ** p
    r, k = optimal_assignment(cost)
    loc_term = math.fsum(cost[r, k]) / max(m, n)
    card_term = c**p * abs(n - m) / max(m, n)
    o = OspaResult(_root(loc_term + card_term, p), _root(loc_term, p), _root(card_term, p))
    return o, _gospa_from_pairs(D[k, r] if tall else D[r, k], m, n, c, p, alpha)


class _TrackWindow:
    """The last ``window`` scans of a run as (estimated labels, true labels, their
    ``(n_true, n_est)`` cut-off distances) and the OSPA(2) base distances
    (:func:`_track_distances`) of the labels present in them.

    :meth:`distances` builds the same ``(n_labels_est, n_labels_true, W)`` array of per-scan
    terms as :func:`_track_distances` (labels in first-seen order, as :func:`_window_tracks`)
    with one indexed write of the scans' distances, and sums it the same way, so the result
    is the same bit for bit without a position array or a distance computed twice.
    """

    def __init__(self, window: int, c: float, q: float, compiled: bool = False) -> None:
        self.window, self.c, self.q, self.compiled = window, c, q, compiled
        self.cq = (np.array([c]) ** q)[0]  # the term of a scan where only one track exists
        # (labels_e, labels_t, pair_e, pair_t, terms); compiled: (ids_e, ids_t, terms)
        self._scans: deque[tuple] = deque(maxlen=window)
        self._ids: tuple[dict, dict] = ({}, {})  # compiled: run-wide ids of the estimated / true labels

    def append(self, est_labels: tuple, true_labels: tuple, D: np.ndarray) -> None:
        """One scan: its labels and ``(len(true_labels), len(est_labels))`` cut-off distances."""
        terms = (D ** self.q if self.q != 1.0 else D).ravel()
        if self.compiled:  # run-wide label ids; the kernel ranks them and walks D.ravel() itself
            ie, it = self._ids
            self._scans.append((np.fromiter([ie.setdefault(x, len(ie)) for x in est_labels], np.int64, len(est_labels)),
                                np.fromiter([it.setdefault(x, len(it)) for x in true_labels], np.int64, len(true_labels)),
                                terms))
            return
        ne, nt = len(est_labels), len(true_labels)
        pair_e = np.tile(np.arange(ne), nt)  # D.ravel()'s (estimate, truth) entries
        pair_t = np.repeat(np.arange(nt), ne)
        self._scans.append((est_labels, true_labels, pair_e, pair_t, terms))

    def distances(self) -> np.ndarray:
        """``(m, n)`` OSPA(2) base distances of the window's estimated and true tracks,
        :func:`_track_distances` of :func:`_window_tracks` of the window, bit for bit."""
        scans = self._scans
        if self.compiled:
            from bnptrack.sinks._score_window import window_terms

            per_scan, count = window_terms(scans, len(self._ids[0]), len(self._ids[1]), self.cq)
            if per_scan.size == 0:
                return np.empty(count.shape)
            mean = per_scan.sum(axis=-1) / np.maximum(count, 1)
            return mean if self.q == 1.0 else mean ** (1.0 / self.q)
        W = len(scans)
        re, ie = _first_seen_ranks([s[0] for s in scans])
        rt, it = _first_seen_ranks([s[1] for s in scans])
        if not ie or not it:
            return np.empty((len(ie), len(it)))
        cnt_e, cnt_t = [len(s[0]) for s in scans], [len(s[1]) for s in scans]
        ex = np.zeros((len(ie), W), dtype=bool)
        ey = np.zeros((len(it), W), dtype=bool)
        ex[re, np.repeat(np.arange(W), cnt_e)] = True
        ey[rt, np.repeat(np.arange(W), cnt_t)] = True
        union = ex[:, None, :] | ey[None, :, :]
        per_scan = np.where(union, self.cq, 0.0)
        pairs = [s[4].size for s in scans]
        if any(pairs):
            off_e = np.repeat(np.cumsum(cnt_e) - cnt_e, pairs)
            off_t = np.repeat(np.cumsum(cnt_t) - cnt_t, pairs)
            rows = re[np.concatenate([s[2] for s in scans]) + off_e]
            cols = rt[np.concatenate([s[3] for s in scans]) + off_t]
            per_scan[rows, cols, np.repeat(np.arange(W), pairs)] = np.concatenate([s[4] for s in scans])
        mean = per_scan.sum(axis=-1) / np.maximum(union.sum(axis=-1), 1)
        return mean if self.q == 1.0 else mean ** (1.0 / self.q)


def _first_seen_ranks(scans: list[tuple]) -> tuple[np.ndarray, dict]:
    """Every label of every scan numbered in first-seen order (:func:`_window_tracks`'s):
    (the numbers, entry by entry; label -> number)."""
    index = dict(zip(dict.fromkeys(chain.from_iterable(scans)), range(1 << 62)))
    n = sum(map(len, scans))
    return np.fromiter(map(index.__getitem__, chain.from_iterable(scans)), np.intp, n), index


class ScoreTally:
    """Running means of a run's scores, for progress lines and summaries (the pipeline's
    sink: ``sink.json`` ``scores``, its health messages, ``bnptrack launch``'s progress).

    ``add(frame, estimate, scores)`` takes one frame and its :meth:`RunScorer.update`
    result.  Means are over the frames with truth (as ``bnptrack track``'s mean OSPA and
    mean cardinality error: :func:`cardinality_error` = ``|n_est - n_true|``);
    ``tracks`` is the number of tracks of the last frame, ``names`` their display names
    (:func:`tracker.types.display_name`), ``labels`` the number of distinct labels reported so
    far.
    """

    __slots__ = ("frames", "scored", "_ospa", "_ospa2", "_card", "tracks", "names", "labels", "_seen", "last_ospa")

    def __init__(self) -> None:
        self.frames = 0
        self.scored = 0
        self._ospa = self._ospa2 = self._card = 0.0
        self.tracks = 0
        self.names: tuple[str, ...] = ()
        self.labels = 0
        self._seen: set[str] = set()
        self.last_ospa: float | None = None

    def add(self, frame: Frame, estimate: Estimate, scores: dict[str, Any]) -> None:
        labels = estimate.labels
        self.count(labels)
        o = scores.get("ospa")
        if o is None or frame.truth is None:
            return
        self.scored += 1
        self.last_ospa = float(o.total)
        self._ospa += float(o.total)
        self._ospa2 += float(scores.get("ospa2") or 0.0)
        self._card += abs(len(labels) - len(frame.truth.ids))

    def count(self, labels: Sequence[str]) -> None:
        """A frame with tracks labelled ``labels``, not scored (what :meth:`add` does for a
        frame whose scores are ``None``)."""
        self.frames += 1
        self.tracks = len(labels)
        self.names = tuple(display_name(x) for x in labels)
        self._seen.update(labels)
        self.labels = len(self._seen)

    def _mean(self, total: float) -> float | None:
        return total / self.scored if self.scored else None

    def totals(self) -> RunScores:
        """The scores so far."""
        return RunScores(frames=self.frames, frames_scored=self.scored, ospa=self._mean(self._ospa),
                         ospa2=self._mean(self._ospa2), cardinality_error=self._mean(self._card),
                         tracks=self.tracks, names=self.names, labels=self.labels, last_ospa=self.last_ospa)

    def as_dict(self) -> dict[str, Any]:
        """:meth:`totals` as plain data (a health message's ``scores``)."""
        return msgspec.to_builtins(self.totals())
