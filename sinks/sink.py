"""The sink interface: what records a run (an MCAP log, a Rerun recording, ...).

A sink is opened once with the run's metadata, gets one
:class:`~sinks.records.SinkRecord` per frame in frame order, and is closed once
(:class:`~sinks.records.Sink`, in :mod:`sinks.records`).  :data:`SINKS` is the table of sinks by name;
:func:`make_sink` builds one from :class:`SinkOptions`, importing its module only then (the
Rerun sink needs rerun-sdk, which takes a second to import and may be absent).
:class:`SinkSet` feeds several sinks in order and closes all of them whatever happens.

Adding a sink: one module with a class that has ``open``/``write``/``close`` and takes
:class:`~sinks.records.SinkOptions`, plus one entry in :data:`SINKS`.

This module imports neither rerun nor mcap.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any
from dataclasses import dataclass, field

from bnptrack.sinks.records import Sink, SinkOptions, SinkRecord

__all__ = ["SinkEntry", "SINKS", "TRACKS_NAME", "RRD_NAME", "make_sink", "SinkSet", "OptionalSink", "UnknownSink", "check_sink_names"]

log = logging.getLogger("bnptrack.sink")


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
    """Modules worth importing before a run starts (slow imports, the sink's own and what its
    first ``open`` imports), when the sink is used."""
    decoded: bool = True
    """The sink reads a record's decoded ``frame``, ``estimate``, ``scores`` and ``health``;
    ``False``: it writes the record's ``payloads`` alone when the record carries them (the
    MCAP log), so a caller that has the payloads need not decode the frame for it."""

    beside: str | None = None
    """The sink whose file this one writes into when both are in a run (its own channel beside
    the other's: the ``foxglove`` scene in the ``mcap`` log); the same file is then no clash."""

    def load(self) -> Callable[[SinkOptions], Sink]:
        if callable(self.factory):
            return self.factory
        module, _, attr = self.factory.partition(":")
        return getattr(importlib.import_module(module), attr)


class UnknownSink(KeyError):
    """A sink name that is not in :data:`SINKS`."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


#: The output files of the MCAP and Rerun sinks.
TRACKS_NAME = "tracks.mcap"
RRD_NAME = "run.rrd"

#: The sinks by name.
SINKS: dict[str, SinkEntry] = {
    "mcap": SinkEntry("bnptrack.sinks.mcap_sink:McapSink", "the frames, truth and tracks as an MCAP log (tracks.mcap)",
                      TRACKS_NAME, decoded=False, imports=("bnptrack.sinks.mcap_writer",)),
    "rerun": SinkEntry("bnptrack.sinks.rerun_adapter:rerun_sink", "a Rerun recording (run.rrd; needs rerun-sdk)",
                       RRD_NAME, required=False,
                       imports=("bnptrack.sinks.rerun_adapter", "bnptrack.sinks.rerun_sink", "pyarrow.compute", "numpy.ma",
                                "dateutil.relativedelta")),
    "foxglove": SinkEntry("bnptrack.sinks.foxglove_sink:FoxgloveSceneSink",
                          "the tracks as foxglove.SceneUpdate messages (/tracks/scene) in the MCAP log",
                          TRACKS_NAME, required=False, beside="mcap"),
}
# ``imports`` include what a sink's first ``open`` imports (mcap.writer's importlib.metadata;
# pyarrow.compute, numpy.ma and dateutil, which the Rerun SDK imports on its first annotation
# context and scalar): the pipeline's sink stage imports them while the tracker starts, not
# between the tracker's readiness and the first frame (0.3-0.5 s there on a loaded machine;
# docs/pipeline.md, "Latency")


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


@contextlib.contextmanager
def _naming(sink: Any) -> Iterator[None]:
    """An OSError of ``sink`` without a file name (a write to an open file: disk full, I/O
    error) gets the sink's file (``options.path``), so that the error names it."""
    try:
        yield
    except OSError as exc:
        path = getattr(getattr(sink, "options", None), "path", None)
        if exc.filename is not None or path is None or exc.errno is None:
            raise
        raise type(exc)(exc.errno, exc.strerror or str(exc), str(path)) from exc


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
                with _naming(sink):
                    sink.open(metadata)
            except BaseException:
                self.close()
                raise
            self._opened.append(sink)

    def write(self, record: SinkRecord) -> None:
        for sink in self._opened:
            with _naming(sink):
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
                with _naming(sink):
                    sink.close()
            except BaseException as exc:  # close the others all the same
                first = first or exc
        if first is not None:
            raise first

    def __enter__(self) -> SinkSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class OptionalSink:
    """A sink whose failure must not end the recording (an entry of :data:`SINKS` that is not
    ``required``: the Rerun recording): its first error is logged (``what`` names it) and the
    sink is dropped (``failed``)."""

    def __init__(self, sink: Sink, what: str) -> None:
        self.sink, self.what, self.failed = sink, what, False

    def _guard(self, call: Any, *args: Any) -> None:
        if self.failed:
            return
        try:
            call(*args)
        except Exception as exc:  # a viewer file must not end the recording
            log.error("%s failed, disabling it: %s", self.what, exc)
            self.failed = True
            try:
                self.sink.close()
            except Exception:
                pass

    def open(self, metadata: Any) -> None:
        self._guard(self.sink.open, metadata)

    def write(self, record: SinkRecord) -> None:
        self._guard(self.sink.write, record)

    def close(self) -> None:
        if not self.failed:
            try:
                self.sink.close()
            except Exception as exc:
                log.error("%s: closing it: %s", self.what, exc)
