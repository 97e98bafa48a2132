"""A Rerun recording written by a child process, off the tracker's critical path.

:class:`RecordingProcess` records a run like :func:`sinks.rerun_sink.write_recording` does
(each frame scored by :class:`sinks.run_scorer.RunScorer`, then logged to a
:class:`sinks.rerun_sink.RerunSink`), but the sink runs in a child Python process.  The
tracker's process scores the frame (OSPA and OSPA(2); scipy is loaded there anyway), pickles
``(frame, estimate, scores)`` and writes the bytes to the child's stdin without ever blocking:
the pipe is asked for 1 MiB (a whole 100-frame run) and what it cannot take at once waits in
memory for the next frame.  This module does not import rerun, so creating a
:class:`RecordingProcess` costs the tracker's process a ``fork`` (or ``fork``/``exec``) and
nothing more.  The child is a fork of the tracker's process when that is safe (no other Python
thread, rerun not imported), so that it does not start a new interpreter and import numpy & co.
again; else a new interpreter (``exec``).

Why a process: importing rerun, building the blueprint and the final flush and footer are all
on the critical path in one process (the measured costs are in docs/rerun.md).  The child
starts importing rerun at once, before the run is described to it, so a caller that creates the
process first (``bnptrack track`` does, before it builds the tracker) has those imports run on
the other core beside the tracker's own imports; afterwards the child logs frame ``k`` while
the tracker computes frame ``k + 1``, flushing every :data:`CHILD_FLUSH_INTERVAL` seconds, so
that little is left to send once the input ends.  The child's CPU time is not saved, only moved
off the critical path: on a machine whose cores are busy it shows in the wall time again.

Protocol: the child's stdin carries pickled objects one after another, ``("open", path,
metadata, params, sink_kwargs)`` once, then ``("frame", frame, estimate, scores)`` per frame.
End of input ends the run: the child closes the sink (footer written), writes :data:`_DONE` to
its stdout (the file is complete: :meth:`RecordingProcess.close` returns without waiting for
the process's own exit, which a thread then reaps) and leaves at once (``os._exit``: rerun's
exit hook and the interpreter's teardown would add to the wait).  End of input before ``open`` (an aborted
run) exits without creating a file.

Failures and signals: the child's stderr goes to a temporary file; when the child ends without
:data:`_DONE`, :meth:`RecordingProcess.close` raises :class:`RecordingError` with the tail of
that stderr.  The child runs in a session of its own, so a Ctrl-C at the terminal reaches the
tracker's process only, whose ``close`` (or, if it dies, the end of the pipe) finalises the
file with every frame written to the pipe so far; a SIGTERM sent to the child itself finalises
it too (``RerunSink``'s handler).  A forked child is in the tracker's process group from the
fork until its ``setsid``: SIGINT and SIGQUIT are blocked across the fork, and the child drops
any that came in that window (the tracker's process gets them once the fork returns).  A process
started with SIGINT ignored (a background job of a non-interactive shell, ``nohup``) keeps it
ignored, as Python does: a Ctrl-C does not stop such a run.
"""

from __future__ import annotations

import fcntl
import os
import pickle
import re
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Literal, NoReturn

from bnptrack.sinks.run_scorer import RunScorer
from bnptrack.sinks.records import SinkOptions, SinkRecord

if TYPE_CHECKING:
    from bnptrack.tracker.models.params import ModelParams
    from bnptrack.tracker.types import Estimate, Frame

__all__ = ["RecordingProcess", "RecordingError", "ProcessRecordSink", "CHILD_FLUSH_INTERVAL", "fork_allowed", "child_main",
           "child_entry"]

#: ``RerunSink.flush_interval`` of the child (s), unless ``open`` is given another.
CHILD_FLUSH_INTERVAL = 0.25
#: Root of the source tree that holds ``sinks`` (put first on the child's ``PYTHONPATH``, so the
#: child runs this very code whatever the parent's ``sys.path`` tricks were).
_SOURCE_ROOT = Path(__file__).resolve().parents[1]
_CHILD_CODE = "from bnptrack.sinks.rerun_process import child_entry; child_entry()"
_DONE = b"done\n"
_REAPER = "rerun-recording-reaper"
_PIPE_SIZE = 1 << 20
_STDERR_TAIL = 4000
#: A log line of the Rust SDK (``2026-01-01T00:00:00.000Z ERROR target: text``).
_RUST_LOG_LINE = re.compile(r"^\d{4}-\d\d-\d\dT\S+Z\s+(ERROR|WARN|INFO|DEBUG|TRACE)\b")
#: The OS error its file writer reports (``Failed to write: No space left on device (os error 28)``).
_RUST_OS_ERROR = re.compile(r"Failed to write: ([^()\n]+?) \(os error (\d+)\)")
#: What a Ctrl-C (or Ctrl-\) at the terminal sends to the foreground process group.
_GROUP_SIGNALS = frozenset({signal.SIGINT, signal.SIGQUIT})


class RecordingError(RuntimeError):
    """The recording process failed; the message ends with the tail of its stderr."""


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    paths = [str(_SOURCE_ROOT), *filter(None, env.get("PYTHONPATH", "").split(os.pathsep))]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    env.setdefault("CI", "1")  # the SDK sends nothing; no rerun CLI runs in the child either
    return env


def fork_allowed() -> bool:
    """Whether this process may fork the child: POSIX, no other Python thread (but the
    reapers of earlier children, which only wait in ``waitpid``), and rerun not imported (its
    runtime threads would be missing in the fork)."""
    here = threading.current_thread()
    others = [t for t in threading.enumerate() if t is not here and t.name != _REAPER]
    return (hasattr(os, "fork") and not others
            and "rerun" not in sys.modules and "rerun_bindings" not in sys.modules)


def _start_child(start: str, stderr: IO[bytes]) -> subprocess.Popen[bytes] | _ForkedChild:
    if start not in ("auto", "fork", "exec"):
        raise ValueError(f"start must be 'auto', 'fork' or 'exec', got {start!r}")
    if start == "fork" and not fork_allowed():
        raise RuntimeError("RecordingProcess(start='fork'): not while rerun is imported or "
                           "other threads run here; use 'exec'")
    if start != "exec" and fork_allowed():
        return _ForkedChild(stderr.fileno())
    return subprocess.Popen(
        [sys.executable, "-c", _CHILD_CODE], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        stderr=stderr, env=_child_env(), start_new_session=True,
    )


class _ForkedChild:
    """The child as a fork of this process, with the part of ``subprocess.Popen``'s surface
    that :class:`RecordingProcess` uses (``stdin``, ``stdout``, ``kill``, ``wait``,
    ``returncode``)."""

    def __init__(self, stderr_fd: int) -> None:
        in_r, in_w = os.pipe()
        out_r, out_w = os.pipe()
        sys.stdout.flush()  # so that the fork inherits no buffered output to write again
        sys.stderr.flush()
        # a Ctrl-C between the fork and the child's setsid would reach the child too: blocked
        # across the fork; the child drops it (_leave_group), this process gets it after
        old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, _GROUP_SIGNALS)
        try:
            self.pid = os.fork()
            if self.pid == 0:
                _forked_main(in_r, out_w, stderr_fd, old_mask)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)
        os.close(in_r)
        os.close(out_w)
        self.stdin: IO[bytes] = os.fdopen(in_w, "wb", buffering=0)
        self.stdout: IO[bytes] = os.fdopen(out_r, "rb", buffering=0)
        self.returncode: int | None = None

    def kill(self) -> None:
        if self.returncode is None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.returncode is None:
            pid, status = os.waitpid(self.pid, 0 if deadline is None else os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
            elif time.monotonic() > deadline:  # type: ignore[operator]
                raise subprocess.TimeoutExpired("rerun_process child", timeout or 0.0)
            else:
                time.sleep(0.005)
        return self.returncode


class _Outbox:
    """Writes bytes to a pipe without blocking: what the pipe cannot take now is kept and goes
    with the next :meth:`send`, or at :meth:`finish`.  A closed reader (the child died) makes
    it :attr:`broken`; everything is dropped from then on."""

    def __init__(self, pipe: IO[bytes]) -> None:
        self._pipe = pipe
        self._fd = pipe.fileno()
        self._pending = bytearray()
        self.broken = False
        os.set_blocking(self._fd, False)
        try:  # Linux: room for a whole short run while the child still imports rerun
            fcntl.fcntl(self._fd, fcntl.F_SETPIPE_SZ, _PIPE_SIZE)
        except (AttributeError, OSError):  # no such call, or above /proc/sys/fs/pipe-max-size
            pass

    def send(self, data: bytes) -> None:
        if not self.broken:
            self._pending += data
            self._write()

    def finish(self, deadline: float) -> bool:
        """Write what is left (waiting for the reader until ``deadline``, a ``time.monotonic``
        value) and close the pipe; ``False`` if the deadline passed first."""
        while self._pending and not self.broken:
            if not select.select([], [self._fd], [], max(deadline - time.monotonic(), 0.0))[1]:
                return False
            self._write()
        self.close()
        return True

    def close(self) -> None:
        try:
            self._pipe.close()
        except OSError:
            pass

    def _write(self) -> None:
        try:
            while self._pending:
                del self._pending[:os.write(self._fd, self._pending)]
        except BlockingIOError:  # the pipe is full: the rest waits
            pass
        except BrokenPipeError:  # the child is gone: close() reports why
            self.broken = True
            self._pending.clear()


class RecordingProcess:
    """``RunScorer`` here, ``RerunSink`` in a child process fed through a pipe.

    Create it as early as possible (the child imports rerun at once), then :meth:`open` the
    recording, :meth:`log` each frame and :meth:`close`.  As a context manager, leaving the
    block closes it, whether by an exception or not: the recording is finalised with the frames
    logged so far, or, if it was never opened, the child is killed (nothing to write).

    Args:
        timeout: seconds :meth:`close` waits for the child to finish the file before killing it.
        start: how the child starts.  ``"fork"``: a fork of this process, which skips a new
            interpreter and the imports this process already has (numpy, the tracker's types,
            ...; docs/rerun.md has the measured cost); allowed only while this process has no other Python
            thread and has not imported rerun (whose native threads a fork would not carry
            over).  ``"exec"``: a new interpreter.  ``"auto"`` (default): fork when allowed,
            else exec.
    """

    def __init__(self, *, timeout: float = 120.0,
                 start: Literal["auto", "fork", "exec"] = "auto") -> None:
        self.timeout = float(timeout)
        self.path: Path | None = None
        self._closed = False
        self._stderr: IO[bytes] = tempfile.TemporaryFile()
        self._proc = _start_child(start, self._stderr)
        self._outbox = _Outbox(self._proc.stdin)
        self._scorer = RunScorer()

    # -- public ------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def open(self, path: str | os.PathLike, *, metadata: Mapping[str, str] | None = None,
             params: ModelParams | None = None, **sink_kwargs: Any) -> None:
        """Start the recording ``path`` (``sink_kwargs`` go to ``RerunSink``; ``flush_interval``
        defaults to :data:`CHILD_FLUSH_INTERVAL`).

        The parent directory is created and the file opened for writing here, so that an
        unwritable path fails at once (``OSError``), not after the run.
        """
        if self.path is not None:
            raise RuntimeError(f"RecordingProcess: already recording {self.path}")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.open("ab").close()
        self.path = path
        sink_kwargs.setdefault("flush_interval", CHILD_FLUSH_INTERVAL)
        self._put(("open", os.fspath(path), dict(metadata or {}), params, sink_kwargs))

    def log(self, frame: Frame, estimate: Estimate, scores: Mapping[str, Any] | None = None) -> None:
        """Score one frame and hand it, its estimate and the scores to the child (pickled now:
        later changes to the objects do not reach the recording).  ``scores``: the
        frame's whole :meth:`RunScorer.update` result when the caller has scored the run (not
        scored again here)."""
        if self.path is None:
            raise RuntimeError("RecordingProcess.log before open")
        if scores is None:
            scores = self._scorer.update(frame, estimate)
        self._put(("frame", frame, estimate, {"ospa": scores.get("ospa"), "ospa2": scores.get("ospa2")}))

    def close(self) -> None:
        """End the input and wait until the child reports the file complete; raises
        :class:`RecordingError` if it failed or took longer than ``timeout``.  Before
        :meth:`open` this is :meth:`abort` (nothing to finalise).  Idempotent."""
        if self._closed:
            return
        if self.path is None:
            self.abort()
            return
        self._closed = True
        deadline = time.monotonic() + self.timeout
        if not (self._outbox.finish(deadline) and self._wait_done(deadline)):
            self._proc.kill()
            self._proc.wait()
            self._proc.stdout.close()  # type: ignore[union-attr]
            raise self._failure(f"did not finish within {self.timeout:g} s")
        self._proc.stdout.close()  # type: ignore[union-attr]
        if self._proc.returncode is not None:  # ended without reporting the file complete
            raise self._failure(f"exited with code {self._proc.returncode}")
        self._stderr.close()
        # the file is complete; the child exits on its own shortly after.  A
        # (non-daemon) thread reaps it, so that this process's exit waits for it too
        threading.Thread(target=self._proc.wait, name=_REAPER).start()

    def abort(self) -> None:
        """Kill the child at once (no recording is finalised; idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._proc.kill()
        self._outbox.close()
        self._proc.wait()
        self._proc.stdout.close()  # type: ignore[union-attr]
        self._stderr.close()

    def __enter__(self) -> RecordingProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------
    def _put(self, msg: tuple[Any, ...]) -> None:
        if self._closed:
            raise RuntimeError("RecordingProcess is closed")
        self._outbox.send(pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL))

    def _wait_done(self, deadline: float) -> bool:
        """Read the child's stdout until :data:`_DONE` (the file is complete) or its end (the
        child ended without it: ``returncode`` is then set).  ``False`` at the deadline."""
        fd = self._proc.stdout.fileno()  # type: ignore[union-attr]
        said = b""
        while _DONE not in said:
            if not select.select([fd], [], [], max(deadline - time.monotonic(), 0.0))[0]:
                return False
            chunk = os.read(fd, 256)
            if not chunk:
                try:
                    self._proc.wait(timeout=max(deadline - time.monotonic(), 1.0))
                except subprocess.TimeoutExpired:
                    return False
                return True
            said += chunk
        return True

    def _failure(self, what: str) -> Exception:
        """The child's failure as one line: an OSError naming the file when its file writer
        reported one (disk full, I/O error), else a :class:`RecordingError` with its last
        Python error line; the Rust SDK's log lines are not repeated."""
        self._stderr.seek(0)
        tail = self._stderr.read().decode("utf-8", "replace")[-_STDERR_TAIL:]
        self._stderr.close()
        return child_failure(tail, self.path, what)


def child_failure(stderr: str, path: Path | None, what: str) -> Exception:
    """The recording child's failure from its ``stderr``, as one line (see
    :meth:`RecordingProcess._failure`)."""
    os_error = _RUST_OS_ERROR.search(stderr)
    if os_error is not None and path is not None:
        return OSError(int(os_error.group(2)), os_error.group(1), str(path))
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip() and not _RUST_LOG_LINE.match(ln.strip())]
    target = f" writing {path}" if path is not None else ""
    return RecordingError(f"the Rerun recording process{target} {what}" + (f": {lines[-1]}" if lines else ""))


class ProcessRecordSink:
    """The Rerun recording as a :class:`sinks.sink.Sink` written by a :class:`RecordingProcess`
    (the ``rerun`` entry of :data:`sinks.sink.SINKS` with ``SinkOptions.process``: ``bnptrack
    track --rrd``).  Building it starts the child, so that its imports overlap the caller's
    (build it before the tracker).  Records without frame or estimate draw nothing; their
    ``scores``, when given, are drawn as they are (else the frame is scored here)."""

    def __init__(self, options: SinkOptions) -> None:
        self.options = options
        self.recorder = RecordingProcess()

    def open(self, metadata: Mapping[str, str] | None) -> None:
        o = self.options.now()
        meta = dict(metadata or {})
        if o.source is not None:
            meta["source_log"] = o.source
        kw = {"live": o.live} if o.live else {}
        self.recorder.open(o.path, metadata=meta, params=o.params, **kw)

    def write(self, record: SinkRecord) -> None:
        if record.frame is not None and record.estimate is not None:
            self.recorder.log(record.frame, record.estimate, scores=record.scores)

    def close(self) -> None:
        self.recorder.close()


# --------------------------------------------------------------------------- the child


def _messages(stream: IO[bytes]) -> Iterator[tuple[Any, ...]]:
    """The pickled messages of ``stream`` until its end.  A message cut short (the writer
    died while sending it) ends the input like the end of the stream does."""
    while True:
        try:
            yield pickle.load(stream)
        except EOFError:
            return
        except pickle.UnpicklingError as exc:
            print(f"rerun_process: input cut short ({exc}); finishing the recording", file=sys.stderr)
            return


def child_main(stream: IO[bytes]) -> bool:
    """Import rerun, wait for ``open``, log every frame until the end of ``stream``, close the
    sink.  Returns whether a recording was written (``False``: the input ended before ``open``)."""
    from bnptrack.sinks.rerun_sink import RerunSink  # the slow import (rerun), before any message

    messages = _messages(stream)
    first = next(messages, None)
    if first is None:
        return False
    kind, path, metadata, params, sink_kwargs = first
    if kind != "open":
        raise ValueError(f"rerun_process: expected 'open' first, got {kind!r}")
    with RerunSink(path, metadata=metadata, params=params, **sink_kwargs) as sink:
        for kind, frame, estimate, scores in messages:
            if kind != "frame":
                raise ValueError(f"rerun_process: unexpected message {kind!r}")
            sink.log(frame, estimate, **scores)
    return True


def _serve(stream: IO[bytes], report_fd: int) -> None:
    """:func:`child_main` on ``stream``, then :data:`_DONE` on ``report_fd`` if it wrote a
    recording."""
    if child_main(stream):
        sys.stdout.flush()
        sys.stderr.flush()
        os.write(report_fd, _DONE)


def child_entry() -> None:
    """The child started with ``exec``: :func:`_serve` on stdin, reporting on stdout, then an
    immediate exit (no teardown).  Anything else printed goes to stderr, not to the report.
    An exception ends the process the usual way (traceback on stderr, exit code 1)."""
    report_fd = os.dup(1)
    os.dup2(2, 1)
    _serve(sys.stdin.buffer, report_fd)
    os._exit(0)


def _leave_group(mask: set[signal.Signals]) -> None:
    """A session of its own, then drop the terminal's signals sent to the parent's group while
    this process was still in it (blocked since before the fork; setting a pending signal to
    ``SIG_IGN`` discards it), put their handlers back and restore the signal mask ``mask``."""
    os.setsid()
    for sig in _GROUP_SIGNALS:
        old = signal.signal(sig, signal.SIG_IGN)
        if old is not None:  # None: not a handler set from Python (stays ignored here)
            signal.signal(sig, old)
    signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def _forked_main(in_fd: int, report_fd: int, stderr_fd: int, mask: set[signal.Signals]) -> NoReturn:
    """The child started with ``fork``: a session of its own (:func:`_leave_group`; ``mask``
    is the signal mask of the parent before the fork), stdin from ``/dev/null``, stdout
    and stderr to the stderr file, every other inherited descriptor closed (another pipe's
    write end held here would keep that pipe's reader from ever seeing its end), then
    :func:`_serve`.  It never returns
    into the parent's code: exit code 0, or 1 after a traceback."""
    code = 1
    try:
        _leave_group(mask)
        in_fd, report_fd = (fcntl.fcntl(fd, fcntl.F_DUPFD, 3) for fd in (in_fd, report_fd))
        os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
        os.dup2(stderr_fd, 1)
        os.dup2(stderr_fd, 2)
        keep = sorted({0, 1, 2, in_fd, report_fd})
        for lo, hi in zip(keep, [*keep[1:], os.sysconf("SC_OPEN_MAX")]):
            os.closerange(lo + 1, hi)
        _serve(os.fdopen(in_fd, "rb"), report_fd)
        code = 0
    except BaseException:  # noqa: BLE001 - reported, and never back into the parent's stack
        traceback.print_exc()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
