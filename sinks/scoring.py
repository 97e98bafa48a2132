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

from sinks.metrics import ospa, ospa2
from tracker.types import Estimate, Frame

__all__ = ["RunScorer", "OSPA_C", "OSPA_P", "OSPA2_WINDOW"]

#: OSPA cut-off (m) and order of the recordings (same as ``bnptrack track``).
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
    """

    def __init__(self, c: float = OSPA_C, p: float = OSPA_P, window: int = OSPA2_WINDOW,
                 q: float = 1.0) -> None:
        self.c, self.p, self.q, self.window = float(c), float(p), float(q), int(window)
        self._est: deque[dict[str, np.ndarray]] = deque(maxlen=self.window)
        self._true: deque[dict[str, np.ndarray]] = deque(maxlen=self.window)

    def update(self, frame: Frame, estimate: Estimate) -> dict[str, Any]:
        self._est.append({t.label: np.asarray(t.position, dtype=float) for t in estimate.tracks})
        if frame.truth is None:
            self._true.append({})
            return {"ospa": None, "ospa2": None}
        truth = frame.truth
        self._true.append(dict(zip(truth.ids, truth.positions)))
        o = ospa(truth.positions, estimate.positions, c=self.c, p=self.p)
        X, Y = _window(list(self._est)), _window(list(self._true))
        if X.shape[0] == 0 and Y.shape[0] == 0:
            o2 = 0.0
        else:
            o2 = ospa2(X, Y, c=self.c, p=self.p, q=self.q).total
        return {"ospa": o, "ospa2": float(o2)}


def _window(run: list[dict[str, np.ndarray]]) -> np.ndarray:
    """``(n_labels, W, 2)`` NaN-padded tracks of the labels present in ``run`` (first-seen order)."""
    labels = dict.fromkeys(label for scan in run for label in scan)
    index = {label: i for i, label in enumerate(labels)}
    arr = np.full((len(index), len(run), 2), np.nan)
    for t, scan in enumerate(run):
        for label, pos in scan.items():
            arr[index[label], t] = pos
    return arr
