"""Fixed-lag rows of ``benchmarks/vs_stonesoup.py``: bnptrack's trackers through the fixed-lag
layer (:mod:`tracker.lag`) and the Stone Soup JPDA anchor with Stone Soup's unscented
Rauch-Tung-Striebel smoother over the same lag.

A lagged anchor publishes, at frame ``k``, the tracks the online anchor published at ``k``
(its births and deletions are not re-decided), each smoothed over its own states from frame
``k`` to frame ``k + lag`` (``stonesoup.smoother.kalman.UnscentedKalmanSmoother`` with the
anchor's transition model and unscented-transform parameters, on a ``Track`` of those states):
the hindsight a fixed-lag smoother with ``lag`` scans has.  The GM-PHD anchor has no tracks
(its estimates are extracted mixture components), so it has no smoothed row.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from bnptrack.tracker.lag import FixedLag
from bnptrack.tracker.state import tracker_frame_rng

__all__ = ["SMOOTHED_ANCHORS", "lagged_bnp", "smoothed_jpda"]

#: The anchors with a smoothed (lagged) row.
SMOOTHED_ANCHORS = ("ss-jpda",)


def lagged_bnp(tracker, params, frames, seed: int, lag: int, scan_cls) -> list:
    """``tracker``'s fixed-lag output as ``scan_cls(labels, positions, ms)`` per frame (ms: the
    tracker's step and the layer's, the last ``lag`` frames' flush spread over them)."""
    layer = FixedLag(tracker, params, lag)
    state, out, ms = layer.initial_state(), [], []
    for f in frames:
        t0 = time.process_time()
        state, st = layer.step(state, f, tracker_frame_rng(seed, f.frame))
        ms.append((time.process_time() - t0) * 1e3)
        if st.lagged is not None:
            out.append(st.lagged)
    t0 = time.process_time()
    out.extend(e for _f, e in layer.flush(state))
    tail = (time.process_time() - t0) * 1e3 / max(len(frames), 1)
    return [scan_cls(e.labels, np.asarray(e.positions, float).reshape(-1, 2), m + tail) for e, m in zip(out, ms)]


def smoothed_jpda(params, jpda_settings, frames, lag: int, scan_cls) -> tuple[list, list, int]:
    """The JPDA anchor's online scans and its smoothed scans (``lag`` scans of hindsight), and
    the warnings Stone Soup raised.  ms of a smoothed scan: the anchor's step plus the smoothing
    of the frame's tracks."""
    from stonesoup.smoother.kalman import UnscentedKalmanSmoother
    from stonesoup.types.track import Track

    from benchmarks.stonesoup_anchors import UKF_ALPHA, UKF_BETA, UKF_KAPPA, JpdaAnchor, _models
    from benchmarks.anchor_convert import position

    anchor = JpdaAnchor(params, jpda_settings)
    transition = _models(params)[0]
    smoother = UnscentedKalmanSmoother(transition, alpha=UKF_ALPHA, beta=UKF_BETA, kappa=UKF_KAPPA)
    online, published, ms = [], [], []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for f in frames:
            t0 = time.process_time()
            anchor.step(f)
            ms.append((time.process_time() - t0) * 1e3)
            tracks = list(anchor.tracker.tracks)
            # each track's index of this frame's state (a track gets one state per scan)
            published.append([(t, len(t.states) - 1) for t in tracks])
            online.append(scan_cls(tuple(str(t.id) for t in tracks),
                                   np.array([position(t.state_vector) for t in tracks], float).reshape(-1, 2), ms[-1]))
        smoothed = []
        for k, rows in enumerate(published):
            t0 = time.process_time()
            pos = [_smoothed_position(smoother, Track(t.states[i:i + lag + 1]), position) for t, i in rows]
            extra = (time.process_time() - t0) * 1e3
            smoothed.append(scan_cls(online[k].labels, np.array(pos, float).reshape(-1, 2), ms[k] + extra))
    return online, smoothed, len(caught)


def _smoothed_position(smoother, window, position) -> np.ndarray:
    """The position of the first state of ``window`` after smoothing over it (its filtered
    position when the window has one state)."""
    if len(window.states) < 2:
        return position(window.states[0].state_vector)
    return position(smoother.smooth(window).states[0].state_vector)
