"""The Rerun recording as a :class:`sinks.sink.Sink` (the ``rerun`` entry of
:data:`sinks.sink.SINKS`): :class:`RerunRecordSink` opens a :class:`sinks.rerun_sink.RerunSink`
and logs each record that has an estimate, scored by the caller or here."""

from __future__ import annotations

from collections.abc import Mapping

from sinks.metrics import RunScorer
from sinks.rerun_sink import RerunSink
from sinks.sink import SinkOptions, SinkRecord

__all__ = ["RerunRecordSink"]


class RerunRecordSink:
    """Write the records to the ``.rrd`` file ``options.path`` (streamed to ``options.live``
    too, when given).  A record without frame or estimate draws nothing (the recording shows
    the run's frames with their tracks).  Records without ``scores`` are scored with a
    :class:`sinks.metrics.RunScorer` of the default OSPA / OSPA(2) settings."""

    def __init__(self, options: SinkOptions) -> None:
        self.options = options
        self.sink: RerunSink | None = None
        self._scorer = RunScorer()

    def open(self, metadata: Mapping[str, str] | None) -> None:
        o = self.options
        self.sink = RerunSink(o.path, recording_id=o.run_id, metadata=metadata or {}, params=o.params,
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
