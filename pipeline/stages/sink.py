"""The sink stage: record the run (``tracks.mcap``, ``run.rrd``, ``sink.json``) from the
``measurements``, ``truth`` and ``tracks`` streams, frame by frame in sequence order."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from bnptrack.tracker.messages import to_estimate, to_frame, to_truth
from bnptrack.pipeline.stages.base import (EXIT_DATA, EXIT_OK, EXIT_STOPPED, StageBase, StageContext, StageIOError,
                                           settle_heap, stop_reason, warm_imports)
from bnptrack.pipeline.stages.delivery import FETCH_AFTER_S, GAP, NO_TRUTH, Accepted, HoleWatch, Intake, Sequencer, fetch_holes
from bnptrack.pipeline.stages.health import missing_entries, EndOfStream, StageInfo
from bnptrack.pipeline.stages.recovery import SUMMARY_NAME, commit_parts, part_path, sync_parts, write_atomic
from bnptrack.pipeline.stages.salvage import UpstreamGone, UpstreamWatch, missing_tail, salvage_part
from bnptrack.pipeline.stages.summary import RunSummary, read_summary
from bnptrack.pipeline.stages.sink_align import FrameAligner, Reject, Write
from bnptrack.pipeline.stages.sink_latency import LATENCY_PART, LatencyBook
from bnptrack.sinks.records import Payloads, Sink, SinkOptions, SinkRecord
from bnptrack.sinks.sink import SINKS, OptionalSink, SinkSet, make_sink
from bnptrack.tracker.types import FrameBounds

__all__ = ["SinkStage"]

log = logging.getLogger("bnptrack.stage")


class SinkStage(StageBase):
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
        self.streams: dict[str, Sequencer] = {
            "measurements": Sequencer.for_delivery(d, 0, "measurements"),
            "truth": Sequencer.for_delivery(d, 0, "truth"),
        }
        if self.sink_cfg.tracks:
            self.streams["tracks"] = Sequencer.for_delivery(d, 0, "tracks")
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
        self.align = FrameAligner(self.streams, FrameBounds(d.max_frame_gap, d.max_gap_s))
        self.upstream_marked: set[str] = set()  # streams given the gaps their upstream stage reported
        self.t_first_ns: int | None = None
        self.alone: UpstreamWatch | None = None  # set when restarted: the rule for an upstream gone
        self.gone = ""  # why the sink stopped waiting (the upstream was gone)
        self.recovered = 0  # frames recovered from the earlier process's .part file
        self.earlier: RunSummary | None = None  # the sink.json an earlier process of this run wrote
        self.restarted = False  # an earlier sink process of this run left outputs: counters are ours only

    # -- output ------------------------------------------------------------------------
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

    def _sink_health(self) -> dict:
        """The sink's part of its health message: what the launcher's progress line shows
        (frames written, the newest frame seen, the last frame's latency, the scores)."""
        seen = self.streams["measurements"].max_seen
        return {"frames_written": self.frames_written, "next_seq": self.align.next_write,
                "max_seq_seen": seen, "last_latency_ms": self.latency.last_ms,
                "scores": self.tally.as_dict()}

    def _health_scalars(self) -> dict[str, float]:
        c = self.counters
        out = {"received": c.received, "accepted": c.accepted, "rejected": c.rejected,
               "duplicates": c.duplicates, "late": c.late, "gaps": c.gaps,
               "dropped": float(self.bus.dropped)}
        if self.latency.last_ms is not None:
            out["latency_ms"] = self.latency.last_ms
        return {k: float(v) for k, v in out.items()}

    def _drain_ready(self) -> None:
        """Write every frame for which each stream has released its item (or a gap)."""
        if not self._open():
            return
        for act in self.align.drain():
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
            log.warning("%s: %s of frame seq %d is missing: recorded as a gap", self.name, stream, s)

    def _push(self, stream: str, seq: int, item: Any) -> None:
        status, released = self.streams[stream].push(seq, item)
        if status == "accepted":
            if item is not NO_TRUTH:
                self.counters.accepted += 1
            self.progress[stream] = self.clock.monotonic()
        elif status == "duplicate":
            if item is not NO_TRUTH:
                self.counters.duplicates += 1
        elif status == "far":
            if item is not NO_TRUTH:
                self.intake.reject_sample(stream, item.payload, seq, self.streams[stream].far_reason(seq))
        else:
            self.counters.late += 1
            log.warning("%s: %s seq %d arrived after its gap was declared: rejected", self.name, stream, seq)
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
                if idle >= grace and self.bus.backlog == 0 and not self._fetch(name, end):
                    log.warning("%s: end of stream: %s still missing after %.1f s without progress "
                                "are gaps", self.name, name, idle)
                    self._release(name, seq.flush_through(end))
                else:
                    done = False
        self._drain_ready()
        return done and self.align.next_write > last

    def _fetch(self, stream: str, upto: int) -> int:
        """Fetch what ``stream`` misses up to ``upto`` from its publisher's cache.  The truth
        of a frame sent without truth is not in any cache: its /measurements says so."""
        return fetch_holes(self.bus, stream, self.streams[stream], upto, self._on_data)

    def _fetch_due(self) -> None:
        for name, seq in self.streams.items():
            if self.holes[name].due(seq):
                self._fetch(name, max(seq.buf))

    def _finalize_or_abandon(self, complete: bool) -> None:
        try:
            self._finalize(complete)
        except OSError as exc:
            self._abandon()
            if isinstance(exc, StageIOError):
                raise
            raise StageIOError(self.name, exc.filename or self.ctx.out / self.sink_cfg.mcap_name, exc) from None

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
            scores=self.tally.as_dict(),
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

    def _view_command(self) -> str:
        """The command that opens the recording (``""``: no ``run.rrd`` was written)."""
        rrd = self.ctx.out / self.sink_cfg.rrd_name
        return f"bnptrack view {rrd}" if str(rrd) in self.files else ""

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

    def _restarted(self) -> bool:
        """Whether an earlier sink process of this run left its outputs (finished or not) here."""
        return self.earlier is not None or any(part_path(p).exists() for p in self.sink_cfg.paths(self.ctx.out).values())

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
        self.streams = {k: Sequencer.for_delivery(self.delivery, self.align.next_write, k) for k in self.streams}
        log.info("%s: recovered %d frame(s) (up to frame %d) from the killed sink's .part file", self.name,
                 self.recovered, self.align.last_frame)
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


_NO_SCORES: dict[str, Any] = {"ospa": None, "ospa2": None}
