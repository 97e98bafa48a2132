"""A recording written to a file and streamed to a live viewer, the viewer never in the way.

The file and the viewer get two recording streams with the same recording id: every call the
Rerun sink makes goes to the file's stream, then to the viewer's (:class:`FileAndLive`).  At the
end the file is finished first (flush, footer), then the viewer's stream is given
:data:`LIVE_CLOSE_S` seconds to deliver what it holds and disconnect, on a thread of its own: a
viewer that stopped reading (frozen, suspended, gone) costs at most that long and a one-line
warning, and the file is complete whatever the viewer does.  A single stream with two sinks
would not do: its flush and disconnect wait on the slowest sink, and a suspended viewer holds
the file's footer back for ever.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import rerun as rr

#: Seconds a live viewer gets, after the file is finished, to take the rest of the run.
LIVE_CLOSE_S = 5.0

_log = logging.getLogger("bnptrack.rerun")


class FileAndLive:
    """Two recording streams driven as one: ``file`` (whose results are returned) and ``live``
    (a viewer's; its failures are logged once and never raised)."""

    def __init__(self, file: rr.RecordingStream, live: rr.RecordingStream, url: str) -> None:
        self.file, self.live, self.url = file, live, url
        self._live_failed = False

    def __getattr__(self, name: str) -> Any:
        to_file, to_live = getattr(self.file, name), getattr(self.live, name)

        def both(*args: Any, **kwargs: Any) -> Any:
            out = to_file(*args, **kwargs)
            if not self._live_failed:
                try:
                    to_live(*args, **kwargs)
                except Exception as exc:  # the viewer is a display: never stop the file for it
                    self._live_failed = True
                    _log.warning("live view %s: %s (the recording goes on to the file only)", self.url, exc)
            return out

        return both

    def flush(self, timeout_sec: float = 0.0) -> None:
        """Flush the file (waiting up to ``timeout_sec``); ask the viewer's stream to send, without waiting."""
        self.file.flush(timeout_sec=timeout_sec)
        try:
            self.live.flush(timeout_sec=0.0)
        except Exception as exc:
            _log.warning("live view %s: %s", self.url, exc)

    def disconnect(self) -> None:
        """Finish the file, then give the viewer :data:`LIVE_CLOSE_S` seconds on a thread of
        its own; past that it is left behind with a warning."""
        self.file.disconnect()

        def finish_live() -> None:
            try:
                self.live.flush(timeout_sec=LIVE_CLOSE_S)
                self.live.disconnect()
            except Exception as exc:
                _log.warning("live view %s: %s", self.url, exc)

        worker = threading.Thread(target=finish_live, name="rerun-live-close", daemon=True)
        worker.start()
        worker.join(LIVE_CLOSE_S + 1.0)
        if worker.is_alive():
            _log.warning("live view %s did not take the end of the run within %g s (a frozen viewer?); "
                         "left behind, the file is complete", self.url, LIVE_CLOSE_S)


def open_file_and_live(application_id: str, recording_id: str, path: str, url: str, blueprint) -> FileAndLive:
    """The two streams of a recording saved to ``path`` and shown live at ``url``."""
    import time

    file = rr.RecordingStream(application_id, recording_id=recording_id, send_properties=False)
    file.save(path, default_blueprint=blueprint)
    live = rr.RecordingStream(application_id, recording_id=recording_id, send_properties=False)
    live.set_sinks(rr.GrpcSink(url), default_blueprint=blueprint)
    both = FileAndLive(file, live, url)
    both.send_recording_start_time_nanos(time.time_ns())  # one start time, the same in both
    return both
