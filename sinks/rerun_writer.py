"""A Rerun recording written by a child process, off the tracker's critical path.

:class:`RecordingProcess` records a run like :func:`sinks.rerun_sink.write_recording` does
(each frame scored by :class:`sinks.scoring.RunScorer`, then logged to a
:class:`sinks.rerun_sink.RerunSink`), but the sink runs in a child Python process.  The
tracker's process scores the frame (about 0.3 ms: OSPA and OSPA(2); scipy is loaded there
anyway), pickles ``(frame, estimate, scores)`` (about 0.1 ms) and queues the bytes; a feeder
thread writes them to the child's stdin (a blocking pipe write, the GIL released).  This module
does not import rerun, so creating a :class:`RecordingProcess` costs the tracker's process a
``fork``/``exec`` and nothing more.

Why a process: for an offline ``bnptrack track --rrd`` run of 100 vo2017 frames, importing
rerun (0.6-0.8 s of CPU), building the blueprint and the final flush and footer add up to about
0.9 s next to a 2.5-3 s run; in one process all of it is on the critical path.  The child
starts importing rerun at once, before the run is described to it, so a caller that creates the
process first (``bnptrack track`` does, before it builds the tracker) has those imports run on
the other core beside the tracker's own imports; afterwards the child logs frame ``k`` while
the tracker computes frame ``k + 1``.  The child's CPU time is not saved, only moved off the
critical path: on a machine whose cores are all busy it shows in the wall time again.

Protocol (stdin of the child, pickled objects one after another): ``("open", path, metadata,
params, sink_kwargs)`` once, then ``("frame", frame, estimate, scores)`` per frame.  End of
input ends the run: the child closes the sink (footer written) and exits 0.  End of input
before ``open`` (an aborted run) exits 0 without creating a file.

Failures and signals: the child's stderr goes to a temporary file; :meth:`RecordingProcess.close`
waits for the child and raises :class:`RecordingError` with the tail of that stderr when it
failed.  The child runs in a session of its own, so a Ctrl-C at the terminal reaches the
tracker's process only, whose ``close`` (or, if it dies, the end of the pipe) finalises the
file with every frame sent so far; a SIGTERM sent to the child itself finalises it too
(``RerunSink``'s handler).
"""

from __future__ import annotations

import os
import pickle
import queue
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from sinks.scoring import RunScorer

if TYPE_CHECKING:
    from tracker.models.params import ModelParams
    from tracker.types import Estimate, Frame

__all__ = ["RecordingProcess", "RecordingError", "child_main", "exit_now"]

#: Root of the source tree that holds ``sinks`` (put first on the child's ``PYTHONPATH``, so the
#: child runs this very code whatever the parent's ``sys.path`` tricks were).
_SOURCE_ROOT = Path(__file__).resolve().parents[1]
_CHILD_CODE = "from sinks.rerun_writer import child_main, exit_now; exit_now(child_main())"
_STDERR_TAIL = 4000


class RecordingError(RuntimeError):
    """The recording process failed; the message ends with the tail of its stderr."""


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    paths = [str(_SOURCE_ROOT), *filter(None, env.get("PYTHONPATH", "").split(os.pathsep))]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    env.setdefault("CI", "1")  # the SDK sends nothing; no rerun CLI runs in the child either
    return env


class RecordingProcess:
    """``RunScorer`` here, ``RerunSink`` in a child process fed through a pipe.

    Create it as early as possible (the child imports rerun at once), then :meth:`open` the
    recording, :meth:`log` each frame and :meth:`close`.  As a context manager, leaving the
    block closes it, whether by an exception or not: the recording is finalised with the frames
    logged so far, or, if it was never opened, the child is killed (nothing to write).

    Args:
        timeout: seconds :meth:`close` waits for the child to finish the file before killing it.
    """

    def __init__(self, *, timeout: float = 120.0) -> None:
        self.timeout = float(timeout)
        self.path: Path | None = None
        self._closed = False
        self._stderr: IO[bytes] = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _CHILD_CODE], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
            stderr=self._stderr, env=_child_env(), start_new_session=True,
        )
        self._scorer = RunScorer()
        self._queue: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._broken: OSError | None = None
        self._feeder = threading.Thread(target=self._feed, name="rerun-recording-feeder", daemon=True)
        self._feeder.start()

    # -- public ------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def open(self, path: str | os.PathLike, *, metadata: Mapping[str, str] | None = None,
             params: ModelParams | None = None, **sink_kwargs: Any) -> None:
        """Start the recording ``path`` (``sink_kwargs`` go to ``RerunSink``).

        The parent directory is created and the file opened for writing here, so that an
        unwritable path fails at once (``OSError``), not after the run.
        """
        if self.path is not None:
            raise RuntimeError(f"RecordingProcess: already recording {self.path}")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.open("ab").close()
        self.path = path
        self._put(("open", os.fspath(path), dict(metadata or {}), params, sink_kwargs))

    def log(self, frame: Frame, estimate: Estimate) -> None:
        """Score one frame and hand it, its estimate and the scores to the child (pickled now:
        later changes to the objects do not reach the recording)."""
        if self.path is None:
            raise RuntimeError("RecordingProcess.log before open")
        self._put(("frame", frame, estimate, self._scorer.update(frame, estimate)))

    def close(self) -> None:
        """End the input, wait for the child to finalise the file; raises
        :class:`RecordingError` if it failed.  Before :meth:`open` this is :meth:`abort`
        (nothing to finalise, no need to wait for the child's imports).  Idempotent."""
        if self._closed:
            return
        if self.path is None:
            self.abort()
            return
        self._closed = True
        self._queue.put(None)
        self._feeder.join()
        try:
            code = self._proc.wait(timeout=self.timeout)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
            raise RecordingError(self._failure(f"did not finish within {self.timeout:g} s")) from None
        if code != 0:
            raise RecordingError(self._failure(f"exited with code {code}"))
        self._stderr.close()

    def abort(self) -> None:
        """Kill the child at once (no recording is finalised; idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._proc.kill()
        self._queue.put(None)
        self._feeder.join()
        self._proc.wait()
        self._stderr.close()

    def __enter__(self) -> RecordingProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------
    def _put(self, msg: tuple[Any, ...]) -> None:
        if self._closed:
            raise RuntimeError("RecordingProcess is closed")
        if self._broken is None:  # after a broken pipe, close() reports the child's failure
            self._queue.put(pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL))

    def _feed(self) -> None:
        """Feeder thread: queued messages -> the child's stdin; ``None`` closes it."""
        pipe = self._proc.stdin
        assert pipe is not None
        try:
            while (data := self._queue.get()) is not None:
                pipe.write(data)
                pipe.flush()
        except OSError as exc:  # the child died; its exit code and stderr say why
            self._broken = exc
        finally:
            try:
                pipe.close()
            except OSError:
                pass

    def _failure(self, what: str) -> str:
        self._stderr.seek(0)
        tail = self._stderr.read().decode("utf-8", "replace")[-_STDERR_TAIL:].strip()
        self._stderr.close()
        target = f" writing {self.path}" if self.path is not None else ""
        return f"the Rerun recording process{target} {what}" + (f": {tail}" if tail else "")


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
            print(f"rerun_writer: input cut short ({exc}); finishing the recording", file=sys.stderr)
            return


def child_main(stream: IO[bytes] | None = None) -> int:
    """The child: import rerun, wait for ``open``, then log every frame until the end of
    ``stream`` (default: stdin), then close the sink.  Returns the exit code."""
    from sinks.rerun_sink import RerunSink  # the slow import (rerun), before any message

    messages = _messages(stream if stream is not None else sys.stdin.buffer)
    first = next(messages, None)
    if first is None:
        return 0  # aborted before open: no file
    kind, path, metadata, params, sink_kwargs = first
    if kind != "open":
        raise ValueError(f"rerun_writer: expected 'open' first, got {kind!r}")
    with RerunSink(path, metadata=metadata, params=params, **sink_kwargs) as sink:
        for kind, frame, estimate, scores in messages:
            if kind != "frame":
                raise ValueError(f"rerun_writer: unexpected message {kind!r}")
            sink.log(frame, estimate, **scores)
    return 0


def exit_now(code: int) -> None:
    """Exit the child at once with ``code``, skipping the interpreter's teardown.

    Called once :func:`child_main` has returned, i.e. the sink is closed and the file complete
    (footer written, the stream disconnected).  A normal exit would then spend another 0.2-0.3 s
    in rerun's exit hook and module teardown, all of it on the critical path of
    :meth:`RecordingProcess.close`.  An exception in ``child_main`` never gets here: the
    interpreter prints it and exits with code 1 as usual.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
