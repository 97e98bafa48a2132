"""The sink stage's recording side: the sinks it opens (the ``[sink]`` section's entries of
:data:`sinks.sink.SINKS`, on ``.part`` files, with the run's metadata and model parameters),
one frame written to them, and what is removed when a write fails.

:class:`SinkWriting` is a base class of :class:`~pipeline.stages.sink.SinkStage` and works on
its state: ``sink_cfg``, ``infos``, ``sinks``, ``files``, ``decode``, ``scorer``, ``tally``,
``latency``, the counts ``frames_written`` / ``tracks_written`` and ``counters``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from bnptrack.tracker.messages import to_estimate, to_frame, to_truth
from bnptrack.pipeline.output_paths import view_command
from bnptrack.pipeline.stages.base import StageIOError, settle_heap
from bnptrack.pipeline.stages.delivery import GAP, NO_TRUTH, Accepted
from bnptrack.pipeline.stages.health import StageInfo
from bnptrack.pipeline.stages.recovery import part_path
from bnptrack.sinks.records import Payloads, Sink, SinkOptions, SinkRecord
from bnptrack.sinks.sink import SINKS, OptionalSink, SinkSet, make_sink

__all__ = ["SinkWriting"]

log = logging.getLogger("bnptrack.stage")

_NO_SCORES: dict[str, Any] = {"ospa": None, "ospa2": None}


class SinkWriting:
    """Open the sinks and write frames to them (see the module docstring)."""

    def _metadata(self) -> tuple[bool, dict[str, str] | None]:
        """(known, metadata): the tracker's output record (or the source's when there is
        no tracker stream)."""
        if self.sink_cfg.tracks:
            info = self.infos.get("tracker")
        else:
            info = self.infos.get("source")
        if info is None:
            return False, None
        meta = dict(info.metadata) if info.metadata is not None else None
        if meta is not None:
            meta.setdefault("run", self.run_id)
        return True, meta

    def _open(self, force: bool = False, meta_if_unknown: dict[str, str] | None = None) -> bool:
        if self.sinks is not None:
            return True
        known, meta = self._metadata()
        if not known and not force:
            return False
        meta = meta if known else meta_if_unknown
        out = self.ctx.out
        out.mkdir(parents=True, exist_ok=True)
        built: list[tuple[str, Sink]] = []
        params = self._params(meta, self.infos.get("tracker"))
        for name, path in self.sink_cfg.paths(out).items():
            sink = self._make_sink(name, path, params)
            if sink is not None:
                built.append((str(path), sink))
        self.sinks = SinkSet([sink for _, sink in built])
        self.files += [f for f, _ in built]  # their .part files are removed if the run is abandoned
        self.sinks.open(meta if meta is not None else {"run": self.run_id})
        failed = {f for f, sink in built if getattr(sink, "failed", False)}
        self.files = [f for f in self.files if f not in failed]
        settle_heap()
        self.bus.declare_alive("ready")
        return True

    def _make_sink(self, name: str, path: Path, params: Any) -> Sink | None:
        """The sink ``name`` of :data:`sinks.sink.SINKS` writing ``path``'s ``.part`` file
        (``None``: an optional sink that cannot be built here, e.g. without rerun-sdk)."""
        entry = SINKS[name]
        options = SinkOptions(part_path(path), params=params, run_id=self.run_id,
                              live=self.sink_cfg.view_url or None)
        try:
            sink = make_sink(name, options)
        except Exception as exc:
            if entry.required:
                raise
            log.info("%s: the %s sink is not available (%s): no %s", self.name, name, exc, path.name)
            return None
        return sink if entry.required else OptionalSink(sink, f"{self.name}: {name} sink ({path.name})")

    @staticmethod
    def _params(meta: dict[str, str] | None, tracker_info: StageInfo | None) -> Any:
        """The run's model parameters, for a sink that draws the sensor's field of view:
        :func:`pipeline.resolve.run_params` of the tracker's announced ones."""
        from bnptrack.pipeline.resolve import run_params

        return run_params(meta, tracker_info.params if tracker_info is not None else None)

    def _write(self, s: int, meas: Any, truth: Any, tracks: Any) -> None:
        try:
            self._write_frame(s, meas, truth, tracks)
        except OSError as exc:
            raise StageIOError(self.name, self.ctx.out / self.sink_cfg.mcap_name, exc) from None

    def _write_frame(self, s: int, meas: Any, truth: Any, tracks: Any) -> None:
        """Record frame ``s`` to every sink: the payloads as received (they were validated on
        receipt, and they are the codec's bytes: the MCAP log stores them without decoding to
        numpy and re-encoding), and, when a consumer wants them (:attr:`decode`), the frame
        and estimate decoded, the scores and the health counters."""
        truth = truth if truth is not GAP and truth is not NO_TRUTH else None
        tracks = tracks if tracks is not GAP else None
        if meas is not GAP:
            self.frames_written += 1
        if tracks is not None:
            self.tracks_written += 1
            self._note_latency(s, tracks, meas)
        if meas is GAP and tracks is None:  # a gap in every stream: nothing to record
            return
        payloads = self._payloads(meas, truth, tracks)
        if not self.decode:  # the payloads are all the sinks read; the tally counts the tracks
            if meas is not GAP and tracks is not None:
                self.tally.count([t.label for t in tracks.msg.tracks])
            self.sinks.write(SinkRecord(None, payloads=payloads))
            return
        frame = to_frame(meas.msg, to_truth(truth.msg) if truth is not None else None) if meas is not GAP else None
        est = to_estimate(tracks.msg) if tracks is not None else None
        scores = None
        if frame is not None and est is not None:
            # scored always (progress, sink.json); drawn by the Rerun sink
            scores = self.scorer.update(frame, est) if self.sink_cfg.score or self.sink_cfg.rerun else _NO_SCORES
            self.tally.add(frame, est, scores)
        self.sinks.write(SinkRecord(frame, est, scores, self._health_scalars(), payloads))

    @staticmethod
    def _payloads(meas: Any, truth: Any, tracks: Any) -> Payloads:
        """The frame's messages as received (``meas`` may be :data:`GAP`, then the tracks
        alone are recorded with their own stamp)."""
        m = meas.msg if meas is not GAP else tracks.msg
        t_stamp = tracks.msg.stamp_ns if tracks is not None else None
        return Payloads(m.stamp_ns, m.frame, meas.payload if meas is not GAP else None,
                        truth.payload if truth is not None else None,
                        tracks.payload if tracks is not None else None,
                        t_stamp if t_stamp != m.stamp_ns else None)

    def _note_latency(self, s: int, tracks: Accepted, meas: Any = GAP) -> None:
        """Per-frame latencies of a written ``/tracks`` (for sink.json and health): timed
        when first delivered to this process (:class:`~pipeline.stages.sink_latency.LatencyBook`)."""
        self.latency.note(s, tracks, meas if meas is not GAP else None)

    def _health_scalars(self) -> dict[str, float]:
        c = self.counters
        out = {"received": c.received, "accepted": c.accepted, "rejected": c.rejected,
               "duplicates": c.duplicates, "late": c.late, "gaps": c.gaps,
               "dropped": float(self.bus.dropped)}
        if self.latency.last_ms is not None:
            out["latency_ms"] = self.latency.last_ms
        return {k: float(v) for k, v in out.items()}

    def _abandon(self) -> None:
        """After a write error (disk full): close what is open, ignoring further errors, and
        remove the unfinished ``.part`` files (no temporary file is left behind)."""
        sinks = self.sinks
        try:
            if sinks is not None:
                sinks.close()
        except Exception:  # the disk is full: nothing more can be written
            pass
        for f in self.files:
            part_path(f).unlink(missing_ok=True)
        self.latency.discard()

    def _view_command(self) -> str:
        """The command that opens the recording (``""``: no ``run.rrd`` was written)."""
        rrd = self.ctx.out / self.sink_cfg.rrd_name
        return view_command(rrd) if str(rrd) in self.files else ""
