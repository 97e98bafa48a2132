"""The tracker stage: track the ``measurements`` stream in sequence order and publish
``tracks``; snapshot the state (with its journal) and resume from it when restarted."""

from __future__ import annotations

import logging
import os
import sys
import threading
from collections import deque
from typing import Any

import msgspec
import numpy as np

from bnptrack.tracker.messages import encode
from bnptrack.pipeline.config import TrackerStageConfig
from bnptrack.pipeline.journal import JOURNAL_NAME, TracksJournal
from bnptrack.pipeline.stages.base import EXIT_DATA, EXIT_OK, EXIT_STOPPED, StageBase, StageContext, settle_heap, warm_imports
from bnptrack.pipeline.stages.delivery import (FETCH_AFTER_S, Accepted, HeadAsk, HoleWatch, Intake, RepeatLog,
                                              Sequencer, end_gaps_due, fetch_holes, publisher_copy, resolve_conflict,
                                              settle_holes)
from bnptrack.pipeline.stages.health import EndOfStream, StageInfo
from bnptrack.pipeline.stages.recovery import SNAPSHOT_NAME, BackgroundWriter, Snapshot, keep_prior, read_snapshot
from bnptrack.pipeline.stages.salvage import UpstreamWatch
from bnptrack.pipeline.stages.tracker_output import StageOutput
from bnptrack.pipeline.stages.tracker_snapshots import TrackerSnapshots
from bnptrack.pipeline.stages.tracker_core import Skip, Step, TrackerCore, Verify
from bnptrack.pipeline.stages.tracker_warmup import preload_tracker, warm_tracker_imports, warm_up_tracker
from bnptrack.tracker.filtering import SCIPY_PAIRS
from bnptrack.tracker.types import Frame, FrameBounds

__all__ = ["LAZY_IMPORTS", "LAZY_PAIRS", "TrackerStage", "build_stage_tracker"]

log = logging.getLogger("bnptrack.stage")

#: Modules the trackers import on first need, inside a step, on large frames only: the KD-tree
#: gating (``scipy.spatial``, tracker/gating.py) and the per-component JPDA* assignment
#: (``scipy.sparse.csgraph``, tracker/bnp/assignment.py) take over from
#: :data:`~tracker.filtering.SCIPY_PAIRS` track x measurement pairs.  A first import in the frame loop stalls that frame and queues the frames
#: behind it (docs/pipeline.md, Performance), so the stage imports them in the background as
#: soon as a frame reaches :data:`LAZY_PAIRS` (:meth:`TrackerStage._lazy_imports_due`), ahead
#: of the frames that need them; a run whose frames stay small (vo2017: at most 33
#: measurements) never pays for them (importing them up front costs 0.4-0.75 s of CPU before the
#: first frame).
LAZY_IMPORTS = ("scipy.sparse.csgraph", "scipy.spatial")
#: Measurements x max(measurements, tracks of the previous frame) of a frame from which the
#: stage starts importing :data:`LAZY_IMPORTS` (a tenth of the pairs that need them:
#: the tracks of the next frames can grow to the measurements' number by births).
LAZY_PAIRS = SCIPY_PAIRS // 10


def build_stage_tracker(tc: TrackerStageConfig, metadata: dict[str, str] | None) -> Any:
    """The tracker stage's :class:`~pipeline.resolve.TrackerSetup`, built by the one resolver
    ``bnptrack track`` uses: model parameters from ``tc.params`` or the source's metadata
    record, the settings preset or file, then the ``--set`` items of ``tc.overrides``.
    Raises :class:`ConfigError` (the launcher calls this before starting any process)."""
    from bnptrack.pipeline.resolve import tracker_setup

    return tracker_setup(tc.tracker, params=tc.params or None, config=tc.config or None,
                         overrides=tc.overrides, metadata=metadata, seed=tc.seed)


class TrackerStage(TrackerSnapshots, StageBase):
    """Track the ``measurements`` stream in sequence order and publish ``tracks``.

    Any tracker :func:`pipeline.resolve.tracker_setup` builds works (the state class comes
    from ``tracker.initial_state()``).  Frame ``k`` uses the tracker's stream of frame ``k``
    (``tracker.state.tracker_frame_rng(seed, k)``) exactly like ``bnptrack track``, so the output
    depends only on the frames and their order.
    """

    role = "tracker"
    #: The stage whose ``info`` and ``eos`` messages the tracker follows.
    upstream = "source"

    def __init__(self, ctx: StageContext) -> None:
        super().__init__(ctx)
        self.tc = self.cfg.tracker
        self.snap_path = self.ctx.out / SNAPSHOT_NAME
        self.intake = Intake(self.name, self.run_id, self.bus, self.counters, self.delivery.max_payload_bytes,
                             time_ns=self.clock.time_ns)
        #: the pure core: which frames to track, in order (:mod:`pipeline.stages.tracker_core`)
        self.ask_head = HeadAsk(self.bus, "measurements", self.clock.monotonic)
        self.gap_log = RepeatLog()
        self.core = TrackerCore(Sequencer.for_delivery(self.delivery, 0, "measurements", self.ask_head),
                                FrameBounds(self.delivery.max_frame_gap, self.delivery.max_gap_s,
                                            self.delivery.resync_frames))
        self.tracker = None
        self.state = None
        #: when the main thread took the sample being processed off the bus (``t_deq``)
        self.t_deq_ns = 0
        self.journal = TracksJournal(self.ctx.out / JOURNAL_NAME, self.delivery.cache_frames)
        self.pending: list[Accepted] = []
        self.restored: Snapshot | None = None
        self.since_snapshot = 0
        self.last_progress = self.clock.monotonic()
        self.step_ms: deque = deque(maxlen=10_000)
        #: (frame, its unused generator): the stream of the frame expected next, built ahead
        self.next_rng: tuple[int, Any] | None = None
        self.writer = BackgroundWriter()
        self.finished_eos: EndOfStream | None = None
        self.holes = HoleWatch(FETCH_AFTER_S, self.clock.monotonic)
        self.alone: UpstreamWatch | None = None  # set when resumed: the rule for an upstream gone
        #: numba's import and set-up, started by run() while the stage waits for the source
        self.preloading: threading.Thread | None = None
        #: the background import of LAZY_IMPORTS, started by the first large frame
        self.lazy_importing: threading.Thread | None = None
        self.last_tracks = 0  # tracks of the last frame's estimate
        self.output: StageOutput | None = None  # the tracker with the stage's lag

    # -- setup -------------------------------------------------------------------------
    def _build(self, info: StageInfo) -> None:
        tc = self.tc
        if self.preloading is not None:  # no import of the build races the preload's
            self.preloading.join()
        setup = build_stage_tracker(tc, info.metadata)
        self.tracker = setup.tracker
        self.output = StageOutput(self.tracker, setup.params, tc.lag)
        initial = self.tracker.initial_state()
        if self.restored is not None:
            self.state = self.output.restore(self.restored.state, type(initial))
        elif tc.prior_from:
            self.state = self.output.initial_state(keep_prior(initial, read_snapshot(tc.prior_from), tc.tracker))
            log.info("%s: starting from the prior of %s", self.name, tc.prior_from)
        else:
            self.state = self.output.initial_state(initial)
        warm_up_tracker(self.tracker)
        self.publish_control("info", StageInfo(stage=self.name, run=self.run_id, kind=tc.tracker,
                                               metadata={**setup.metadata, "run": self.run_id}, tracker=tc.tracker,
                                               params=msgspec.to_builtins(setup.params),
                                               seed=tc.seed, pid=os.getpid()))
        log.info("%s: %s tracker, params %s, seed %d", self.name, tc.tracker,
                 setup.choice.describe(setup.params), tc.seed)

    # -- per frame ---------------------------------------------------------------------
    def _process(self, released: list[tuple[int, Any]]) -> None:
        for s, item in released:
            act = self.core.decide(s, item)
            if isinstance(act, Verify):  # open mode: the publisher's own copy of the seq
                act = self.core.decide(s, publisher_copy(self.bus, "measurements", act.item, self.intake.check),
                                       own=True)
            if isinstance(act, Step):
                if act.fresh:  # a new segment of the stream: no prediction over the jump
                    self._new_segment()
                self._step(s, act.item, act.frame)
            elif isinstance(act, Skip):
                self.counters.gaps += 1
                self.gap_log.warning("%s: frame seq %d is missing (gap); predicting through it", self.name, s)
            else:
                self.intake.reject_sample("measurements", act.payload, s, act.why)

    def _step(self, s: int, acc: Accepted, frame: Frame) -> None:
        """Track frame ``s``, publish its tracks (with a lag: those of the frame ``lag``
        before), then journal them, snapshot when due and build the next frame's generator
        (after the put: not between a frame's receipt and its tracks)."""
        from bnptrack.tracker.state import tracker_frame_rng

        if self.lazy_importing is None and self._lazy_imports_due(frame):
            self.lazy_importing = threading.Thread(target=warm_imports, args=LAZY_IMPORTS,
                                                   name="lazy-imports", daemon=True)
            self.lazy_importing.start()
        rng = self._frame_rng(frame.frame)
        clock = self.clock
        t_s0 = clock.time_ns()
        t0 = clock.perf_counter()
        # t: the source's publication time (end-to-end latency); t_in: when the tracker
        # received the frame; t_deq: when the main thread took it off the bus
        entry = (s, {"t": acc.meta.get("t", 0), "t_in": acc.t_recv_ns, "t_deq": self.t_deq_ns})
        state, out = self.output.step(self.state, frame, rng, entry)
        t1 = clock.perf_counter()
        t_s1 = clock.time_ns()
        records = [self._publish(e, est, t_s0, t_s1) for e, est in out]
        self.step_ms.append((t1 - t0) * 1e3)
        # the state advances only once its output is out (a snapshot is always consistent)
        self.state = state
        self.core.stepped(s, frame)
        self._journal(records)
        self.counters.processed += 1
        self.since_snapshot += 1
        if self.since_snapshot >= self.tc.snapshot_every:
            self.snapshot()
        self.next_rng = (frame.frame + 1, tracker_frame_rng(self.tc.seed, frame.frame + 1))

    def _publish(self, entry: tuple[int, dict], est: Any, t_s0: int, t_s1: int) -> tuple[int, bytes, dict]:
        """Publish ``est`` as the ``/tracks`` sample of ``entry``'s sequence number; returns
        its journal record.  ``t_s0`` / ``t_s1``: around the step, ``t_out``: when the tracks
        were published (the per-segment breakdown of benchmarks/pipeline_latency.py, read
        back from the journal)."""
        s, taken = entry
        payload = encode(est, self.run_id)
        meta = {"seq": s, "t": taken["t"], "frame": est.frame, "t_in": taken["t_in"], "t_deq": taken["t_deq"],
                "t_s0": t_s0, "t_s1": t_s1, "t_out": self.clock.time_ns()}
        self.bus.publish("tracks", payload, meta)
        self.last_tracks = len(est.tracks)
        return s, payload, meta

    def _lazy_imports_due(self, frame: Frame) -> bool:
        """Whether ``frame`` is large enough (:data:`LAZY_PAIRS`) for the large frames'
        imports to start (those not imported yet): the steps that need them then wait only
        for what is left of the import."""
        m = frame.z.shape[0]  # an ndarray: Frame's constructors make it one
        if m * max(m, self.last_tracks) < LAZY_PAIRS:
            return False
        return any(name not in sys.modules for name in LAZY_IMPORTS)

    def _frame_rng(self, k: int) -> Any:
        """The tracker's stream of frame ``k`` (:func:`tracker.state.tracker_frame_rng`): the
        one built ahead after the previous frame when ``k`` follows it, else built now."""
        from bnptrack.tracker.state import tracker_frame_rng

        ahead, self.next_rng = self.next_rng, None
        if ahead is not None and ahead[0] == k:
            return ahead[1]
        return tracker_frame_rng(self.tc.seed, k)

    def _on_data(self, ev: Any) -> None:
        self.counters.received += 1
        acc = self.intake.check(ev)
        if acc is None:
            return
        t = acc.meta.get("t")
        if isinstance(t, int):
            self.counters.latency_ms.append((acc.t_recv_ns - t) / 1e6)
        if self.tracker is None:
            self.pending.append(acc)
            return
        self._push(acc)

    def _push(self, acc: Accepted) -> None:
        status, released = self.core.push(acc.seq, acc)
        if status == "accepted":
            self.counters.accepted += 1
            self.last_progress = self.clock.monotonic()
        elif status == "duplicate":
            self.counters.duplicates += 1
        elif status in ("far", "ahead"):
            self.intake.reject_sample("measurements", acc.payload, acc.seq, self.core.seq.far_reason(acc.seq))
        elif status == "conflict":
            self.counters.duplicates += 1
            resolve_conflict(self.bus, "measurements", self.core.seq, acc.seq, self.intake.check)
        else:
            self.counters.late += 1
            self.gap_log.warning("%s: frame seq %d arrived after its gap was declared: rejected", self.name, acc.seq)
        if released:
            self._process(released)

    def _extra_health(self) -> dict:
        a = np.fromiter(self.step_ms, float) if self.step_ms else np.zeros(0)
        return {
            "last_seq": self.core.last_seq,
            "last_frame": self.core.last_frame,
            "step_ms_p50": float(np.median(a)) if a.size else None,
            "pending": self.core.seq.pending,
        }

    # -- loop --------------------------------------------------------------------------
    def run(self) -> int:
        warm_imports("bnptrack.pipeline.resolve", "bnptrack.tracker.state")
        warm_tracker_imports(self.tc.tracker)
        # numba's import and set-up (the first kernel call's cost) and the trackers' lazy
        # imports overlap the wait for the source
        self.preloading = threading.Thread(target=preload_tracker, name="numba-preload", daemon=True)
        self.preloading.start()
        history = self._restore()
        self.bus.declare(["tracks", f"info/{self.name}", f"eos/{self.name}"])
        for s, payload, meta in history:  # the run so far, into the new publisher's cache
            self.bus.publish("tracks", payload, meta)
        if history:
            log.info("%s: published the %d /tracks sample(s) of the journal again", self.name, len(history))
        del history  # free the payloads (run() lasts as long as the run)
        if self.finished_eos is not None:  # restarted after it had finished the run
            return self._end_again()
        self.bus.subscribe(["measurements", "info/*", "eos/*"])
        # where the history ends: hold the catch-up window until there
        self.core.seq.hold_catch_up_through(self.bus.head("measurements"))
        self.bus.declare_alive()
        if self.restored is not None:
            self.alone = UpstreamWatch(self.bus, [self.upstream], ["measurements"],
                                       self.delivery.upstream_gone_s, self.clock.monotonic)
        try:
            return self._loop()
        finally:
            try:
                self.snapshot(wait=True)
            finally:
                self._close_journal()
                self.health(force=True, extra=self._extra_health)

    def _loop(self) -> int:
        """Track until the run is done (EXIT_OK) or the stage is stopped (EXIT_STOPPED)."""
        finished = False
        while not self.ctx.stop.is_set():
            ev = self.bus.recv(0.05)
            if ev is not None:
                self.t_deq_ns = self.clock.time_ns()
                self._on_event(ev)
            self.health(extra=self._extra_health)
            seq = self.core.seq
            if self.tracker is not None and self.holes.due(seq):
                self._process(settle_holes(self.bus, "measurements", seq, self._on_data))
            if not finished and self.tracker is not None and self.upstream in self.eos_seen:
                finished = self._check_end(self.eos_seen[self.upstream])
            if finished and set(self.tc.done_by) <= set(self.eos_seen):
                return EXIT_OK
            if not finished and self.alone is not None and self.alone.gone():
                return self._gone()
        return EXIT_STOPPED

    def _gone(self) -> int:
        """Resumed, with the source gone and no cache holding its frames: keep what is done
        (the snapshot and the journal), announce no end of stream (the run did not end
        here) and exit EXIT_DATA (finished, output incomplete)."""
        log.error("%s: run %s: %s; processed up to seq %d (frame %d): %s and %s keep it", self.name,
                  self.run_id, self.alone.reason(), self.core.last_seq, self.core.last_frame, self.snap_path,
                  self.journal.path)
        return EXIT_DATA

    def _on_event(self, ev: Any) -> None:
        if self.on_control(ev):
            if self.tracker is None and self.upstream in self.infos:
                self._build(self.infos[self.upstream])
                settle_heap()
                self.bus.declare_alive("ready")
                for acc in self.pending:
                    self._push(acc)
                self.pending.clear()
        elif ev.topic == "measurements":
            self._on_data(ev)
        else:
            log.debug("%s: ignoring %s", self.name, ev.topic)

    def _check_end(self, eos: EndOfStream) -> bool:
        """After the source's end of stream: declare what is still missing after the grace
        period gaps; once everything is processed, snapshot and announce the end (True)."""
        seq = self.core.seq
        if not seq.complete_through(eos.last_seq):
            # grace counts from the later of the last progress and the end of stream
            idle = self.clock.monotonic() - max(self.last_progress, self.eos_time[self.upstream])
            if idle >= self.delivery.eos_grace_s and self.bus.backlog == 0 and end_gaps_due(
                    fetch_holes(self.bus, "measurements", seq, eos.last_seq, self._on_data), idle, self.delivery):
                log.warning("%s: end of stream: frames still missing after %.1f s without "
                            "progress are gaps", self.name, idle)
                self._process(seq.flush_through(eos.last_seq))
        if not seq.complete_through(eos.last_seq):
            return False
        self._flush_window()
        self.finished_eos = EndOfStream(
            stage=self.name, run=self.run_id, last_seq=eos.last_seq,
            frames=self.counters.processed, gaps=list(seq.gaps),
            rejected=list(self.core.rejected_seqs), error=eos.error)
        self.snapshot(wait=True)
        self.publish_control("eos", self.finished_eos)
        log.info("%s: processed %d frame(s) (%d gap(s)); waiting for %s", self.name,
                 self.counters.processed, len(seq.gaps), ", ".join(self.tc.done_by) or "nobody")
        self.health(force=True, extra=self._extra_health)
        return True

