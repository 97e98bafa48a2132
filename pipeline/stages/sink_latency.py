"""The sink's latency figures (``sink.json``'s ``latency``, the health counters' p50/p99, the
launcher's summary line): which written ``/tracks`` are timed, and what they say.

A latency is a frame's first delivery: the time from the source's publication (``t`` of the
attachment) to this sink process's receipt of the frame's ``/tracks``.  A sink that
(re)starts while the run is going receives the run so far from the publishers' caches (the
Zenoh history, a restarted tracker's journal): those samples were published before it
subscribed (the tracker's ``t_out``, else the source's ``t``, is earlier than the
subscription): a re-delivery, or a frame published while no sink ran.  Its "latency" is the
age of the frame (seconds, the outage and the catch-up), not the pipeline's per-frame latency,
and its first delivery was timed by the killed process, if at all.  Each sink process saves its timed
frames to :data:`LATENCY_PART` (about once a second) and a restarted one reads them back first:
a re-delivered frame keeps its predecessor's first-delivery latency; one that no process timed
(not yet saved when the predecessor was killed, or published while no sink ran) is written like
every frame but not timed, and ``excluded`` counts it (and the frames recovered from a killed
sink's ``.part`` file, which carry no time stamp).  A frame that waited live (a restarted tracker
catching up) is timed: its delay is real (docs/pipeline.md, "Latency after a restart").
"""

from __future__ import annotations

import logging
import os
from collections.abc import MutableSequence
from pathlib import Path
from typing import IO, Any

import msgspec

__all__ = ["LatencyBook", "LATENCY_PART"]

log = logging.getLogger("bnptrack.stage")

#: The timed frames of a run's sink processes so far, in the output directory until the run's
#: ``sink.json`` holds them: a line ``{"run": RUN}``, then one JSON line per frame.
LATENCY_PART = ".sink.latency.part"


def _int(v: Any) -> int | None:
    return v if isinstance(v, int) and not isinstance(v, bool) and v > 0 else None


class LatencyBook:
    """The timed frames of one sink process.  ``since_ns``: when it subscribed (its clock),
    set by :meth:`subscribed`; ``counter``: the health counters' latency samples (appended
    with each timed frame)."""

    def __init__(self, counter: MutableSequence[float]) -> None:
        self.counter = counter
        self.since_ns: int | None = None
        self.seq: list[int] = []
        self.e2e_ms: list[float] = []
        self.tracker_ms: list[float] = []
        self.hop_ms: list[tuple[float, float, float]] = []
        self.handoff_ms: list[float] = []  # the tracker's callback -> main thread (t_deq - t_in)
        self.meas_hop_ms: list[float] = []  # source -> this sink, the frame's /measurements
        self.history: list[int] = []  # seqs from the caches, published before since_ns, not carried
        self.untimed = 0  # written /tracks without a publication time (recovered from a .part file)
        self.last_ms: float | None = None  # the age of the last written frame (progress, health)
        self.n_stamped = 0  # written /tracks with a publication time (timed or history)
        self.t_first_pub_ns: int | None = None
        self.t_last_ns: int | None = None
        self.carried: set[int] = set()  # seqs timed by an earlier sink process of the run
        self._unsaved: list[list] = []
        self._path: Path | None = None
        self._run = ""
        self._file: IO[bytes] | None = None
        self._saved_at = float("-inf")

    def subscribed(self, t_ns: int) -> None:
        self.since_ns = int(t_ns)

    # -- across sink processes -------------------------------------------------------------
    def carry_over(self, path: Path, run: str) -> None:
        """Take the frames that earlier sink processes of run ``run`` timed and saved at
        ``path`` (none: no such file, or another run's), and save this process's there too."""
        self._path, self._run = path, run
        try:
            lines = path.read_bytes().split(b"\n")
        except OSError:
            return
        try:
            if msgspec.json.decode(lines[0]).get("run") != run:
                return
        except (msgspec.DecodeError, AttributeError):
            return
        try:
            self._file = open(path, "ab")  # noqa: SIM115 (closed by discard)
        except OSError as exc:
            self._give_up(exc)
        for line in lines[1:]:
            try:
                seq, e2e, tracker, hop, handoff, meas_hop = msgspec.json.decode(line)
            except (msgspec.DecodeError, ValueError, TypeError):
                continue  # the torn last line of a killed process
            self._add(int(seq), e2e, tracker, tuple(hop) if hop else None, handoff, meas_hop)
            self.carried.add(int(seq))

    def save_due(self, now: float, every: float = 1.0) -> None:
        """Save the frames timed since the last save, at most every ``every`` seconds."""
        if self._unsaved and now - self._saved_at >= every:
            self._saved_at = now
            self.save()

    def save(self) -> None:
        """Append the frames timed since the last save (best effort: the run goes on without
        the file when it cannot be written; a restarted sink then times fewer frames)."""
        if not self._unsaved or self._path is None:
            return
        try:
            if self._file is None:
                self._file = open(self._path, "wb")  # noqa: SIM115 (closed by discard)
                self._file.write(msgspec.json.encode({"run": self._run}) + b"\n")
            self._file.write(b"".join(msgspec.json.encode(r) + b"\n" for r in self._unsaved))
            self._file.flush()  # in the kernel: it survives a SIGKILL of this process
        except OSError as exc:
            self._give_up(exc)
        self._unsaved.clear()

    def _give_up(self, exc: OSError) -> None:
        log.warning("sink: cannot save the timed frames to %s (%s): a restarted sink would not have them",
                    self._path, exc)
        self.discard()
        self._path = None

    def discard(self) -> None:
        """Close and remove the file (the run's ``sink.json`` holds the figures now)."""
        f, self._file = self._file, None
        try:
            if f is not None:
                f.close()
        except OSError:  # a full disk: nothing more to do with it
            pass
        if self._path is not None:
            try:
                os.unlink(self._path)
            except OSError:  # gone already
                pass

    def note(self, s: int, tracks: Any, meas: Any = None) -> None:
        """Frame ``s``'s written ``/tracks`` (an ``Accepted``), with its ``/measurements``
        (``meas``; ``None`` when missing): timed when first delivered, else counted."""
        meta = tracks.meta
        t_pub = _int(meta.get("t"))
        if t_pub is None:
            self.untimed += s not in self.carried
            return
        self.n_stamped += 1
        self.t_last_ns = tracks.t_recv_ns
        if self.t_first_pub_ns is None:
            self.t_first_pub_ns = t_pub
        self.last_ms = (tracks.t_recv_ns - t_pub) / 1e6
        t_out = _int(meta.get("t_out")) or t_pub
        if s in self.carried:  # timed on its first delivery, to an earlier sink process
            return
        if self.since_ns is not None and t_out < self.since_ns:
            self.history.append(s)
            return
        self._time(s, tracks, t_pub, meas)

    def _time(self, s: int, tracks: Any, t_pub: int, meas: Any) -> None:
        meta = tracks.meta
        t_in, t_out, t_deq = _int(meta.get("t_in")), _int(meta.get("t_out")), _int(meta.get("t_deq"))
        hop = None
        if t_in is not None and t_out is not None:
            hop = ((t_in - t_pub) / 1e6, (t_out - t_in) / 1e6, (tracks.t_recv_ns - t_out) / 1e6)
        handoff = (t_deq - t_in) / 1e6 if t_in is not None and t_deq is not None else None
        meas_hop = None
        if meas is not None and _int(meas.meta.get("t")) is not None:
            meas_hop = (meas.t_recv_ns - meas.meta["t"]) / 1e6
        rec = [s, (tracks.t_recv_ns - t_pub) / 1e6, float(tracks.msg.diagnostics.get("ms", float("nan"))),
               hop, handoff, meas_hop]
        self._add(*rec)
        if self._path is not None:
            self._unsaved.append(rec)

    def _add(self, s: int, e2e: float, tracker: float, hop: Any, handoff: float | None,
             meas_hop: float | None) -> None:
        self.seq.append(s)
        self.e2e_ms.append(e2e)
        self.counter.append(e2e)
        self.tracker_ms.append(tracker)
        if hop is not None:
            self.hop_ms.append(hop)
        if handoff is not None:
            self.handoff_ms.append(handoff)
        if meas_hop is not None:
            self.meas_hop_ms.append(meas_hop)

    def throughput_fps(self) -> float | None:
        """Frames per second from the first stamped frame's publication to the last
        ``/tracks``' receipt, over the frames with a publication time (a restarted sink's
        history included: its span starts at the run's first frame)."""
        if self.t_first_pub_ns is None or self.t_last_ns is None or self.n_stamped < 2:
            return None
        return self.n_stamped / max((self.t_last_ns - self.t_first_pub_ns) / 1e9, 1e-9)

    def as_dict(self) -> dict[str, Any]:
        """``sink.json``'s ``latency``: the timed frames' figures, aligned on ``seq`` (the hop
        lists hold the frames whose attachment has the stamps), and what was not timed."""
        return {"seq": self.seq, "e2e_ms": self.e2e_ms, "tracker_ms": self.tracker_ms,
                "source_to_tracker_ms": [h[0] for h in self.hop_ms],
                "in_tracker_ms": [h[1] for h in self.hop_ms],
                "tracker_to_sink_ms": [h[2] for h in self.hop_ms],
                "tracker_handoff_ms": self.handoff_ms,
                "source_to_sink_measurements_ms": self.meas_hop_ms,
                "timed_frames": len(self.seq),
                "timed_by_earlier_sink": len(self.carried),
                "excluded": {"from_caches": len(self.history), "recovered": self.untimed},
                "from_caches_seq": _ranges(self.history)}


def _ranges(seqs: list[int]) -> list[list[int]]:
    """``seqs`` (ascending) as ``[first, last]`` runs."""
    out: list[list[int]] = []
    for s in seqs:
        if out and s == out[-1][1] + 1:
            out[-1][1] = s
        else:
            out.append([s, s])
    return out
