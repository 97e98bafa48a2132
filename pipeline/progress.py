"""Progress lines of a running pipeline (``bnptrack launch`` / ``replay``).

The launcher calls :meth:`Progress.update` about once a second with a :class:`Status`: the
latest health messages of the source and the sink (the sink's carries the frames written,
the last frame's latency and the running scores, see ``SinkStage._sink_health``) and how
long the run has been going.  :func:`progress_line` turns that into one line::

    [  4.0 s] frames 31 (10.0/s), behind 0 frames / 2.3 ms, tracks 9, OSPA 24.1 m (mean 26.8)

On a terminal the line is rewritten in place (carriage return); otherwise (a pipe, a file,
CI logs) every update is a plain line.  :meth:`Progress.echo` prints other messages without
garbling the line in place.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import IO, TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bnptrack.pipeline.stages.summary import RunSummary

__all__ = ["Status", "Progress", "progress_line", "describe_latency", "describe_rejected"]


@dataclass
class Status:
    """What the launcher knows of a running pipeline.  ``source`` / ``sink``: their latest
    ``health/<stage>`` documents (``None`` before the first); ``elapsed_s`` since launch."""

    elapsed_s: float
    source: dict[str, Any] | None = None
    phase: str = ""  # "checking": the configuration is being checked, nothing started yet;
    # "final": the stages have ended (the line is printed whenever the last one was)
    sink: dict[str, Any] | None = None
    stages: dict[str, str] = field(default_factory=dict)


def _published(source: dict[str, Any] | None) -> int | None:
    if not source:
        return None
    return int((source.get("counters") or {}).get("published", 0))


def progress_line(st: Status, fps: float | None) -> str:
    """One progress line (no newline): frames done and their rate, how far the sink is behind
    the source (frames published but not yet recorded, and the latency of the last recorded
    frame; not the fixed lag of ``--lag``), the
    tracks of the last frame and, when the frames carry truth, the last and mean OSPA."""
    head = f"[{st.elapsed_s:6.1f} s]"
    if st.phase == "checking":
        return f"{head} checking the configuration (tracker, source, paths) before starting anything"
    sink = st.sink
    if sink is None:
        waiting = ", ".join(k for k, v in st.stages.items() if v == "running") or "the stages"
        return f"{head} starting: waiting for {waiting} (frames 0)"
    done = int(sink.get("frames_written", 0))
    pub = _published(st.source)
    if not done and not pub:
        return f"{head} frames 0: the sink is ready, waiting for the first frame"
    parts = [f"frames {done}" + (f" ({fps:.1f}/s)" if fps is not None else "")]
    behind = []
    if pub is not None:
        n = max(pub - done, 0)
        behind.append(f"{n} frame{'' if n == 1 else 's'}")
    lat = sink.get("last_latency_ms")
    if lat is not None:
        behind.append(f"{lat:.1f} ms")
    if behind:
        parts.append("behind " + " / ".join(behind))
    scores = sink.get("scores") or {}
    parts.append(f"tracks {scores.get('tracks', 0)}")
    if scores.get("ospa") is not None:
        parts.append(f"OSPA {scores['last_ospa']:.1f} m (mean {scores['ospa']:.1f})")
    return f"{head} " + ", ".join(parts)


class Progress:
    """Print progress lines to ``stream`` (default stderr), at most one per ``period`` s.

    ``tty`` (default: ``stream.isatty()``): rewrite one line in place; otherwise plain lines.
    """

    def __init__(self, stream: IO[str] | None = None, *, tty: bool | None = None, period: float = 1.0) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.period = float(period)
        self._last_t: float | None = None
        self._last_line = ""  # the last line printed
        self._last_frames: tuple[int, int] | None = None  # (frames, sink health t_ns)
        self._fps: float | None = None
        self._open = False  # a line in place is on screen
        self._transient = False  # ... and it is the "checking" line

    def _rate(self, sink: dict[str, Any] | None) -> float | None:
        """Frames per second between the last two sink health messages."""
        if not sink or not isinstance(sink.get("t_ns"), int):
            return self._fps
        now = (int(sink.get("frames_written", 0)), int(sink["t_ns"]))
        prev = self._last_frames
        if prev is not None and now[1] > prev[1]:
            # a restarted sink counts its frames again from 0: no rate until it has two points
            self._fps = (now[0] - prev[0]) / ((now[1] - prev[1]) / 1e9) if now[0] >= prev[0] else None
        if prev is None or now[1] > prev[1]:
            self._last_frames = now
        return self._fps

    def update(self, st: Status, force: bool = False) -> bool:
        """Print a line if one is due (or ``force``); True if printed.  The ``checking`` line
        (before the configuration checks) is shown on a terminal only, and erased if nothing
        follows it (a configuration error stays one line: ``Error: ...``)."""
        if st.phase == "checking":
            if self.tty:
                self.stream.write("\r\x1b[2K" + progress_line(st, None))
                self.stream.flush()
                self._open = self._transient = True
            return self.tty
        self._transient = False
        force = force or st.phase == "final"
        if not force and self._last_t is not None and st.elapsed_s - self._last_t < self.period:
            return False
        line = progress_line(st, self._rate(st.sink))
        if line == self._last_line:  # the final line of a run whose last update said it all
            return False
        self._last_t, self._last_line = st.elapsed_s, line
        if self.tty:
            self.stream.write("\r\x1b[2K" + line)
            self._open = True
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        return True

    def echo(self, msg: str) -> None:
        """Print a message on its own line (ending a line in place first)."""
        self.close()
        self.stream.write(msg + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End the line in place, if any (before the summary); erase it if it is the
        ``checking`` line."""
        if self._open:
            self.stream.write("\r\x1b[2K" if self._transient else "\n")
            self.stream.flush()
            self._open = self._transient = False


def describe_latency(summary: RunSummary | None, paced: bool = True) -> str:
    """The summary's latency line from ``sink.json`` (``""``: nothing to say): p50 and p99 of
    the frames timed on their first delivery and, when some were not timed, how many and why
    -- received from the publishers' caches by a restarted (or late) sink, published before it
    subscribed (re-deliveries; their age measures the outage, not the pipeline), recovered from a
    killed sink's ``.part`` file (:mod:`pipeline.stages.sink_latency`)."""
    if summary is None:
        return ""
    lat = summary.counters.get("latency_ms") or {}
    book = summary.latency
    excluded = book.get("excluded") or {}
    why = [f"{n} {what}" for n, what in (
        (int(excluded.get("from_caches") or 0), "from the caches, published before the restarted sink subscribed"),
        (int(excluded.get("recovered") or 0), "recovered from the killed sink's .part file")) if n]
    text = ""
    if lat.get("p50") is not None:
        text = f"source -> sink p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms"
        if why:
            text += f" over {int(book.get('timed_frames', lat.get('n')) or 0)} frame(s)"
    elif why:
        text = "no frame timed"
    if why:
        text += f" (not timed: {', '.join(why)})"
    if text and lat.get("p50") is not None and not paced:
        text += " (frames published as fast as possible: includes queueing)"
    return text


def describe_rejected(summary: RunSummary) -> str:
    """The summary's ``rejected`` row from ``sink.json``: the samples the sink rejected and the
    duplicates it dropped -- counted by the sink process that finished the run, which says so
    when it was restarted (its predecessor's counts died with it; its dead letters are in
    ``health.jsonl``)."""
    c = summary.counters
    text = f"{c.get('rejected', 0)} (duplicates dropped: {c.get('duplicates', 0)})"
    if summary.restarted:
        text += "; counted by the restarted sink since its restart"
    return text
