"""The sink interface: what records a run (an MCAP log, a Rerun recording, ...).

A sink is opened once with the run's metadata, gets one :class:`SinkRecord` per frame in
frame order, and is closed once (:class:`Sink`).  :data:`SINKS` is the table of sinks by name;
:func:`make_sink` builds one from :class:`SinkOptions`, importing its module only then (the
Rerun sink needs rerun-sdk, which takes a second to import and may be absent).
:class:`SinkSet` feeds several sinks in order and closes all of them whatever happens.

Adding a sink: one module with a class that has ``open``/``write``/``close`` and takes
:class:`SinkOptions`, plus one entry in :data:`SINKS`.

This module imports neither rerun nor mcap.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from tracker.types import Estimate, Frame

__all__ = ["Sink", "SinkRecord", "Payloads", "SinkOptions", "SinkEntry", "SINKS", "make_sink", "SinkSet",
           "UnknownSink", "check_sink_names"]


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
    ``scores``: the frame's :meth:`sinks.metrics.RunScorer.update` result when the caller has
    scored it (``{"ospa": OspaResult | None, "ospa2": float | None}``); ``None``: a sink that
    draws scores computes them.  ``health``: pipeline counters at this frame (time series of
    the Rerun recording).  ``payloads``: the messages' bytes when the caller has them.
    """

    frame: Frame | None
    estimate: Estimate | None = None
    scores: Mapping[str, Any] | None = None
    health: Mapping[str, float] | None = None
    payloads: Payloads | None = None


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


@dataclass(frozen=True)
class SinkEntry:
    """A row of :data:`SINKS`: the factory (``"module:attribute"``, imported on use, or the
    callable itself) that takes :class:`SinkOptions` and returns a :class:`Sink`; what it
    writes; ``filename``: its file in a run's output directory (the pipeline's sink stage;
    ``bnptrack track`` writes it next to ``--out`` with this suffix); ``required``: a failure
    of the sink fails the run (else the pipeline's sink stage logs it and goes on without it)."""

    factory: str | Callable[[SinkOptions], Sink]
    writes: str = field(default="")
    filename: str = "run.out"
    required: bool = True
    imports: tuple[str, ...] = ()
    """Modules worth importing before a run starts (slow imports), when the sink is used."""
    decoded: bool = True
    """The sink reads a record's decoded ``frame``, ``estimate``, ``scores`` and ``health``;
    ``False``: it writes the record's ``payloads`` alone when the record carries them (the
    MCAP log), so a caller that has the payloads need not decode the frame for it."""

    def load(self) -> Callable[[SinkOptions], Sink]:
        if callable(self.factory):
            return self.factory
        module, _, attr = self.factory.partition(":")
        return getattr(importlib.import_module(module), attr)


class UnknownSink(KeyError):
    """A sink name that is not in :data:`SINKS`."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


#: The sinks by name.
SINKS: dict[str, SinkEntry] = {
    "mcap": SinkEntry("sinks.mcap_sink:McapSink", "the frames, truth and tracks as an MCAP log (tracks.mcap)",
                      "tracks.mcap", decoded=False),
    "rerun": SinkEntry("sinks.rerun_adapter:rerun_sink", "a Rerun recording (run.rrd; needs rerun-sdk)",
                       "run.rrd", required=False, imports=("sinks.rerun_sink",)),
}


def check_sink_names(names: Sequence[str], key: str, table: Mapping[str, SinkEntry] | None = None) -> None:
    """Raise :class:`ValueError` (one line naming ``key`` and the known sinks) unless every
    name in ``names`` is in ``table`` (default :data:`SINKS`) once."""
    table = SINKS if table is None else table
    for name in names:
        if name not in table:
            raise ValueError(f"{key}: unknown sink {name!r} (known: {', '.join(sorted(table))})")
    if len(set(names)) != len(names):
        raise ValueError(f"{key}: {list(names)!r} names a sink twice")


def make_sink(name: str, options: SinkOptions, table: Mapping[str, SinkEntry] | None = None) -> Sink:
    """The sink ``name`` of ``table`` (default :data:`SINKS`) built with ``options``; raises
    :class:`UnknownSink` naming the known sinks, :class:`ImportError` when its module (or what
    it needs, e.g. rerun-sdk) cannot be imported."""
    table = SINKS if table is None else table
    entry = table.get(name)
    if entry is None:
        raise UnknownSink(f"unknown sink {name!r} (known: {', '.join(sorted(table))})")
    return entry.load()(options)


class SinkSet:
    """Several sinks fed in order: ``open`` opens them in order (one that fails closes those
    already open, in reverse order, and the error propagates), ``write`` gives each record to
    each sink in order, ``close`` closes all of them in reverse order even when one fails (the
    first error propagates after all were tried; a set never opened closes every sink).  Use
    as a context manager."""

    def __init__(self, sinks: Sequence[Sink]) -> None:
        self.sinks = list(sinks)
        self._opened: list[Sink] = []
        self._opening = False
        self._closed = False

    def open(self, metadata: Mapping[str, str] | None) -> None:
        self._opening = True
        for sink in self.sinks:
            try:
                sink.open(metadata)
            except BaseException:
                self.close()
                raise
            self._opened.append(sink)

    def write(self, record: SinkRecord) -> None:
        for sink in self._opened:
            sink.write(record)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        first: BaseException | None = None
        # a set never opened closes all its sinks (what they hold from their construction,
        # e.g. a started child process, is released)
        for sink in reversed(self._opened if self._opening else self.sinks):
            try:
                sink.close()
            except BaseException as exc:  # close the others all the same
                first = first or exc
        if first is not None:
            raise first

    def __enter__(self) -> SinkSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
