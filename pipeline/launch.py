"""Run a pipeline: one OS process per stage, supervised (``bnptrack launch`` / ``replay``).
The entry point of one stage process (``bnptrack stage``) is :mod:`pipeline.stage_process`.

:class:`Launcher`:

0. validates the whole pipeline (:func:`pipeline.preflight.check_pipeline`): a
   configuration error is raised before any process starts or any file is written; an
   output directory that holds another run's files is refused unless ``overwrite``, one
   that another launcher holds (its lock, ``<out>/.bnptrack.lock``) always;
1. resolves the run id and the output directory (``recordings/<run>/``), locks it and,
   with ``overwrite``, removes the earlier run's files (a fresh launch never resumes an
   old run);
2. opens the embedded Zenoh router (``zenoh.embedded_router``, a free loopback port by
   default) unless the pipeline names routers to ``connect`` to;
3. writes ``<out>/pipeline.json`` (the resolved pipeline the stages read) and starts every
   stage as ``python -m bnptrack stage ROLE --pipeline <out>/pipeline.json`` in its own
   session (so a terminal's Ctrl-C reaches the launcher only), logging to
   ``<out>/logs/<stage>.log``; ``<out>/stages.json`` lists their pids and restarts;
4. supervises: a stage that exits 0 or 3 is done (3: its output is incomplete; from the
   source: a data error), a stage that crashes (any other code, or a signal) is restarted up to
   ``supervisor.max_restarts`` times; a configuration error (2) stops the pipeline;
5. ends when every stage has exited (the source and the tracker leave once the sink has
   recorded the end of stream); SIGINT / SIGTERM (or ``timeout``) stop every stage with
   SIGTERM (they flush their files), then SIGKILL after ``supervisor.stop_timeout_s``.

Health messages of every stage are appended to ``<out>/health.jsonl``.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


from bnptrack.pipeline.config import PipelineConfig, check_run_id, dump_pipeline, resolve_run
from bnptrack.pipeline.launch_setup import LaunchSetup
from bnptrack.pipeline.outcome import SinkWait, check_eos, describe_missing, foreign_eos, unsent_eos
from bnptrack.pipeline.progress import Status
from bnptrack.pipeline.preflight import check_pipeline, lock_out, refuse_other_run
from bnptrack.pipeline.supervisor import (HealthMonitor, LaunchResult, StageProcess, recorded_complete, sink_left_output, stop_stages, write_stages)
from bnptrack.pipeline.stages import EXIT_CONFIG, EXIT_DATA, EXIT_IO, EXIT_OK, SUMMARY_NAME
from bnptrack.pipeline.stages.summary import SummaryError, load_summary

__all__ = ["Launcher", "launch"]

log = logging.getLogger("bnptrack.launch")

_DATA_ERROR = "the source stopped on a data error (see its log)"


# --------------------------------------------------------------------------- supervisor


class Launcher(LaunchSetup):
    """Start and supervise the stages of ``cfg`` (see the module docstring).

    ``echo`` receives one-line messages (stages started, restarted; the CLI prints them on
    stderr); ``progress`` is called with a :class:`pipeline.progress.Status` (the latest
    health of the source and the sink) about every 50 ms while the stages run, from the
    launch on (it prints at its own pace: :class:`pipeline.progress.Progress`).
    ``timeout`` (seconds) stops the pipeline with an error if it has not finished.
    """

    def __init__(self, cfg: PipelineConfig, *, echo: Callable[[str], None] | None = None,
                 timeout: float | None = None, python: str | None = None,
                 log_level: str = "INFO", overwrite: bool = False,
                 progress: Callable[[Status], Any] | None = None, view: bool = False) -> None:
        self.cfg = resolve_run(cfg)
        self.overwrite = overwrite
        check_run_id(self.cfg.run)
        self.out = Path(self.cfg.out)
        self.echo = echo or (lambda msg: None)
        self.timeout = timeout
        self.python = python or sys.executable
        self.log_level = log_level
        self.stages: list[StageProcess] = []
        self._stop = threading.Event()
        self._stop_reason = ""
        self.router = None
        self.monitor = HealthMonitor(self.out)
        self.credentials: dict[str, str] = {}
        self.progress = progress
        self.view = view
        self.viewer = None
        self._data_error = ""  # the source stopped on a data error
        self._sink_done_at: float | None = None
        self._sink_wait: SinkWait | None = None  # a stage was given up: the sink records what it has
        self._conflict = ""  # the source saw an end of stream of its name it did not send

    # -- public ----------------------------------------------------------------------
    def request_stop(self, reason: str = "interrupted") -> None:
        self._stop_reason = self._stop_reason or reason
        self._stop.set()

    def run(self) -> LaunchResult:
        t0 = time.monotonic()
        cfg = self.cfg
        if self.progress is not None:  # a first line at once: the checks import the tracker
            self.progress(Status(0.0, phase="checking"))
        check_pipeline(cfg, self.overwrite)  # every error before anything starts or is written
        if self.view:
            cfg = self.cfg = self._spawn_viewer(cfg)
        self.out.mkdir(parents=True, exist_ok=True)
        lock = lock_out(self.out)  # held until this process exits: no second launch here
        try:
            refuse_other_run(cfg, self.overwrite)
            return self._run_locked(t0)
        finally:
            os.close(lock)

    def _run_locked(self, t0: float) -> LaunchResult:
        cfg = self.cfg
        self._remove_earlier_run()
        result = LaunchResult(run=cfg.run, out=self.out, ok=False)
        try:
            stage_cfg = self._network(cfg)
            result.endpoints = list(stage_cfg.zenoh.connect)
            cfg_path = self.out / "pipeline.json"
            cfg_path.write_bytes(dump_pipeline(stage_cfg))
            self.monitor.open(stage_cfg, self.credentials)
            env = self._stage_env()
            self._start_stages(cfg_path, env)
            self.echo(f"run {cfg.run}: started {', '.join(f'{s.role} (pid {s.pid})' for s in self.stages)}"
                      f"; zenoh {stage_cfg.zenoh.mode} mode, {', '.join(stage_cfg.zenoh.connect) or 'no router'}"
                      f"; logs in {self.out / 'logs'}")
            self._supervise(env, t0, result)
            self.monitor.drain()  # the sink's last health message: the final progress line
            self._report_progress(t0, phase="final")
        finally:
            try:
                self._stop_all()
            finally:
                self._close_network()
        result.elapsed_s = time.monotonic() - t0
        result.restarts = {s.role: s.restarts for s in self.stages}
        self._conclude(result)
        for sp in self.stages:
            sp.close_link()
        return result

    def _start_stages(self, cfg_path: Path, env: dict[str, str]) -> None:
        """Start every stage (sink first) as ``python -m bnptrack stage ROLE``."""
        order = [r for r in ("sink", "tracker", "source") if r in self.cfg.stages]
        for role in order:
            argv = [self.python, "-m", "bnptrack", "stage", role, "--pipeline", str(cfg_path),
                    "--name", role, "--parent-pid", str(os.getpid()), "--log-level", self.log_level]
            sp = StageProcess(role, argv, self.out / "logs" / f"{role}.log")
            if role in self.credentials:  # down the stage's private link, not its environment
                sp.key = (role, self.credentials[role])
            self.stages.append(sp)
            sp.start(env)
        self._write_stages()

    def _conclude(self, result: LaunchResult) -> None:
        """Complete ``result`` from the sink's ``sink.json``: files, a source's data error,
        what the output lacks."""
        summary_path = self.out / SUMMARY_NAME
        unreadable = ""
        try:
            result.summary = load_summary(summary_path)
        except SummaryError as exc:
            result.summary, unreadable = None, str(exc)
        if result.summary is not None:
            result.files = [f for f in result.summary.files if Path(f).exists()]
            result.files.append(str(summary_path))
            src_err = result.summary.source_error
            if src_err and (result.ok or result.error == _DATA_ERROR):
                result.error = (f"{src_err} -- the pipeline processed the "
                                f"{result.summary.frames_written} readable frame(s)")
                result.ok = False
        conflict = ""
        if not result.interrupted:  # the end of stream the sink ended on must be the source's own
            conflict, result.summary = check_eos(self.out, result.summary, self.stages)
            conflict = conflict or self._conflict
        missing = unreadable or describe_missing(result.summary)
        if result.gave_up and result.summary is not None and not (missing or conflict):  # the exit code follows the output
            self.echo(f"{result.error}; the output is complete all the same")
            result.ok, result.error = True, ""
        elif result.gave_up or result.ok:
            result.incomplete = "; ".join(p for p in (result.error if result.gave_up else "", conflict, missing) if p)
            result.ok = not result.incomplete

    # -- network -----------------------------------------------------------------------
    # -- supervision -------------------------------------------------------------------
    def _write_stages(self) -> None:
        write_stages(self.out, self.stages)

    def _supervise(self, env: dict[str, str], t0: float, result: LaunchResult) -> None:
        while True:
            if self._stop.wait(0.05):
                result.interrupted = self._stop_reason == "interrupted"
                result.error = self._stop_reason
                return
            self.monitor.drain()
            self._report_progress(t0)
            if self.timeout is not None and time.monotonic() - t0 > self.timeout:
                result.error = f"timed out after {self.timeout:g} s"
                return
            changed = False
            for sp in self.stages:
                outcome = self._check_stage(sp, env, result)
                if outcome == "stop":
                    return
                changed = changed or outcome == "changed"
            if changed:
                try:
                    self._write_stages()
                except OSError as exc:
                    result.error = f"launcher: cannot write {self.out / 'stages.json'}: {exc}"
                    return
            if (conflict := foreign_eos(self.stages)) and not self._sink_wait:
                self._conflict = conflict
                self.echo(f"{conflict}: stopping every stage")
                result.ok = not self._data_error
                return
            if self._sink_wait is not None:
                if not self._sink_wait.waiting(self.stages, self.monitor.latest.get("sink")):
                    return
            elif self._finished(result):
                return

    def _check_stage(self, sp: StageProcess, env: dict[str, str], result: LaunchResult) -> str:
        """Look after one stage: ``"changed"`` (it exited or was restarted), ``"stop"`` (the
        run ends: ``result`` says why) or ``""``."""
        if sp.state == "running" and not sp.alive():
            sp.returncode = sp.proc.returncode
            return self._on_exit(sp, result)
        if sp.state == "restarting" and time.monotonic() >= (sp.restart_at or 0):
            sp.restarts += 1
            sp.start(env)
            self.echo(f"stage {sp.role} restarted (pid {sp.pid})")
            return "changed"
        return ""

    def _on_exit(self, sp: StageProcess, result: LaunchResult) -> str:
        """A stage exited with ``sp.returncode``: done, failed (``"stop"``) or to restart."""
        rc = sp.returncode
        if rc in (EXIT_OK, EXIT_DATA):  # EXIT_DATA: finished, output incomplete (sink.json says what)
            sp.state = "done"
            if rc == EXIT_DATA and sp.role == "source":
                self._data_error = _DATA_ERROR
            return "changed"
        what = f"killed by {signal.Signals(-rc).name}" if rc < 0 else f"exit code {rc}"
        if rc == EXIT_IO:  # disk full / I/O error: a restart cannot help
            sp.state = "failed"
            self.monitor.await_error(sp.role)  # the stage's health message names the file
            result.error = (self.monitor.io_errors.get(sp.role) or sp.error_line()
                            or f"stage {sp.role}: I/O error (log: {sp.log_path})")
            return "stop"
        if rc == EXIT_CONFIG:
            sp.state = "failed"
            result.error = f"stage {sp.role}: configuration error: {sp.error_line()} (log: {sp.log_path})"
            return "stop"
        settled = self._needless_restart(sp, what)
        if settled == "done":
            sp.state = "done"
            return "changed"
        sup = self.cfg.supervisor
        if settled or sp.restarts >= sup.max_restarts:
            sp.state = "failed"
            result.error = settled or (f"stage {sp.role} crashed ({what}) and was restarted "
                                       f"{sp.restarts} time(s) already; giving up (log: {sp.log_path})")
            result.gave_up = sp.role
            if settled or sp.role == "sink" or not any(o.role == "sink" and o.alive() for o in self.stages):
                return "stop"
            self.echo(f"{result.error}; the sink records what it has")
            self._sink_wait = SinkWait(self.cfg.delivery.eos_grace_s + 1.0)
            return "changed"
        sp.state = "restarting"
        sp.restart_at = time.monotonic() + sup.restart_backoff_s
        self.echo(f"stage {sp.role} (pid {sp.pid}) crashed ({what}); restarting "
                  f"({sp.restarts + 1}/{sup.max_restarts})")
        return "changed"

    def _finished(self, result: LaunchResult) -> bool:
        """Every stage is done; or the sink is, and the others lingered ``linger_s`` (then
        they are stopped)."""
        if not all(sp.state == "done" for sp in self.stages):
            # a sink that finished while others linger: give them linger_s, then stop them
            sinks_done = all(sp.state == "done" for sp in self.stages if sp.role == "sink")
            if not (sinks_done and any(sp.role == "sink" for sp in self.stages)):
                return False
            if self._sink_done_at is None:
                self._sink_done_at = time.monotonic()
                return False
            if time.monotonic() - self._sink_done_at <= self.cfg.supervisor.linger_s and not unsent_eos(self.stages):
                return False
            self.echo("the sink has finished; stopping the remaining stages")
            self._stop_all()
            for sp in self.stages:
                if sp.state != "done":
                    sp.state = "done"
        result.ok = not self._data_error
        result.error = self._data_error
        return True

    def _needless_restart(self, sp: StageProcess, what: str) -> str:
        """Whether a crashed stage must not be restarted: ``"done"`` when the run is complete
        without it (it was killed after the sink had recorded everything), an error when its
        output can no longer be completed (the sink, killed before it had recorded the run,
        after every other stage had left, with no output to finalize), ``""`` to restart it
        (alone, it finalizes what its predecessor wrote: :func:`sink_left_output`)."""
        others = [o for o in self.stages if o is not sp]
        sinks = [o for o in others if o.role == "sink"]
        if sp.role != "sink":
            if (sinks and all(o.state == "done" for o in sinks)) or (not sinks and all(o.state == "done" for o in others)):
                self.echo(f"stage {sp.role} (pid {sp.pid}) was {what} after the run was recorded: done")
                return "done"
            return ""
        if not all(o.state == "done" for o in others):
            return ""  # a restarted sink records the run, or announces again that it has
        if recorded_complete(self.out / SUMMARY_NAME, self.cfg.run):
            self.echo(f"stage sink (pid {sp.pid}) was {what} after it had recorded the complete run: done")
            return "done"
        return "" if sink_left_output(self.cfg, self.out) else (
            f"stage sink was {what} after every other stage had finished: nothing can resend "
            f"it the run, so its output is incomplete (log: {sp.log_path})")

    def _report_progress(self, t0: float, phase: str = "") -> None:
        if self.progress is None:
            return
        h = self.monitor.latest
        self.progress(Status(time.monotonic() - t0, source=h.get("source"), sink=h.get("sink"),
                             stages={s.role: s.state for s in self.stages}, phase=phase))

    def _stop_all(self) -> None:
        if stop_stages(self.stages, self.cfg.supervisor.stop_timeout_s, self.echo):
            try:
                self._write_stages()
            except OSError as exc:  # disk full: the stages are stopped all the same
                log.error("launcher: cannot write %s: %s", self.out / "stages.json", exc)


def launch(cfg: PipelineConfig, *, echo: Callable[[str], None] | None = None,
           timeout: float | None = None, handle_signals: bool = True,
           overwrite: bool = False, progress: Callable[[Status], Any] | None = None,
           view: bool = False) -> LaunchResult:
    """Run a pipeline to its end (the CLI's ``launch`` and ``replay``).  An ``out`` that holds
    another run is refused unless ``overwrite``; one that holds a live run always.  ``view``:
    start a Rerun viewer and stream the recording to it as well."""
    launcher = Launcher(cfg, echo=echo, timeout=timeout, overwrite=overwrite, progress=progress, view=view)
    old: dict[int, Any] = {}
    if handle_signals and threading.current_thread() is threading.main_thread():
        def on_signal(signum: int, _frame: Any) -> None:
            if echo:
                echo(f"{signal.Signals(signum).name}: stopping every stage (flushing files)")
            launcher.request_stop("interrupted")

        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, on_signal)
    try:
        return launcher.run()
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
