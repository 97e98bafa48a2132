"""The figures every run's summary prints, in one form: ``track`` (from its
:class:`~pipeline.offline.TrackResult`) and ``launch`` / ``replay`` (from the sink's ``sink.json``,
:class:`~pipeline.stages.summary.RunSummary`) build a :class:`RunFigures` and print
:func:`figure_rows`, so the three commands carry the same lines where the data exists: mean OSPA,
mean OSPA(2), mean cardinality error, the final tracks with their display names and the labels
reported in all, and the time per frame (with ``--lag``: the online step plus the lag layer).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bnptrack.pipeline.offline import TrackResult
    from bnptrack.pipeline.stages.summary import RunSummary

__all__ = ["RunFigures", "figure_rows", "final_tracks_text"]


@dataclass(frozen=True)
class RunFigures:
    """A run's scores (means over the frames with truth; ``None`` without), its last frame's
    tracks and the tracker's time per frame."""

    frames: int
    frames_scored: int = 0
    ospa: float | None = None
    ospa2: float | None = None
    ospa2_window: int | None = None
    cardinality_error: float | None = None
    c: float = 100.0
    p: float = 1.0
    tracks: int = 0
    names: tuple[str, ...] = ()
    labels: int | None = None
    ms: tuple[float, ...] = ()
    lag: int = 0

    @classmethod
    def of_track(cls, res: TrackResult, lag: int = 0) -> RunFigures:
        """The figures of ``bnptrack track``'s run."""
        from bnptrack.pipeline.offline import OSPA_C, OSPA_P
        from bnptrack.sinks.run_scorer import OSPA2_WINDOW

        return cls(frames=res.n_frames, frames_scored=sum(f.ospa is not None for f in res.frames),
                   ospa=res.mean_ospa, ospa2=res.mean_ospa2, ospa2_window=OSPA2_WINDOW,
                   cardinality_error=res.mean_cardinality_error, c=OSPA_C, p=OSPA_P, tracks=res.final_tracks,
                   names=res.final_names, labels=res.labels, ms=tuple(res.ms.tolist()), lag=lag)

    @classmethod
    def of_summary(cls, summary: RunSummary, lag: int = 0) -> RunFigures:
        """The figures of a pipeline run from its sink's ``sink.json`` (``scores``, and the
        tracker's ``ms`` of the timed frames in ``latency.tracker_ms``)."""
        from bnptrack.sinks.run_scorer import RunScores

        s = summary.scores if summary.scores is not None else RunScores()
        ms = tuple(float(v) for v in summary.latency.get("tracker_ms") or () if v is not None and math.isfinite(v))
        return cls(frames=s.frames, frames_scored=s.frames_scored, ospa=s.ospa, ospa2=s.ospa2,
                   ospa2_window=s.ospa2_window, cardinality_error=s.cardinality_error, c=s.c, p=s.p,
                   tracks=s.tracks, names=s.names, labels=s.labels, ms=ms, lag=lag)


def figure_rows(f: RunFigures) -> list[tuple[str, str]]:
    """The summary rows of ``f`` (``key``, ``value``)."""
    rows: list[tuple[str, str]] = []
    if f.lag:
        rows.append(("lag", lag_text(f.lag, f.frames)))
    if f.ospa is not None:
        rows.append(("mean OSPA", f"{f.ospa:.2f} m (c={f.c:g}, p={f.p:g}, position; {f.frames_scored} frames)"))
        if f.ospa2 is not None:
            rows.append(("mean OSPA(2)", f"{f.ospa2:.2f} m (window {f.ospa2_window} frames)"))
        if f.cardinality_error is not None:
            rows.append(("mean card. error", f"{f.cardinality_error:.2f}"))
    elif f.frames:
        rows.append(("mean OSPA", "n/a (no /truth with the frames)"))
    tracks = final_tracks_text(f.tracks, f.names)
    if f.labels is not None:
        tracks += f" ({f.labels} label{'' if f.labels == 1 else 's'} in all)"
    rows.append(("final tracks", tracks))
    if f.ms:
        text = f"median {statistics.median(f.ms):.2f}, p95 {_p95(f.ms):.2f}"
        if f.lag:
            text += " (the whole step: online step + lag layer)"
        rows.append(("ms per frame", text))
    return rows


def lag_text(lag: int, frames: int) -> str:
    """What ``--lag`` did: each frame re-decided with the ``lag`` frames after it (or, in a run
    no longer than the lag, with every later frame)."""
    if frames and lag >= frames:
        return (f"{lag} scan(s), longer than the run's {frames} frame(s): each frame re-decided with "
                f"every frame after it, smoothed")
    return f"{lag} scan(s): each frame re-decided with the {lag} after it, smoothed"


def _p95(values: Sequence[float]) -> float:
    """The 95th percentile, linearly interpolated (``np.percentile``'s default)."""
    ordered = sorted(values)
    pos = 0.95 * (len(ordered) - 1)
    lo = math.floor(pos)
    hi = min(lo + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (pos - lo)


def final_tracks_text(n: int, names: Sequence[str], most: int = 12) -> str:
    """``8: T1.4 T9.4 ...``: the number of final tracks and their display names (the names
    the recording, the export and the Foxglove scene show), the first ``most`` of them."""
    if not names:
        return str(n)
    shown = " ".join(names[:most])
    return f"{n}: {shown}" + (f" (+{len(names) - most} more)" if len(names) > most else "")
