"""The end of a sink stage's run: what ``tracks.mcap`` lacks and why, the outputs closed and
committed, and ``sink.json`` (:class:`~pipeline.stages.summary.RunSummary`) written after them
-- or, after a write error, the unfinished ``.part`` files removed.

:class:`SinkFinish` is a base class of :class:`~pipeline.stages.sink.SinkStage` and works on
its state: ``streams``, ``align``, ``sinks``, ``files``, ``counters``, ``intake``, ``tally``,
``latency``, ``eos_seen``, ``recovered``, ``restarted``, ``gone``.
"""

from __future__ import annotations

import logging
from typing import Any

from bnptrack.pipeline.stages.base import StageIOError, stop_reason
from bnptrack.pipeline.stages.health import missing_entries
from bnptrack.pipeline.stages.recovery import SUMMARY_NAME, commit_parts, sync_parts, write_atomic
from bnptrack.pipeline.stages.salvage import missing_tail
from bnptrack.pipeline.stages.summary import RunSummary

__all__ = ["SinkFinish"]

log = logging.getLogger("bnptrack.stage")


class SinkFinish:
    """Finalize a sink stage's outputs (see the module docstring)."""

    def _finalize_or_abandon(self, complete: bool) -> None:
        try:
            self._finalize(complete)
        except OSError as exc:
            self._abandon()
            if isinstance(exc, StageIOError):
                raise
            raise StageIOError(self.name, exc.filename or self.ctx.out / self.sink_cfg.mcap_name, exc) from None

    def _finalize(self, complete: bool) -> None:
        if not complete:
            # write what we have, in order: everything received so far, gaps for the holes
            self._open(force=True)
            top = max([self.align.next_write - 1] + [s.max_seen for s in self.streams.values()])
            for name, seq in self.streams.items():
                self._release(name, seq.flush_through(top))
            self._drain_ready()
        if self.sinks is not None:
            self.sinks.close()
        gaps = {name: list(seq.gaps) for name, seq in self.streams.items()}
        missing = self._missing(complete)
        src = self.eos_seen.get("source")
        summary = RunSummary(
            run=self.run_id,
            complete=complete,
            frames_written=self.frames_written,
            tracks_written=self.tracks_written,
            last_seq=self.align.next_write - 1,
            gaps=gaps,
            output_complete=not missing,  # incomplete: _missing lists every seq not written
            missing=missing,
            recovered_frames=self.recovered,
            source_error=src.error if src is not None else "",
            # the source's end of stream this sink ended on (the launcher checks it against the source's own)
            source_eos={"last_seq": src.last_seq, "frames": src.frames} if src is not None else None,
            counters=self.counters.as_dict(),
            restarted=self.restarted,  # the counters are this process's (an earlier one's are lost)
            rejected_by_topic=self.intake.rejected_by_topic,
            dropped=int(self.bus.dropped),
            zenoh_misses=int(self.bus.misses),
            files=self.files,
            scores=self.tally.totals(),
            view=self._view_command(),
            throughput_fps=self.latency.throughput_fps(),
            t_first_pub_ns=self.latency.t_first_pub_ns,
            t_last_recv_ns=self.latency.t_last_ns,
            latency=self.latency.as_dict(),
        )
        self.ctx.out.mkdir(parents=True, exist_ok=True)
        path = self.ctx.out / SUMMARY_NAME
        sync_parts(self.files)  # the outputs are on disk before the summary says they are done
        write_atomic(path, summary.encode())
        commit_parts(self.files)
        self.latency.discard()  # sink.json holds the timed frames now
        self.files.append(str(path))
        log.info("%s: wrote %d frame(s), %d /tracks message(s)%s to %s", self.name, self.frames_written,
                 self.tracks_written,
                 "" if not any(gaps.values()) else f", gaps {gaps}", ", ".join(self.files))

    def _missing(self, complete: bool) -> list[dict[str, Any]]:
        """What ``tracks.mcap`` lacks, and why (:func:`~pipeline.stages.health.missing_entries`);
        before the end of stream also every frame after the last one written."""
        tr = self.eos_seen.get("tracker")
        gaps = {name: seq.gaps for name, seq in self.streams.items()}
        return missing_entries(gaps, tr.rejected if tr is not None else (), self.align.rejected_seqs,
                               self.align.mismatched) + ([] if complete else self._missing_tail())

    def _missing_tail(self) -> list[dict[str, Any]]:
        """The frames after the last one written (up to the source's end of stream, when known)."""
        if self.gone:
            why = self.gone + (f" (recovered {self.recovered} frame(s), up to frame {self.align.last_frame}, from the "
                               "killed sink's .part file)" if self.recovered else "")
        else:
            why = f"not received: the sink was stopped ({stop_reason(self.ctx.stop) or 'by a signal'})"
        return missing_tail(self.streams, self.align.next_write, self.eos_seen.get("source"), why)
