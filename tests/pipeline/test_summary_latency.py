"""The latency a run's summary and ``sink.json`` report is that
of first deliveries.  A sink that (re)starts while the run is going receives the run so far
from the publishers' caches; those frames were published before it subscribed, and timing
them from their first publication gave "latency p50 18147 ms" after a sink restart in a
3,000-frame replay.  They are recorded but not timed, and counted (docs/pipeline.md,
"Latency after a restart").  In memory, with stage-level fakes for the source and the tracker."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import msgspec
import pytest

from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.progress import describe_latency, describe_rejected
from bnptrack.pipeline.stages.summary import RunSummary
from bnptrack.pipeline.stages import EXIT_OK, SUMMARY_NAME, ManualClock, part_path, source_frames
from bnptrack.pipeline.stages.health import EndOfStream, StageInfo
from bnptrack.pipeline.stages.sink_latency import LATENCY_PART, LatencyBook
from bnptrack.tracker.messages import encode, from_truth
from bnptrack.tracker.types import Estimate

from testkit import mem_cfg, run_memory_pipeline, wait_until

AGO_NS = 600 * 10**9  # the history was published ten minutes before the sink subscribed


def _publish_frames(src, trk, run: str, frames, seqs, t_of) -> None:
    """What the source and the tracker publish for frames ``seqs``: /measurements, /truth and
    /tracks (an empty estimate) with the attachments of the real stages; ``t_of(seq)`` is
    the source's publication time, the tracker's stamps follow it by 1-3 ms."""
    for s in seqs:
        f = frames[s]
        t = t_of(s)
        src.publish("measurements", encode(f, run), {"seq": s, "t": t, "frame": f.frame, "truth": True})
        src.publish("truth", encode(from_truth(f.frame, f.stamp_ns, f.truth, run)), {"seq": s, "t": t, "frame": f.frame})
        est = Estimate(frame=f.frame, stamp_ns=f.stamp_ns, tracks=(), diagnostics={"ms": 1.0})
        trk.publish("tracks", encode(est, run), {"seq": s, "t": t, "frame": f.frame, "t_in": t + 10**6,
                                                 "t_deq": t + 2 * 10**6, "t_out": t + 3 * 10**6})


def _run_late_sink(tmp_path: Path, n: int, k: int, killed: bool = False,
                   saved: list[tuple[int, float]] = ()) -> tuple[dict, int]:
    """Frames ``0..k-1`` published (by fakes of the source and the tracker, alive) ten minutes
    before the sink stage starts, ``k..n-1`` live once it has subscribed; ``killed``: an earlier
    sink process of the run left its ``.tracks.mcap.part`` (cut short), so this one is a
    restarted sink; ``saved``: (seq, latency in ms) of the frames that process timed and saved
    (:data:`LATENCY_PART`, cut in the middle of the next line).  The sink's ``sink.json`` and
    the time it subscribed at (its clock)."""
    cfg = mem_cfg(tmp_path, frames=n)
    meta, frames = source_frames(cfg)
    frames = list(frames)
    if killed:
        Path(cfg.out).mkdir(parents=True)
        part_path(Path(cfg.out) / "tracks.mcap").write_bytes(b"\x89MCAP0\r\n")  # killed at once
    if saved:
        _save_as_killed(Path(cfg.out) / LATENCY_PART, cfg.run, saved)
    net = MemoryNetwork()
    now = time.time_ns()
    clock = ManualClock(start_ns=now)  # stands still until the source's end of stream
    enc = msgspec.json.encode
    src, trk = net.bus(cfg.run, "source"), net.bus(cfg.run, "tracker")
    src.declare_alive()
    trk.declare_alive()
    src.publish("info/source", enc(StageInfo(stage="source", run=cfg.run, kind="list", metadata=meta)))
    trk.publish("info/tracker", enc(StageInfo(stage="tracker", run=cfg.run, tracker="fake", metadata=meta)))
    _publish_frames(src, trk, cfg.run, frames, range(k), lambda s: now - AGO_NS + s * 20 * 10**6)

    def live() -> None:
        wait_until(lambda: "sink" in net.alive.get((cfg.run, "alive"), set()), 60, "the sink to subscribe")
        _publish_frames(src, trk, cfg.run, frames, range(k, n), lambda s: time.time_ns())
        for bus in (src, trk):
            bus.publish(f"eos/{bus.stage}", enc(EndOfStream(stage=bus.stage, run=cfg.run, last_seq=n - 1, frames=n)))

    feeder = threading.Thread(target=live, daemon=True)
    feeder.start()
    assert run_memory_pipeline(cfg, net, roles=("sink",), clock=clock) == {"sink": EXIT_OK}
    feeder.join(10)
    return json.loads((Path(cfg.out) / SUMMARY_NAME).read_text()), now


def test_a_restarted_sink_times_only_the_frames_delivered_live(tmp_path):
    n, k = 12, 8  # most of the run is history, as after a sink killed late in a run
    s, now = _run_late_sink(tmp_path, n, k, killed=True)
    assert s["complete"] and s["frames_written"] == n and s["tracks_written"] == n  # every frame recorded
    assert s["restarted"] and describe_rejected(RunSummary.of(s)) == (
        "0 (duplicates dropped: 0); counted by the restarted sink since its restart")
    lat = s["latency"]
    assert lat["seq"] == list(range(k, n)) and lat["timed_frames"] == n - k
    assert lat["excluded"] == {"from_caches": k, "recovered": 0}
    assert lat["from_caches_seq"] == [[0, k - 1]]
    assert s["counters"]["latency_ms"]["n"] == n - k
    # the live frames' latency is the time on this machine's loopback, not the history's age
    # (600 s: timing the history would give p50 and p99 of those ages)
    assert all(0 <= e < 60_000 for e in lat["e2e_ms"]) and len(lat["e2e_ms"]) == n - k
    assert s["counters"]["latency_ms"]["p99"] < 60_000
    assert lat["tracker_to_sink_ms"] == pytest.approx([e - 3.0 for e in lat["e2e_ms"]])
    assert lat["in_tracker_ms"] == [2.0] * (n - k) and lat["tracker_handoff_ms"] == [1.0] * (n - k)
    # the throughput spans the run, from frame 0's publication (ten minutes ago) to the end
    span_s = (s["t_last_recv_ns"] - (now - AGO_NS)) / 1e9
    assert s["t_first_pub_ns"] == now - AGO_NS and s["throughput_fps"] == pytest.approx(n / span_s)
    text = describe_latency(RunSummary.of(s))
    p50, p99 = s["counters"]["latency_ms"]["p50"], s["counters"]["latency_ms"]["p99"]
    assert text == (f"source -> sink p50 {p50:.2f} ms, p99 {p99:.2f} ms over {n - k} frame(s) "
                    f"(not timed: {k} from the caches, published before the restarted sink subscribed)")


def test_a_sink_there_from_the_start_times_every_frame(tmp_path):
    s, _ = _run_late_sink(tmp_path, 6, 0)
    assert not s["restarted"] and describe_rejected(RunSummary.of(s)) == "0 (duplicates dropped: 0)"
    lat = s["latency"]
    assert lat["seq"] == list(range(6)) and lat["excluded"] == {"from_caches": 0, "recovered": 0}
    assert lat["from_caches_seq"] == []
    p50, p99 = s["counters"]["latency_ms"]["p50"], s["counters"]["latency_ms"]["p99"]
    assert describe_latency(RunSummary.of(s)) == f"source -> sink p50 {p50:.2f} ms, p99 {p99:.2f} ms"
    assert describe_latency(RunSummary.of(s), paced=False).endswith("(frames published as fast as possible: includes queueing)")


def _save_as_killed(path: Path, run: str, saved) -> None:
    """What a sink process killed after timing and saving the frames ``saved`` leaves."""
    ms = 10**6
    book = LatencyBook([])
    book.carry_over(path, run)
    for seq, e2e in saved:
        book.note(seq, _Acc({"t": 1000 * ms, "t_in": 1001 * ms, "t_out": 1002 * ms}, int(1000 * ms + e2e * ms)))
    book.save()
    book._file.write(b'[99, 1.0, 2.0')  # the kill, in the middle of a line
    book._file.close()


def test_a_restarted_sink_keeps_the_latencies_its_killed_predecessor_timed(tmp_path):
    """The killed sink process timed frames 0-5 live and saved them; 6 and 7 it received but had
    not saved.  Its successor takes 0-5 with their first-delivery latencies, does not time 6-7
    (from the caches) and times 8-11 (live); the saved file is gone once sink.json holds them."""
    n, k = 12, 8
    saved = [(s, 4.0 + s) for s in range(6)]
    s, _ = _run_late_sink(tmp_path, n, k, killed=True, saved=saved)
    lat = s["latency"]
    assert lat["seq"] == [*range(6), *range(k, n)] and lat["timed_frames"] == 10
    assert lat["e2e_ms"][:6] == [4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    assert lat["timed_by_earlier_sink"] == 6 and lat["excluded"] == {"from_caches": 2, "recovered": 0}
    assert lat["from_caches_seq"] == [[6, 7]] and s["counters"]["latency_ms"]["n"] == 10
    assert lat["tracker_to_sink_ms"][:6] == [2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    assert not (tmp_path / "out" / LATENCY_PART).exists()
    assert "over 10 frame(s) (not timed: 2 from the caches, published before the restarted sink subscribed)" in describe_latency(RunSummary.of(s))


def test_a_saved_latency_file_of_another_run_is_ignored_and_replaced(tmp_path):
    path = tmp_path / LATENCY_PART
    _save_as_killed(path, "other", [(0, 5.0)])
    book = LatencyBook([])
    book.carry_over(path, "mine")
    assert book.seq == [] and book.carried == set()
    book.note(3, _Acc({"t": 10**9}, 10**9 + 2 * 10**6))
    book.save()
    again = LatencyBook([])
    again.carry_over(path, "mine")
    assert again.seq == [3] and again.e2e_ms == [2.0] and again.carried == {3}
    again.discard()
    assert not path.exists()


def test_a_latency_file_that_cannot_be_written_does_not_stop_the_sink(tmp_path, caplog):
    """Best effort: the frames stay timed in the process (sink.json); only a restarted sink would
    lack them."""
    book = LatencyBook([])
    book.carry_over(tmp_path / "no such dir" / LATENCY_PART, "mine")
    book.note(0, _Acc({"t": 10**9}, 10**9 + 10**6))
    book.save()  # no directory: warned, not raised
    book.note(1, _Acc({"t": 10**9}, 10**9 + 3 * 10**6))
    book.save()
    book.discard()
    assert book.seq == [0, 1] and book.e2e_ms == [1.0, 3.0]
    assert [r.getMessage().split(" (")[0] for r in caplog.records] == [
        f"sink: cannot save the timed frames to {tmp_path / 'no such dir' / LATENCY_PART}"]


class _Acc:
    """The fields of an ``Accepted`` that the latency book reads."""

    def __init__(self, meta: dict, t_recv_ns: int, ms: float = 4.0) -> None:
        self.meta, self.t_recv_ns = meta, t_recv_ns
        self.msg = type("M", (), {"diagnostics": {"ms": ms}})()


def test_the_latency_book_cuts_at_the_subscription_on_the_trackers_stamp():
    """Hand-computed: subscribed at t=1000 ms.  Frame 0 published by the tracker at 999 ms
    (history: not timed); frame 1 published by the source before the subscription but by the
    tracker after it (a frame that waited live: timed, 1500 ms); frame 2 without a tracker
    stamp falls back to the source's; frame 3 has no stamp at all (recovered from a .part)."""
    ms = 10**6
    counter: list[float] = []
    book = LatencyBook(counter)
    book.subscribed(1000 * ms)
    book.note(0, _Acc({"t": 990 * ms, "t_in": 991 * ms, "t_out": 999 * ms}, 1005 * ms))
    book.note(1, _Acc({"t": 995 * ms, "t_in": 996 * ms, "t_deq": 997 * ms, "t_out": 2490 * ms}, 2495 * ms),
              _Acc({"t": 995 * ms}, 998 * ms))
    book.note(2, _Acc({"t": 2500 * ms}, 2520 * ms))
    book.note(3, _Acc({}, 0))
    assert book.seq == [1, 2] and book.e2e_ms == counter == [1500.0, 20.0]
    assert book.hop_ms == [(1.0, 1494.0, 5.0)] and book.handoff_ms == [1.0] and book.meas_hop_ms == [3.0]
    assert book.last_ms == 20.0  # the age of the last written frame (progress, health)
    d = book.as_dict()
    assert d["excluded"] == {"from_caches": 1, "recovered": 1} and d["from_caches_seq"] == [[0, 0]]
    # three stamped frames from 990 ms to 2520 ms
    assert book.throughput_fps() == pytest.approx(3 / 1.53)
    summary = RunSummary.of({"counters": {"latency_ms": {"n": 2, "p50": 760.0, "p99": 1485.2}}, "latency": d})
    assert describe_latency(summary) == (
        "source -> sink p50 760.00 ms, p99 1485.20 ms over 2 frame(s) (not timed: 1 from the caches, "
        "published before the restarted sink subscribed, 1 recovered from the killed sink's .part file)")
    assert describe_latency(RunSummary.of({"counters": {"latency_ms": {"n": 0, "p50": None}},
                                           "latency": {"excluded": {"from_caches": 0, "recovered": 4}}})) == (
        "no frame timed (not timed: 4 recovered from the killed sink's .part file)")
