"""What a sink receives: the :class:`Sink` protocol, one frame's :class:`SinkRecord` (with
the messages' bytes, :class:`Payloads`) and where it writes (:class:`SinkOptions`).  The table
of sinks is :mod:`sinks.sink`; a sink module imports only this one, so the table can name
the sink modules without an import cycle."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from bnptrack.tracker.types import Estimate, Frame

__all__ = ["Sink", "SinkRecord", "Payloads", "SinkOptions"]


@dataclass(frozen=True, slots=True)
class Payloads:
    """A frame's messages as the codec's bytes (``tracker.messages``), as
    received and validated: a sink that stores messages writes them as they are, without
    decoding to numpy and encoding again (the pipeline's sink stage).  ``truth`` / ``tracks``
    are ``None`` when the frame has none; ``tracks_stamp_ns``: the ``/tracks`` message's own
    stamp when it is not ``stamp_ns``."""

    stamp_ns: int
    frame: int
    measurements: bytes | None
    truth: bytes | None = None
    tracks: bytes | None = None
    tracks_stamp_ns: int | None = None


@dataclass(frozen=True, slots=True)
class SinkRecord:
    """One frame of a run, as every sink gets it.

    ``frame``: the measurements (and truth) of the frame, ``None`` when they were lost
    upstream (a gap in the pipeline: the tracks alone are recorded).  ``estimate``: the
    tracker's output for the frame, ``None`` when there is none (a log without tracker).
    ``scores``: the frame's :meth:`sinks.run_scorer.RunScorer.update` result when the caller has
    scored it (``{"ospa": OspaResult | None, "ospa2": float | None}``); ``None``: a sink that
    draws scores computes them.  ``health``: pipeline counters at this frame (time series of
    the Rerun recording).  ``payloads``: the messages' bytes when the caller has them.
    ``online``: with a lagged ``estimate`` (``bnptrack track --lag``), the tracker's online
    estimate of the same frame (the MCAP sink writes it to ``/tracks_online``).
    """

    frame: Frame | None
    estimate: Estimate | None = None
    scores: Mapping[str, Any] | None = None
    health: Mapping[str, float] | None = None
    payloads: Payloads | None = None
    online: Estimate | None = None


@runtime_checkable
class Sink(Protocol):
    """What records a run.

    ``open(metadata)`` once before any record (the run's description: scenario, params,
    tracker, seed, ...; ``None``: a run without one), ``write(record)`` once per frame in frame order, ``close()`` once at
    the end (idempotent; the file is complete when it returns).
    """

    def open(self, metadata: Mapping[str, str] | None) -> None: ...

    def write(self, record: SinkRecord) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class SinkOptions:
    """Where and how a sink writes: ``path`` (its file), ``params`` (the run's
    :class:`tracker.models.params.ModelParams`, for a sink that draws the sensor's field of
    view), ``run_id`` (the recording id), ``live`` (a Rerun viewer URL to stream to as well;
    ``params`` and ``live`` may be callables that give them at ``open``: :meth:`now`),
    ``handle_signals`` (finish the file at SIGTERM/SIGINT; main thread only), ``process``
    (write in a child process, off the caller's critical path, when the sink can: the Rerun
    sink, :mod:`sinks.rerun_process`; its construction then starts the child), ``source``
    (the input log the run reads, for a sink that notes it: the Rerun recording's
    ``source_log``)."""

    path: Path
    params: Any = None
    run_id: str | None = None
    live: Any = None
    handle_signals: bool = False
    process: bool = False
    source: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    def now(self) -> SinkOptions:
        """These options with ``params`` and ``live`` called when they are callables (a caller
        that builds its sinks before it knows them: a sink calls this in ``open``)."""
        late = {k: v() for k in ("params", "live") if callable(v := getattr(self, k))}
        return replace(self, **late) if late else self
