"""The MCAP log as a :class:`sinks.sink.Sink` (the ``mcap`` entry of :data:`sinks.sink.SINKS`):
:class:`McapSink` writes ``/measurements``, ``/truth`` and ``/tracks`` of each record, as the
pipeline's sink stage and ``bnptrack track`` write them (and, for a lagged run, the online
estimates to ``/tracks_online``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from bnptrack.sinks.records import SinkOptions, SinkRecord

__all__ = ["McapSink"]


class McapSink:
    """Write the records to the MCAP file ``options.path`` with the run's metadata as its
    ``bnptrack.scenario`` record (none without metadata).  A record with :attr:`SinkRecord.payloads` is written as
    those bytes (no re-encoding); otherwise its frame and estimate are encoded.  The frame
    (when present) comes before the tracks, as in every bnptrack log."""

    def __init__(self, options: SinkOptions) -> None:
        self.options = options
        self.writer: Any = None

    def open(self, metadata: Mapping[str, str] | None) -> None:
        from bnptrack.sinks.mcap_writer import McapLogWriter

        self.options.path.parent.mkdir(parents=True, exist_ok=True)
        self.writer = McapLogWriter(self.options.path, dict(metadata) if metadata is not None else None)

    def write(self, record: SinkRecord) -> None:
        w = self.writer
        if w is None:
            raise RuntimeError(f"McapSink({self.options.path}) is not open")
        p = record.payloads
        if p is not None:
            if p.measurements is not None:
                w.write_encoded_frame(p.measurements, p.truth, p.stamp_ns, p.frame)
            if p.tracks is not None:
                w.write_encoded_tracks(p.tracks, p.stamp_ns if p.tracks_stamp_ns is None else p.tracks_stamp_ns,
                                       p.frame)
            return
        if record.frame is not None:
            w.write_frame(record.frame)
        if record.estimate is not None:
            w.write_tracks(record.estimate)
        if record.online is not None:
            w.write_online_tracks(record.online)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
