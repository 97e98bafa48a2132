"""The sink stage after a restart: an earlier sink process of the run left its outputs.  A
complete run is announced again and never reopened; an incomplete one is kept, or the frames
the killed process wrote to its ``.part`` file are recorded again.

:class:`SinkRestart` is a base class of :class:`~pipeline.stages.sink.SinkStage` and works on
its state: ``earlier``, ``sink_cfg``, ``streams``, ``align``, ``recovered``, ``gone``.
"""

from __future__ import annotations

import logging

from bnptrack.pipeline.stages.base import EXIT_OK
from bnptrack.pipeline.stages.health import EndOfStream
from bnptrack.pipeline.stages.recovery import SUMMARY_NAME, commit_parts, part_path
from bnptrack.pipeline.stages.salvage import UpstreamGone, salvage_part
from bnptrack.pipeline.stages.summary import RunSummary
from bnptrack.pipeline.stages.sink_latency import LATENCY_PART

__all__ = ["SinkRestart"]

log = logging.getLogger("bnptrack.stage")


class SinkRestart:
    """What a restarted sink does with an earlier process's outputs (see the module docstring)."""

    def _end_again(self, summary: RunSummary) -> int:
        """Announce the recorded end of stream again (for stages still waiting for it)."""
        commit_parts(summary.files)  # killed between sink.json and the renames
        (self.ctx.out / LATENCY_PART).unlink(missing_ok=True)  # ... or before the timings' removal
        log.info("%s: %s already records the complete run (%d frame(s)); not reopening it",
                 self.name, self.ctx.out / SUMMARY_NAME, summary.frames_written)
        self.bus.subscribe(["eos/*"])
        self.bus.declare([f"eos/{self.name}"])
        self.bus.declare_alive()
        self.publish_control("eos", EndOfStream(
            stage=self.name, run=self.run_id, last_seq=summary.last_seq, frames=summary.frames_written,
            gaps=summary.all_gaps(), error=summary.source_error, files=list(summary.files)))
        self.linger_until_alone(self.cfg.supervisor.linger_s, at_least=1.0)
        return EXIT_OK

    def _restarted(self) -> bool:
        """Whether an earlier sink process of this run left its outputs (finished or not) here."""
        return self.earlier is not None or any(part_path(p).exists() for p in self.sink_cfg.paths(self.ctx.out).values())

    def _recover(self, outcome: str) -> str:
        """Keep an earlier finished output, or write the frames the killed sink process had
        written to its ``.part`` file (read before anything reopens it), as if received:
        every sink gets them again."""
        if self.earlier is not None:
            commit_parts(self.earlier.files)  # killed between sink.json and the renames
            log.info("%s: %s already records %d frame(s) of this run (output incomplete); keeping it",
                     self.name, self.ctx.out / SUMMARY_NAME, self.earlier.frames_written)
            return "kept"
        found = salvage_part(part_path(self.ctx.out / self.sink_cfg.mcap_name), self.run_id)
        if (found is None or not found.frames) and outcome == "alone":
            raise UpstreamGone(f"stage {self.name}: run {self.run_id}: {self.gone}, and nothing to recover "
                               f"(no readable frame in {part_path(self.ctx.out / self.sink_cfg.mcap_name)}): "
                               "nothing written")
        if found is None or not found.frames:
            return outcome
        self._open(force=True, meta_if_unknown=found.metadata)
        for s, f in enumerate(found.frames):
            self._write(s, *f.items(s, self.sink_cfg.tracks))
        self.recovered = len(found.frames)
        last = found.frames[-1]
        self.align.restart_at(self.recovered, last.frame, last.stamp_ns)
        self.streams = self._sequencers(self.align.next_write, list(self.streams))
        log.info("%s: recovered %d frame(s) (up to frame %d) from the killed sink's .part file", self.name,
                 self.recovered, self.align.last_frame)
        return outcome
