"""Gaps confirmed with the live publishers, look-ahead bounded by the live head, a conflicting
copy of a seq resolved by the publisher (in memory: Sequencer, settle_holes, and the stages on a
MemoryNetwork whose publishers answer the explicit history)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from bnptrack.pipeline.events import Event
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, SUMMARY_NAME, Sequencer
from bnptrack.pipeline.stages.delivery import GAP, RepeatLog, settle_holes
from bnptrack.sources.mcap_log import read_log

from testkit import mem_cfg, offline, run_memory_pipeline, strip


class _Item:
    def __init__(self, payload: bytes) -> None:
        self.payload = payload


class _FakeBus:
    """A bus whose publisher is away (``answers = False``: no head, no fetch) or back."""

    stage = "fake"

    def __init__(self, held: dict[int, bytes]) -> None:
        self.held, self.answers, self.asked = held, False, []

    def head(self, topic: str, timeout: float = 2.0) -> int | None:
        return max(self.held) if self.answers and self.held else None

    def fetch(self, topic: str, lo: int, hi: int, timeout: float = 5.0) -> list[Event]:
        self.asked.append((lo, hi))
        if not self.answers:
            return []
        return [Event(topic, p, {"seq": s}, 0) for s, p in sorted(self.held.items()) if lo <= s <= hi]


def _confirming(bus: _FakeBus) -> Sequencer:
    return Sequencer(window=3, catch_up=100, confirm=True, ask_head=lambda: bus.head("m"))


def test_a_hole_past_the_window_is_not_a_gap_until_the_answering_publisher_lacks_it():
    """Frames 2-9 lost on the way while the router is away, 10-13 arrive: nothing is declared
    (the window alone declares nothing); asking while nobody answers declares nothing; once the
    publisher answers, its copies fill the hole; what it no longer holds (seq 4) is a gap."""
    held = {s: b"f%d" % s for s in range(14) if s != 4}
    bus = _FakeBus(held)
    q = _confirming(bus)
    released = []
    for s in [0, 1, 10, 11, 12, 13]:
        status, out = q.push(s, _Item(held[s]))
        assert status == "accepted"
        released += out
    assert [s for s, _ in released] == [0, 1] and q.gaps == []
    got = settle_holes(bus, "m", q, lambda ev: released.extend(q.push(ev.meta["seq"], _Item(ev.payload))[1]))
    assert got == [] and q.gaps == [] and bus.asked == [(2, 9)]  # asked, nobody answered
    bus.answers = True
    released += settle_holes(bus, "m", q, lambda ev: released.extend(q.push(ev.meta["seq"], _Item(ev.payload))[1]))
    assert q.gaps == [4]
    assert [s for s, _ in released] == list(range(14))
    assert [s for s, item in released if item is GAP] == [4]


def test_a_plain_sequencer_still_declares_by_the_window():
    q = Sequencer(window=3)
    out = []
    for s in [0, 1, 10]:
        out += q.push(s, _Item(b"x"))[1]
    assert q.gaps == list(range(2, 8))


def test_a_sample_past_the_live_head_is_refused_and_declares_nothing():
    bus = _FakeBus({s: b"f%d" % s for s in range(20)})
    bus.answers = True
    q = _confirming(bus)
    for s in range(5):
        q.push(s, _Item(b"f%d" % s))
    status, out = q.push(5 + 99_999, _Item(b"forged"))
    assert status == "ahead" and out == [] and q.gaps == [] and q.pending == 0
    assert "live head 19" in q.far_reason(5 + 99_999)
    status, out = q.push(19, _Item(b"f19"))  # genuine, past the window: within the head
    assert status == "accepted" and q.pending == 1


def test_a_later_different_copy_of_a_buffered_seq_does_not_evict_it():
    q = _confirming(_FakeBus({}))
    q.push(0, _Item(b"a"))
    q.push(2, _Item(b"genuine"))
    status, _ = q.push(2, _Item(b"copy of another frame"))
    assert status == "conflict" and q.buf[2].payload == b"genuine"
    assert q.push(2, _Item(b"genuine"))[0] == "duplicate"


def test_repeated_warnings_are_rate_limited(caplog):
    rl = RepeatLog(first=5, every=100)
    with caplog.at_level(logging.WARNING, logger="bnptrack.stage"):
        for s in range(1000):
            rl.warning("gap %d", s)
    assert len(caplog.records) == 5 + 10  # the first 5, then the 100th, 200th, ..., 1000th
    assert rl.n == 1000


def _same_as_offline(cfg) -> dict:
    log = read_log(Path(cfg.out) / "tracks.mcap")
    frames, ests = offline(cfg)
    assert [f.frame for f in log.frames] == [f.frame for f in frames]
    assert [strip(e) for e in log.tracks] == [strip(e) for e in ests]
    return json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())


def test_frames_lost_on_the_wire_but_held_by_the_publisher_are_fetched_not_declared(tmp_path):
    """Seq 3-10 never arrive live (a router restart); later frames do, far past the window:
    the stages ask the publishers and record every frame, with no gap."""
    cfg = mem_cfg(tmp_path, frames=16, **{"delivery.window": "3"})
    net = MemoryNetwork()
    net.fetchable = True
    lost = set(range(3, 11))

    def tap(run, topic, payload, att):
        if topic in ("measurements", "truth", "tracks") and att and json.loads(att)["seq"] in lost:
            return []
        return [(payload, att)]

    net.tap = tap
    codes = run_memory_pipeline(cfg, net)
    assert codes["sink"] == EXIT_OK and codes["tracker"] == EXIT_OK
    summary = _same_as_offline(cfg)
    assert summary["gaps"] == {"measurements": [], "truth": [], "tracks": []}
    assert summary["output_complete"]


def test_open_mode_far_ahead_and_copied_frames_lose_no_genuine_frame(tmp_path):
    """Anybody may put in open mode: a well-formed sample 99,999 seqs ahead (under
    max_seq_ahead) and a copy of frame seq 2 published as seq 9 (before the genuine seq 9):
    the output is the offline one, nothing is declared missing."""
    cfg = mem_cfg(tmp_path, frames=14, **{"zenoh.auth": "false"})
    net = MemoryNetwork()
    net.fetchable = True

    def tap(run, topic, payload, att):
        out = [(payload, att)]
        meta = json.loads(att) if att else {}
        if topic == "measurements" and meta.get("seq") == 2:
            out.append((payload, json.dumps({**meta, "seq": 9}).encode()))
            out.append((payload, json.dumps({**meta, "seq": 2 + 99_999}).encode()))
        return out

    net.tap = tap
    codes = run_memory_pipeline(cfg, net)
    assert codes["sink"] == EXIT_OK and codes["tracker"] == EXIT_OK
    summary = _same_as_offline(cfg)
    assert summary["gaps"] == {"measurements": [], "truth": [], "tracks": []}
    assert summary["output_complete"] and summary["missing"] == []
