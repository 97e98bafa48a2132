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

__all__ = ["RunScorer", "OSPA_C", "OSPA_P", "OSPA2_WINDOW"]

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
