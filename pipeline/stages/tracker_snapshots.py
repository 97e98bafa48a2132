"""The tracker stage's snapshots: its state, position and end of stream written atomically
(with its journal of ``/tracks``, to which each published sample is appended), read back when
the stage is restarted, and a restarted stage that had finished the run announcing its end
again; the fixed-lag window published at the end of the stream or when the stream
resynchronises after a jump (the tracker then starts afresh).

:class:`TrackerSnapshots` is a base class of :class:`~pipeline.stages.tracker.TrackerStage`
and works on its state: ``tc``, ``snap_path``, ``core``, ``tracker``, ``output``, ``state``, ``journal``,
``writer``, ``counters``, ``restored``, ``finished_eos``, ``since_snapshot``, ``clock`` and its
``_publish``.
"""

from __future__ import annotations

import logging

import msgspec

from bnptrack.pipeline.stages.base import EXIT_OK, StageIOError
from bnptrack.pipeline.stages.delivery import Sequencer
from bnptrack.pipeline.stages.recovery import Snapshot, read_snapshot
from bnptrack.pipeline.stages.tracker_output import WindowState, published_through
from bnptrack.tracker.config import ConfigError

__all__ = ["TrackerSnapshots"]

log = logging.getLogger("bnptrack.stage")


class TrackerSnapshots:
    """Snapshot and resume a tracker stage (see the module docstring)."""

    def _journal(self, records: list[tuple[int, bytes, dict]]) -> None:
        """Append published samples to the journal (after the state advanced)."""
        for s, payload, meta in records:
            try:
                self.journal.append(s, payload, meta)
            except OSError as exc:
                raise StageIOError(self.name, self.journal.path, exc) from None
            self.counters.published += 1

    def _flush_window(self) -> None:
        """At the end of the stream: publish the frames still in the fixed-lag window."""
        if self.output is None:
            return
        state, out = self.output.flush(self.state)
        if out:
            now = self.clock.time_ns()
            records = [self._publish(e, est, now, now) for e, est in out]
            self.state = state
            self._journal(records)

    def _new_segment(self) -> None:
        """The stream resynchronised after a jump (:class:`~tracker.types.FrameGate`): publish
        the frames still in the fixed-lag window, then start the tracker afresh."""
        self._flush_window()
        self.state = self.output.initial_state(self.tracker.initial_state())

    def _restore(self) -> list[tuple[int, bytes, dict]]:
        """Resume from the snapshot when there is one (and ``resume``), and open the journal
        cut back to it; returns its samples, which :meth:`run` publishes again."""
        if not self.tc.resume:
            self.journal.start()
            return []
        if self.snap_path.exists():
            self._apply_snapshot(read_snapshot(self.snap_path))
        restored = self.restored
        published = self.core.last_seq if restored is None or restored.published_seq is None \
            else restored.published_seq
        return self.journal.resume(published)

    def _apply_snapshot(self, snap: Snapshot) -> None:
        tc = self.tc
        if (snap.run, snap.tracker, snap.seed, snap.lag) != (self.run_id, tc.tracker, tc.seed, tc.lag):
            raise ConfigError(
                f"{self.snap_path}: snapshot of run {snap.run!r}, tracker {snap.tracker!r}, seed "
                f"{snap.seed}, lag {snap.lag} does not match this stage (run {self.run_id!r}, tracker "
                f"{tc.tracker!r}, seed {tc.seed}, lag {tc.lag}); delete it or set tracker.resume = false"
            )
        self.restored = snap
        seq = Sequencer.for_delivery(self.delivery, snap.last_seq + 1, "measurements", self.ask_head)
        seq.restore_gaps(snap.gaps)
        self.core.resume(seq, snap.last_seq, snap.last_frame, snap.last_stamp_ns, snap.rejected, snap.frame_gate)
        self.counters.gaps = len(snap.gaps)
        self.counters.processed = snap.counters.get("processed", 0)
        self.counters.restarts_resumed = snap.counters.get("restarts_resumed", 0) + 1
        self.finished_eos = snap.eos
        log.info("%s: resuming from %s (after seq %d, frame %d)", self.name, self.snap_path,
                 snap.last_seq, snap.last_frame)

    def snapshot(self, wait: bool = False) -> None:
        """Snapshot the state (written in the background; ``wait``: until it is on disk)."""
        if self.tracker is None or self.state is None:
            return
        core = self.core
        entries = self.state.entries if isinstance(self.state, WindowState) else ()
        snap = Snapshot(
            run=self.run_id, tracker=self.tc.tracker, seed=self.tc.seed, last_seq=core.last_seq,
            last_frame=core.last_frame, state=self.output.snapshot(self.state), gaps=list(core.seq.gaps),
            lag=self.tc.lag, published_seq=published_through(core.last_seq, entries),
            last_stamp_ns=core.last_stamp_ns, rejected=list(core.rejected_seqs), frame_gate=core.gate_state(),
            counters={"processed": self.counters.processed,
                      "restarts_resumed": self.counters.restarts_resumed},
            time_ns=self.clock.time_ns(), eos=self.finished_eos,
        )
        try:
            self.ctx.out.mkdir(parents=True, exist_ok=True)
            fd = self.journal.dup_fd()
            self.writer.submit(self.snap_path, msgspec.msgpack.encode(snap), () if fd is None else (fd,))
            self.since_snapshot = 0
            if wait:
                self.writer.flush()
        except OSError as exc:
            raise StageIOError(self.name, self.snap_path, exc) from None

    def _close_journal(self) -> None:
        """Close the journal; a failing final write names the journal (not an anonymous OSError)."""
        try:
            self.journal.close()
        except OSError as exc:
            raise StageIOError(self.name, self.journal.path, exc) from None

    def _end_again(self) -> int:
        """A tracker restarted after it finished: its journal is in the cache again; announce
        the end of stream again and serve until the sink is done (or nobody is left)."""
        log.info("%s: the snapshot records the finished run (last seq %d): announcing its end again",
                 self.name, self.finished_eos.last_seq)
        self.bus.subscribe(["eos/*"])
        self.bus.declare_alive()
        self.publish_control("eos", self.finished_eos)
        try:
            self.serve_until_done_or_alone(self.tc.done_by)
        finally:
            self._close_journal()
        return EXIT_OK
