"""The Rerun recording as a :class:`sinks.sink.Sink` (the ``rerun`` entry of
:data:`sinks.sink.SINKS`): :func:`rerun_sink` gives a :class:`RerunRecordSink`, which opens a
:class:`sinks.rerun_sink.RerunSink` in this process and logs each record that has an
estimate, scored by the caller or here, or with ``SinkOptions.process`` a
:class:`sinks.rerun_process.ProcessRecordSink` (the same recording written by a child
process).  This module imports rerun only when a :class:`RerunRecordSink` opens."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from bnptrack.sinks.run_scorer import RunScorer
from bnptrack.sinks.records import Sink, SinkOptions, SinkRecord

__all__ = ["RerunRecordSink", "rerun_sink"]


def rerun_sink(options: SinkOptions) -> Sink:
    """The Rerun sink for ``options``: in a child process when ``options.process``."""
    if options.process:
        from bnptrack.sinks.rerun_process import ProcessRecordSink

        return ProcessRecordSink(options)
    return RerunRecordSink(options)


class RerunRecordSink:
    """Write the records to the ``.rrd`` file ``options.path`` (streamed to ``options.live``
    too, when given).  A record without frame or estimate draws nothing (the recording shows
    the run's frames with their tracks).  Records without ``scores`` are scored with a
    :class:`sinks.run_scorer.RunScorer` of the default OSPA / OSPA(2) settings."""

    def __init__(self, options: SinkOptions) -> None:
        self.options = options
        self.sink: Any = None
        self._scorer = RunScorer()

    def open(self, metadata: Mapping[str, str] | None) -> None:
        from bnptrack.sinks.rerun_sink import RerunSink  # imports rerun

        o = self.options.now()
        meta = dict(metadata or {})
        if o.source is not None:
            meta["source_log"] = o.source
        self.sink = RerunSink(o.path, recording_id=o.run_id, metadata=meta, params=o.params,
                              handle_signals=o.handle_signals, live=o.live)

    def write(self, record: SinkRecord) -> None:
        if self.sink is None:
            raise RuntimeError(f"RerunRecordSink({self.options.path}) is not open")
        frame, est = record.frame, record.estimate
        if frame is None or est is None:
            return
        scores = record.scores if record.scores is not None else self._scorer.update(frame, est)
        self.sink.log(frame, est, ospa=scores.get("ospa"), ospa2=scores.get("ospa2"), health=record.health)

    def close(self) -> None:
        if self.sink is not None:
            self.sink.close()
