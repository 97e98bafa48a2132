"""The sink stage: record the run (``tracks.mcap``, ``run.rrd``, ``sink.json``) from the
``measurements``, ``truth`` and ``tracks`` streams, frame by frame in sequence order."""

from __future__ import annotations

import logging
from typing import Any

from bnptrack.pipeline.stages.base import (EXIT_DATA, EXIT_OK, EXIT_STOPPED, StageBase, StageContext, StageIOError, warm_imports)
from bnptrack.pipeline.stages.delivery import (FETCH_AFTER_S, NO_TRUTH, HeadAsk, HoleWatch, Intake, RepeatLog,
                                              Sequencer, end_gaps_due, fetch_holes, publisher_copy, resolve_conflict,
                                              settle_holes)
from bnptrack.pipeline.stages.health import EndOfStream
from bnptrack.pipeline.stages.recovery import SUMMARY_NAME
from bnptrack.pipeline.stages.salvage import UpstreamGone, UpstreamWatch
from bnptrack.pipeline.stages.summary import RunSummary, read_summary
from bnptrack.pipeline.stages.sink_align import FrameAligner, Reject, Verify, Write
from bnptrack.pipeline.stages.sink_latency import LATENCY_PART, LatencyBook
from bnptrack.pipeline.stages.sink_finish import SinkFinish
from bnptrack.pipeline.stages.sink_restart import SinkRestart
from bnptrack.pipeline.stages.sink_write import SinkWriting
from bnptrack.sinks.sink import SINKS, SinkSet
from bnptrack.tracker.types import FrameBounds

__all__ = ["SinkStage"]

log = logging.getLogger("bnptrack.stage")


class SinkStage(SinkWriting, SinkFinish, SinkRestart, StageBase):
    """Record the run: each frame, in order, to the sinks the ``[sink]`` section chooses
    (:meth:`pipeline.config.SinkConfig.paths`: ``<out>/tracks.mcap`` with ``/measurements``,
    ``/truth``, ``/tracks`` like ``bnptrack track``; ``<out>/run.rrd`` when the Rerun sink is
    available; more entries of :data:`sinks.sink.SINKS` by ``sink.outputs``), written as
    ``.part`` files until the end, and ``<out>/sink.json`` (counts, gaps, latency).  A sink
    whose entry is not ``required`` (Rerun) is dropped, logged, when it fails.  Duplicate
    frames (e.g. ``/tracks`` re-published by a restarted tracker) are dropped."""

    role = "sink"

    def __init__(self, ctx: StageContext) -> None:
        super().__init__(ctx)
        self.sink_cfg = self.cfg.sink
        d = self.delivery
        self.intake = Intake(self.name, self.run_id, self.bus, self.counters, d.max_payload_bytes,
                             time_ns=self.clock.time_ns)
        # the truth shares the measurements' seq (a frame without truth has none): their head
        source_head = HeadAsk(self.bus, "measurements", self.clock.monotonic)
        self.heads = {"measurements": source_head, "truth": source_head,
                      "tracks": HeadAsk(self.bus, "tracks", self.clock.monotonic)}
        self.gap_log = RepeatLog()
        self.streams: dict[str, Sequencer] = self._sequencers(0, ["measurements", "truth"]
                                                              + (["tracks"] if self.sink_cfg.tracks else []))
        self.holes = {k: HoleWatch(FETCH_AFTER_S, self.clock.monotonic) for k in self.streams}
        self.progress: dict[str, float] = {k: self.clock.monotonic() for k in self.streams}
        self.sinks: SinkSet | None = None
        from bnptrack.sinks.run_scorer import RunScorer, ScoreTally

        self.scorer = RunScorer()
        #: decode each frame (numpy arrays, scores, health counters) only for a consumer: the
        #: scores (``sink.score``) or a sink that reads decoded records (``SinkEntry.decoded``)
        self.decode = self.sink_cfg.score or any(SINKS[n].decoded for n in self.sink_cfg.paths(self.ctx.out))
        self.tally = ScoreTally()
        self.frames_written = 0
        self.tracks_written = 0
        self.latency = LatencyBook(self.counters.latency_ms)  # the timed frames (first deliveries)
        self.files: list[str] = []
        self.held: list[tuple[int, Any, Any, Any]] = []
        #: the pure core: which frames to record, in order (:mod:`pipeline.stages.sink_align`)
        self.align = FrameAligner(self.streams, FrameBounds(d.max_frame_gap, d.max_gap_s, d.resync_frames))
        self.upstream_marked: set[str] = set()  # streams given the gaps their upstream stage reported
        self.t_first_ns: int | None = None
        self.alone: UpstreamWatch | None = None  # set when restarted: the rule for an upstream gone
        self.gone = ""  # why the sink stopped waiting (the upstream was gone)
        self.recovered = 0  # frames recovered from the earlier process's .part file
        self.earlier: RunSummary | None = None  # the sink.json an earlier process of this run wrote
        self.restarted = False  # an earlier sink process of this run left outputs: counters are ours only

    def _sink_health(self) -> dict:
        """The sink's part of its health message: what the launcher's progress line shows
        (frames written, the newest frame seen, the last frame's latency, the scores)."""
        seen = self.streams["measurements"].max_seen
        return {"frames_written": self.frames_written, "next_seq": self.align.next_write,
                "max_seq_seen": seen, "last_latency_ms": self.latency.last_ms,
                "scores": self.tally.as_dict()}

    def _drain_ready(self) -> None:
        """Write every frame for which each stream has released its item (or a gap)."""
        if not self._open():
            return
        acts = self.align.drain()
        while acts and isinstance(acts[-1], Verify):  # open mode: the publisher's own copy of the seq
            v = acts.pop()
            self._carry_out(acts)
            self.align.verified(v.seq, publisher_copy(self.bus, "measurements", v.meas, self.intake.check))
            acts = self.align.drain()
        self._carry_out(acts)

    def _carry_out(self, acts: list) -> None:
        for act in acts:
            if isinstance(act, Write):
                self._write(act.seq, act.meas, act.truth, act.tracks)
            elif isinstance(act, Reject):
                self.intake.reject_sample("measurements", act.payload, act.seq, act.why)
            else:
                log.error("%s: seq %d: /%s is for frame %d but /measurements is frame %d; dropping the %s",
                          self.name, act.seq, act.stream, act.frame, act.meas_frame, act.stream)
                self.counters.rejected += 1

    # -- intake ------------------------------------------------------------------------
    def _release(self, stream: str, released: list[tuple[int, Any]]) -> None:
        for s in self.align.release(stream, released):
            self.counters.gaps += 1
            self.gap_log.warning("%s: %s of frame seq %d is missing: recorded as a gap", self.name, stream, s)

    def _push(self, stream: str, seq: int, item: Any) -> None:
        status, released = self.streams[stream].push(seq, item)
        if status == "accepted":
            if item is not NO_TRUTH:
                self.counters.accepted += 1
            self.progress[stream] = self.clock.monotonic()
        elif status == "duplicate":
            if item is not NO_TRUTH:
                self.counters.duplicates += 1
        elif status in ("far", "ahead"):
            if item is not NO_TRUTH:
                self.intake.reject_sample(stream, item.payload, seq, self.streams[stream].far_reason(seq))
        elif status == "conflict":
            self.counters.duplicates += 1
            resolve_conflict(self.bus, stream, self.streams[stream], seq, self.intake.check)
        else:
            self.counters.late += 1
            self.gap_log.warning("%s: %s seq %d arrived after its gap was declared: rejected", self.name, stream, seq)
        self._release(stream, released)

    def _on_data(self, ev: Any) -> None:
        if ev.topic not in self.streams:
            return
        self.counters.received += 1
        acc = self.intake.check(ev)
        if acc is None:
            return
        if self.t_first_ns is None:
            self.t_first_ns = acc.t_recv_ns
        self._push(ev.topic, acc.seq, acc)
        if ev.topic == "measurements" and acc.meta.get("truth") is False:
            self._push("truth", acc.seq, NO_TRUTH)

    # -- completion --------------------------------------------------------------------
    def _check_end(self) -> bool:
        """True when everything up to the end of stream is released and written."""
        src = self.eos_seen.get("source")
        if src is None:
            return False
        last = src.last_seq
        now = self.clock.monotonic()
        grace = self.delivery.eos_grace_s
        done = True
        for name, seq in self.streams.items():
            upstream = "source"
            if name == "tracks":
                upstream = "tracker"
                tr = self.eos_seen.get("tracker")
                if tr is None:
                    done = False
                    continue
                if (tr.gaps or tr.rejected) and name not in self.upstream_marked:
                    self._release(name, seq.mark_gaps([*tr.gaps, *tr.rejected]))
                    self.upstream_marked.add(name)
                end = tr.last_seq
            else:
                end = last
            if not seq.complete_through(end):
                # grace counts from the later of the last progress and the end of stream
                idle = now - max(self.progress[name], self.eos_time[upstream])
                if idle >= grace and self.bus.backlog == 0 and end_gaps_due(self._fetch(name, end), idle,
                                                                            self.delivery):
                    log.warning("%s: end of stream: %s still missing after %.1f s without progress "
                                "are gaps", self.name, name, idle)
                    self._release(name, seq.flush_through(end))
                else:
                    done = False
        self._drain_ready()
        return done and self.align.next_write > last

    def _fetch(self, stream: str, upto: int) -> int | None:
        """Fetch what ``stream`` misses up to ``upto`` from its publisher's cache.  The truth
        of a frame sent without truth is not in any cache: its /measurements says so."""
        return fetch_holes(self.bus, stream, self.streams[stream], upto, self._on_data)

    def _fetch_due(self) -> None:
        for name, seq in self.streams.items():
            if self.holes[name].due(seq):
                self._release(name, settle_holes(self.bus, name, seq, self._on_data))

    def _sequencers(self, start: int, names: list[str]) -> dict[str, Sequencer]:
        return {k: Sequencer.for_delivery(self.delivery, start, k, self.heads[k]) for k in names}

    def run(self) -> int:
        # an earlier sink process of this run finished: a complete run is never reopened
        # (truncated); an incomplete one is kept unless this sink records the run itself
        self.earlier = read_summary(self.ctx.out / SUMMARY_NAME, self.run_id)
        if self.earlier is not None and self.earlier.complete:
            return self._end_again(self.earlier)
        self.latency.carry_over(self.ctx.out / LATENCY_PART, self.run_id)  # an earlier process's
        self._warm_up()
        topics = ["measurements", "truth"] + (["tracks"] if self.sink_cfg.tracks else [])
        self.latency.subscribed(self.clock.time_ns())  # what was published before is history
        self.bus.subscribe(topics + ["info/*", "eos/*"])
        for name, seq in self.streams.items():  # where each stream's history ends
            seq.hold_catch_up_through(self.bus.head(name))
        self.bus.declare([f"eos/{self.name}"])
        self.bus.declare_alive()
        self.restarted = self._restarted()
        if self.restarted:
            self.alone = UpstreamWatch(self.bus, ["source"] + (["tracker"] if self.sink_cfg.tracks else []),
                                       topics, self.delivery.upstream_gone_s, self.clock.monotonic)
        outcome = self._record()
        if self.gone:  # alone: finalized (or kept) what the run has
            log.error("%s: run %s: %s; %s what it has in %s", self.name, self.run_id, self.gone,
                      "kept" if outcome == "kept" else "wrote", self.ctx.out)
            return EXIT_DATA
        if outcome in ("stopped", "kept"):
            return EXIT_STOPPED
        self.publish_control("eos", EndOfStream(
            stage=self.name, run=self.run_id, last_seq=self.align.next_write - 1, frames=self.frames_written,
            gaps=sorted({g for v in self.streams.values() for g in v.gaps}),
            error=self.eos_seen["source"].error, files=self.files))
        self.linger_until_alone(self.cfg.supervisor.linger_s)
        return EXIT_OK

    def _warm_up(self) -> None:
        warm_imports("bnptrack.sources.mcap_log", "bnptrack.pipeline.resolve")
        # the open looks up the built-in parameter files (importlib.resources.files), whose
        # first call imports importlib's resource readers (unless a .pth file did at start-up)
        from importlib import resources

        resources.files("bnptrack.tracker")
        for name in self.sink_cfg.paths(self.ctx.out):
            for module in SINKS[name].imports:
                try:
                    warm_imports(module)
                except ImportError:  # that sink is left out when it opens
                    pass

    def _record(self) -> str:
        """Record until the run is complete (``"complete"``), the stage is stopped
        (``"stopped"``) or, restarted, it finds the upstream gone (``"alone"``).  Having received
        nothing itself, it keeps an earlier process's finished output (``"kept"``: nothing is
        touched) or first writes what it recovers from that process's ``.part`` file; nothing
        at all, alone, raises :class:`UpstreamGone` (no file touched).  The outputs are
        finalized (or abandoned after a write error)."""
        outcome = "stopped"
        failed = False
        try:
            outcome = self._loop()
            if outcome != "complete" and self.sinks is None:
                outcome = self._recover(outcome)
        except UpstreamGone:
            failed = True
            raise
        except OSError as exc:
            if isinstance(exc, ConnectionError):  # the transport, not a file
                raise
            failed = True
            self._abandon()
            if isinstance(exc, StageIOError):
                raise
            raise StageIOError(self.name, exc.filename or self.ctx.out / self.sink_cfg.mcap_name, exc) from None
        finally:
            if not failed and outcome != "kept":
                self._finalize_or_abandon(outcome == "complete")
            self.health(force=True, extra=self._sink_health)
        return outcome

    def _loop(self) -> str:
        while not self.ctx.stop.is_set():
            ev = self.bus.recv(0.05)
            if ev is not None:
                self._on_event(ev)
                # take what is already queued before looking at completion
                while (ev := self.bus.recv(0)) is not None:
                    self._on_event(ev)
            self._drain_ready()
            self._fetch_due()
            self.latency.save_due(self.clock.monotonic())
            self.health(extra=self._sink_health)
            if self._check_end():
                return "complete"
            if self.alone is not None and self.alone.gone():
                self.gone = self.alone.reason()
                return "alone"
        return "stopped"

    def _on_event(self, ev: Any) -> None:
        if not self.on_control(ev):
            self._on_data(ev)

