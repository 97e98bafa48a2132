"""Per-frame scores of a tracking run as it goes: OSPA and OSPA(2) (:class:`RunScorer`).

Used by the Rerun recordings (:mod:`sinks.rerun_sink`, :mod:`sinks.rerun_writer`) and the
pipeline's sink stage.  This module imports neither rerun nor scipy (``sinks.metrics`` imports
scipy when it first computes a score), so a process can score frames without paying for the
recording's imports and vice versa.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from sinks.metrics import OspaResult, _cutoff_distances, _ospa_unchecked, _track_distances, _window_tracks, ospa
from tracker.types import Estimate, Frame

__all__ = ["RunScorer", "ScoreTally", "OSPA_C", "OSPA_P", "OSPA2_WINDOW"]

#: OSPA cut-off (m) and order of the paper's experiments: ``bnptrack track``, the experiments
#: and the recordings all use these.
OSPA_C = 100.0
OSPA_P = 1.0
#: OSPA(2) sliding window in scans (and its inner order q = 1).
OSPA2_WINDOW = 10


class RunScorer:
    """Per-frame OSPA and OSPA(2) of a run, computed as frames arrive.

    ``update(frame, estimate)`` returns ``{"ospa": OspaResult | None, "ospa2": float | None}``
    (``None`` for a frame without truth), ready to pass to :meth:`sinks.rerun_sink.RerunSink.log`.  OSPA is
    :func:`sinks.metrics.ospa` of (truth positions, estimated positions), as
    ``pipeline.offline.frame_metrics`` computes it; OSPA(2) at frame k is
    :func:`sinks.metrics.ospa2` over the last ``window`` frames, the value
    :func:`sinks.metrics.ospa2_series` gives at k for the whole run.

    It runs on the tracker's thread of ``bnptrack track --rrd`` for every frame, so it keeps
    each scan as (labels, ``(n, 2)`` positions) and goes straight to the metrics' kernels
    (the OSPA(2) window is built by the same ``_window_tracks`` as ``ospa2_series``'s);
    the public functions' checks run only for a scan with a non-finite position, where they
    raise their error.
    """

    def __init__(self, c: float = OSPA_C, p: float = OSPA_P, window: int = OSPA2_WINDOW,
                 q: float = 1.0) -> None:
        self.c, self.p, self.q, self.window = float(c), float(p), float(q), int(window)
        self._est: deque[tuple[tuple[str, ...], np.ndarray]] = deque(maxlen=self.window)
        self._true: deque[tuple[tuple[str, ...], np.ndarray]] = deque(maxlen=self.window)

    def update(self, frame: Frame, estimate: Estimate, ospa_result: OspaResult | None = None) -> dict[str, Any]:
        """The frame's scores.  ``ospa_result``: its OSPA if the caller has it already (the same
        value, e.g. ``pipeline.offline.FrameMetrics.ospa_result``: ``bnptrack track --rrd``
        scores every frame for its summary anyway); otherwise computed here."""
        est = estimate.positions
        self._est.append((estimate.labels, est))
        if frame.truth is None:
            self._true.append(((), _NO_POSITIONS))
            return {"ospa": None, "ospa2": None}
        truth = frame.truth
        true = truth.positions
        self._true.append((tuple(truth.ids), true))
        if not (np.isfinite(est).all() and np.isfinite(true).all()):
            ospa(true, est, c=self.c, p=self.p)  # raises, naming the bad position
        o = ospa_result if ospa_result is not None else _ospa_unchecked(
            _cutoff_distances(true, est, self.c), self.c, self.p)
        X, Y = _window_tracks(list(self._est), 2), _window_tracks(list(self._true), 2)
        o2 = _ospa_unchecked(_track_distances(X, Y, self.c, self.q), self.c, self.p).total
        return {"ospa": o, "ospa2": float(o2)}


_NO_POSITIONS = np.zeros((0, 2))


class ScoreTally:
    """Running means of a run's scores, for progress lines and summaries (the pipeline's
    sink: ``sink.json`` ``scores``, its health messages, ``bnptrack launch``'s progress).

    ``add(frame, estimate, scores)`` takes one frame and its :meth:`RunScorer.update`
    result.  Means are over the frames with truth (as ``bnptrack track``'s mean OSPA and
    mean cardinality error: :func:`sinks.metrics.cardinality_error` = ``|n_est - n_true|``);
    ``tracks`` is the number of tracks of the last frame, ``labels`` the number of distinct
    labels reported so far.
    """

    __slots__ = ("frames", "scored", "_ospa", "_ospa2", "_card", "tracks", "labels", "_seen", "last_ospa")

    def __init__(self) -> None:
        self.frames = 0
        self.scored = 0
        self._ospa = self._ospa2 = self._card = 0.0
        self.tracks = 0
        self.labels = 0
        self._seen: set[str] = set()
        self.last_ospa: float | None = None

    def add(self, frame: Frame, estimate: Estimate, scores: dict[str, Any]) -> None:
        self.frames += 1
        labels = estimate.labels
        self.tracks = len(labels)
        self._seen.update(labels)
        self.labels = len(self._seen)
        o = scores.get("ospa")
        if o is None or frame.truth is None:
            return
        self.scored += 1
        self.last_ospa = float(o.total)
        self._ospa += float(o.total)
        self._ospa2 += float(scores.get("ospa2") or 0.0)
        self._card += abs(len(labels) - len(frame.truth.ids))

    def _mean(self, total: float) -> float | None:
        return total / self.scored if self.scored else None

    def as_dict(self) -> dict[str, Any]:
        """``{"frames", "frames_scored", "ospa", "ospa2", "cardinality_error", "tracks",
        "labels", "last_ospa"}`` (means; ``None`` without truth)."""
        return {"frames": self.frames, "frames_scored": self.scored, "ospa": self._mean(self._ospa),
                "ospa2": self._mean(self._ospa2), "cardinality_error": self._mean(self._card),
                "tracks": self.tracks, "labels": self.labels, "last_ospa": self.last_ospa,
                "c": OSPA_C, "p": OSPA_P, "ospa2_window": OSPA2_WINDOW}
