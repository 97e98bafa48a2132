"""The source stage: publish the frames of a simulation or an MCAP log (``measurements`` +
``truth``), then the end of stream; serve the cache until the ``done_by`` stages are done."""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Iterator
from typing import Any
from pathlib import Path

from bnptrack.tracker.messages import encode, from_truth
from bnptrack.pipeline.config import PipelineConfig, SourceConfig
from bnptrack.pipeline.stages.base import EXIT_DATA, EXIT_OK, EXIT_STOPPED, StageBase, settle_heap
from bnptrack.pipeline.stages.health import EndOfStream, StageInfo
from bnptrack.sources.frame_window import FrameWindow
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.types import Frame

__all__ = ["SourceStage", "source_frames", "check_channels", "check_window", "window_frames"]

log = logging.getLogger("bnptrack.stage")


def source_frames(cfg: PipelineConfig) -> tuple[dict[str, str] | None, Iterator[Frame]]:
    """The source's metadata record and its frames (``source.frames`` limits them)."""
    src_cfg = cfg.source
    if src_cfg.kind == "synthetic":
        from bnptrack.sources.scenarios import open_scenario, scene_of
        from bnptrack.sources.synthetic import simulate

        try:  # the scene first, so that a bad scenario is named as the source's setting
            scene_of(src_cfg.scenario, src_cfg.seed, src_cfg.overrides)
        except (KeyError, ValueError) as exc:
            raise ConfigError(f"source.scenario: {exc}") from None
        opened = open_scenario(src_cfg.scenario, src_cfg.params, src_cfg.seed, src_cfg.overrides, src_cfg.snr_db)
        metadata = opened.metadata
        frames: Iterator[Frame] = simulate(opened.scenario, opened.params, src_cfg.seed, sensor=src_cfg.sensor)
    else:
        from bnptrack.sources.mcap_log import McapLogError, iter_frames, read_metadata

        if not src_cfg.log:
            raise ConfigError("source.log: an MCAP log is required when source.kind = 'mcap'")
        if not Path(src_cfg.log).is_file():
            raise ConfigError(f"source.log: {src_cfg.log}: no such file")
        try:
            metadata = read_metadata(src_cfg.log)
            check_channels(src_cfg)
        except McapLogError as exc:  # not an MCAP file at all: nothing to replay
            raise ConfigError(f"source.log: {exc}") from None
        frames = iter_frames(src_cfg.log, dict(src_cfg.topics))
    return metadata, window_frames(frames, src_cfg)


def check_channels(src_cfg: SourceConfig) -> None:
    """Raise :class:`ConfigError` when no channel of ``source.log`` is (or is mapped by
    ``source.topics`` to) ``/measurements``: the error of ``bnptrack track`` (the log's
    channels and how to map one), plus the pipeline file's key."""
    from bnptrack.sources.mcap_log import missing_measurements_message
    from bnptrack.sources.channels import channel_list
    from bnptrack.sources.robot_log import robot_topics
    from bnptrack.tracker.messages import TOPIC_MEASUREMENTS

    channels = channel_list(src_cfg.log)
    try:
        robot_topics(src_cfg.log, src_cfg.topics, channels)
    except ValueError as exc:
        raise ConfigError(f"source.topics: {exc}") from None
    if not any(src_cfg.topics.get(c.topic, c.topic) == TOPIC_MEASUREMENTS for c in channels):
        raise ConfigError(f"{missing_measurements_message(src_cfg.log, channels)}; in a pipeline file: "
                          f"source.topics = {{\"SRC\" = \"{TOPIC_MEASUREMENTS}\"}}")


def check_window(src_cfg: SourceConfig) -> None:
    """Raise :class:`ConfigError` for a window (``start_*`` / ``end_*``) that mixes seconds and
    frames at one end or ends before it starts (:meth:`sources.frame_window.FrameWindow.check`)."""
    try:
        FrameWindow.of(src_cfg).check("source.")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def window_frames(frames: Iterator[Frame], src_cfg: SourceConfig) -> Iterator[Frame]:
    """The frames of ``frames`` inside the source's window and count (``source.frames``; see
    :class:`SourceConfig`): seconds count from the first frame's time stamp; the input is not
    read past the end."""
    check_window(src_cfg)
    return FrameWindow.of(src_cfg).cut(frames)


class SourceStage(StageBase):
    """Publish frames (``measurements`` + ``truth``), then end of stream; serve the cache
    until the ``done_by`` stages have finished."""

    role = "source"
    sent_eos: EndOfStream | None = None

    def on_control(self, ev: Any) -> bool:
        """Control messages; an end of stream of this source's name that it did not send is
        reported to the launcher (``foreign_eos``: a forged one, the launcher stops the run)."""
        before = self.eos_seen.get(self.name)
        handled = super().on_control(ev)
        seen = self.eos_seen.get(self.name)
        if seen is not None and seen is not before:
            sent = self.sent_eos
            if sent is None or (seen.last_seq, seen.frames) != (sent.last_seq, sent.frames):
                log.error("%s: an end of stream of %s at seq %d that this process did not send", self.name,
                          self.name, seen.last_seq)
                self.ctx.report({"foreign_eos": {"last_seq": seen.last_seq, "frames": seen.frames}})
        return handled

    def run(self) -> int:
        src_cfg = self.cfg.source
        metadata, frames = source_frames(self.cfg)
        self.bus.declare(["measurements", "truth", f"info/{self.name}", f"eos/{self.name}"])
        self.bus.subscribe(["eos/*"])
        self.bus.declare_alive()
        self.publish_control("info", StageInfo(stage=self.name, run=self.run_id, kind=src_cfg.kind,
                                               metadata=metadata, pid=os.getpid()))
        settle_heap()
        self.bus.declare_alive("ready")
        if not self._wait_ready(src_cfg):
            return EXIT_STOPPED
        t0 = self.clock.monotonic()
        seq, stopped, error = self._publish_all(frames, src_cfg, t0)
        if stopped:
            log.info("%s: stopped after %d frame(s)", self.name, seq + 1)
            self.ctx.report({"stopped": {"last_seq": seq, "frames": seq + 1}})
            self.health(force=True)
            return EXIT_STOPPED
        eos = EndOfStream(stage=self.name, run=self.run_id, last_seq=seq, frames=seq + 1, error=error)
        # the launcher knows this end of stream before anyone can act on it (checked against
        # the one the sink records: a forged one conflicts)
        self.ctx.report({"eos": {"last_seq": seq, "frames": seq + 1}})
        self.sent_eos = eos
        self.publish_control("eos", eos)
        log.info("%s: published %d frame(s) in %.2f s; waiting for %s to finish", self.name, seq + 1,
                 self.clock.monotonic() - t0, ", ".join(src_cfg.done_by) or "nobody")
        self.health(force=True)
        done = self.wait_done(src_cfg.done_by)
        self.health(force=True)
        if not done:
            return EXIT_STOPPED
        return EXIT_DATA if error else EXIT_OK

    def _wait_ready(self, src_cfg: SourceConfig) -> bool:
        """Wait until the ``wait_for`` stages are ready (at most ``ready_timeout_s``); False
        when stopped meanwhile."""
        if not src_cfg.wait_for:
            return True
        log.info("%s: waiting for %s to be ready", self.name, ", ".join(src_cfg.wait_for))
        clock = self.clock
        deadline = clock.monotonic() + src_cfg.ready_timeout_s if src_cfg.ready_timeout_s > 0 else math.inf
        missing = set(src_cfg.wait_for)
        while not self.ctx.stop.is_set():
            missing = self.bus.wait_alive(src_cfg.wait_for, min(0.2, max(0.0, deadline - clock.monotonic())),
                                          "ready")
            if not missing or clock.monotonic() >= deadline:
                break
        if self.ctx.stop.is_set():
            return False
        if missing:
            log.warning("%s: %s not ready after %.0f s; publishing anyway (they will get the "
                        "cache's history when they join)", self.name, ", ".join(sorted(missing)),
                        src_cfg.ready_timeout_s)
        return True

    def _publish_all(self, frames: Iterator[Frame], src_cfg: SourceConfig, t0: float) -> tuple[int, bool, str]:
        """Publish every frame (paced by ``rate``); returns (last seq, stopped, error)."""
        seq = -1
        stamp0: int | None = None
        try:
            for frame in frames:
                if self.ctx.stop.is_set():
                    return seq, True, ""
                if src_cfg.rate > 0:
                    if stamp0 is None:
                        stamp0 = frame.stamp_ns
                    due = t0 + (frame.stamp_ns - stamp0) / 1e9 / src_cfg.rate
                    wait = due - self.clock.monotonic()
                    if wait > 0 and self.clock.wait(self.ctx.stop, wait):
                        return seq, True, ""
                seq += 1
                self._publish(seq, frame)
        except Exception as exc:
            from bnptrack.sources.mcap_log import McapLogError

            if not isinstance(exc, McapLogError):
                raise
            log.error("%s: %s", self.name, exc)
            return seq, False, str(exc)
        return seq, False, ""

    def _publish(self, seq: int, frame: Frame) -> None:
        """Publish frame ``seq`` (its truth too, when it has one); keep up with control."""
        bus = self.bus
        has_truth = frame.truth is not None
        meas = encode(frame, self.run_id)
        truth = encode(from_truth(frame.frame, frame.stamp_ns, frame.truth, self.run_id)) if has_truth else None
        t = self.clock.time_ns()
        bus.publish("measurements", meas, {"seq": seq, "t": t, "frame": frame.frame, "truth": has_truth})
        if truth is not None:
            bus.publish("truth", truth, {"seq": seq, "t": t, "frame": frame.frame})
        self.counters.published += 1
        self.health()
        while True:  # keep up with control messages without blocking
            ev = bus.recv(0)
            if ev is None:
                break
            self.on_control(ev)
