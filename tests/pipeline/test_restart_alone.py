"""In memory: a stage restarted after the others have left never hangs,
never truncates a finished output, and finalizes what it has (docs/pipeline.md, "Restart at
any moment").  The same over real processes: tests/integration/test_restart_alone_processes.py."""

from __future__ import annotations

import hashlib
import json
import threading
from pathlib import Path

import msgspec
import pytest

from bnptrack.pipeline.outcome import describe_missing
from bnptrack.pipeline.stages.summary import RunSummary
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import (
    EXIT_DATA,
    EXIT_OK,
    EXIT_STOPPED,
    SNAPSHOT_NAME,
    STAGES,
    SUMMARY_NAME,
    ManualClock,
    StageContext,
    UpstreamGone,
    UpstreamWatch,
    part_path,
    read_snapshot,
    salvage_part,
)
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.mcap_log import read_log, read_metadata

from testkit import mem_cfg, run_memory_pipeline, wait_until

GONE_S = 5.0  # the default delivery.upstream_gone_s
#: how long a stage that must not give up is watched, on its clock: four times upstream_gone_s,
#: past every other grace period of its configuration (eos_grace_s 0.3, linger_s 0.5)
NEVER_S = 4 * GONE_S


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A complete 12-frame run (in memory), its config and its frames as written."""
    cfg = mem_cfg(tmp_path_factory.mktemp("done"), frames=12)
    assert run_memory_pipeline(cfg, MemoryNetwork()) == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    mcap = Path(cfg.out) / "tracks.mcap"
    whole = salvage_part(mcap, cfg.run)
    assert whole is not None and len(whole.frames) == 12
    return cfg, whole


def _killed_sink_dir(tmp_path: Path, finished, k: int, torn: bytes = b"\x08\x01\x02") -> Path:
    """An output directory as a sink killed mid-run leaves it: ``.tracks.mcap.part`` holding
    the first ``k`` frames of the finished run (flushed, no footer) and a torn record."""
    cfg, whole = finished
    out = tmp_path / "out"
    out.mkdir()
    part = part_path(out / "tracks.mcap")
    w = McapLogWriter(part, read_metadata(Path(cfg.out) / "tracks.mcap"))
    for f in whole.frames[:k]:
        w.write_encoded_frame(f.payloads["/measurements"], f.payloads.get("/truth"), f.stamp_ns, f.frame)
        w.write_encoded_tracks(f.payloads["/tracks"], f.stamp_ns, f.frame)
    w.flush()
    cut = part.read_bytes()
    w.close()
    part.write_bytes(cut + torn)  # the kill: no summary, no footer, half a record
    return out


def _run_alone(cfg, role: str, net: MemoryNetwork | None = None, clock: ManualClock | None = None,
               hold: threading.Event | None = None) -> tuple[dict, ManualClock, threading.Thread]:
    """Run stage ``role`` in a thread on a network where nobody else is (unless the test
    says), its clock moving 0.5 s per poll; ``result`` gets the exit code (or the error) and
    the stage's clock when it returned."""
    net = net or MemoryNetwork()
    clock = clock or ManualClock()
    result: dict = {}
    bus = net.bus(cfg.run, role)
    ctx = StageContext(cfg, bus, name=role, clock=clock)
    result["ctx"] = ctx

    def go() -> None:
        try:
            result["code"] = STAGES[role](ctx).run()
        except BaseException as exc:
            result["error"] = exc
        finally:
            result["t"] = clock.monotonic()
            bus.close()

    t = threading.Thread(target=go, daemon=True)
    t.start()
    return result, clock, t


def _drive(clock: ManualClock, t: threading.Thread, timeout: float = 60.0, until: float | None = None) -> None:
    """Move the clock 0.5 s per 20 ms until ``t`` ends (or the clock reaches ``until``)."""
    def step() -> bool:
        if not t.is_alive() or (until is not None and clock.monotonic() >= until):
            return True
        clock.advance(0.5)
        return False

    wait_until(step, timeout, "the stage to finish")


def _cfg_for(finished, out: Path):
    cfg, _ = finished
    return msgspec.structs.replace(cfg, out=str(out))


def test_a_sink_restarted_alone_finalizes_the_killed_sinks_frames_and_exits_3(tmp_path, finished):
    """The earlier sink was killed after 7 frames; the source and tracker are gone (no token,
    no cache).  The restarted sink waits upstream_gone_s on its clock, recovers the 7 frames
    from the .part, writes them as the final tracks.mcap byte for byte as received, and says
    in sink.json that the rest of the run is missing because the upstream was gone."""
    out = _killed_sink_dir(tmp_path, finished, 7)
    cfg = _cfg_for(finished, out)
    result, clock, t = _run_alone(cfg, "sink")
    wait_until(lambda: "sink" in (result.get("ctx").bus.net.alive.get((cfg.run, "alive")) or ()) or not t.is_alive(),
               30, "the sink to declare itself alive")
    _drive(clock, t)
    assert "error" not in result, result.get("error")
    assert result["code"] == EXIT_DATA
    assert result["t"] >= GONE_S  # it waited the whole upstream_gone_s on its clock
    mcap = out / "tracks.mcap"
    assert not part_path(mcap).exists() and not list(out.glob(".*.part"))
    got = salvage_part(mcap, cfg.run)
    want = finished[1].frames[:7]
    assert [f.payloads for f in got.frames] == [f.payloads for f in want]
    log = read_log(mcap)  # a finished, readable MCAP file
    assert [e.frame for e in log.tracks] == [f.frame for f in want] and log.metadata["run"] == cfg.run
    s = json.loads((out / SUMMARY_NAME).read_text())
    assert s["complete"] is False and s["output_complete"] is False
    assert s["recovered_frames"] == 7 and s["frames_written"] == 7 and s["tracks_written"] == 7
    assert [m["topic"] for m in s["missing"]] == ["/measurements", "/truth", "/tracks"]
    for m in s["missing"]:
        assert m["seqs"] == [] and m["from_seq"] == 7
        assert m["why"].startswith("upstream gone before the end of stream: no live source or tracker for 5 s")
        assert "recovered 7 frame(s), up to frame 7" in m["why"]
    line = describe_missing(RunSummary.of(s))
    assert line.startswith("the sink stopped before the end of stream (after seq 6); /measurements from seq 7 on: "
                           "upstream gone before the end of stream")


def test_a_sink_started_again_after_an_incomplete_finalized_run_never_truncates_it(tmp_path, finished):
    """The output a restarted sink finalized (7 recovered frames, output incomplete) is
    finished: a sink started again with nobody there, or stopped before it received
    anything, keeps it byte for byte (exit 3 alone, 130 stopped) instead of replacing it
    with an empty recording."""
    out = _killed_sink_dir(tmp_path, finished, 7)
    cfg = _cfg_for(finished, out)
    result, clock, t = _run_alone(cfg, "sink")
    _drive(clock, t)
    assert result["code"] == EXIT_DATA
    files = [out / "tracks.mcap", out / SUMMARY_NAME]
    before = [_digest(p) for p in files]
    result, clock, t = _run_alone(cfg, "sink")
    _drive(clock, t)
    assert result["code"] == EXIT_DATA and result["t"] >= GONE_S
    assert [_digest(p) for p in files] == before
    net = MemoryNetwork()
    net.bus(cfg.run, "source").declare_alive()  # someone there: it waits, then is stopped
    result, clock, t = _run_alone(cfg, "sink", net)
    _drive(clock, t, until=3 * GONE_S)
    result["ctx"].stop.set()
    _drive(clock, t)
    assert result["code"] == EXIT_STOPPED and [_digest(p) for p in files] == before
    assert not list(out.glob(".*.part"))


def test_a_sink_restarted_alone_with_nothing_to_recover_exits_2_and_touches_nothing(tmp_path, finished):
    """The killed sink had written no frame yet (header only): one line naming the run and
    the missing upstream, exit 2 (from `bnptrack stage`), and the .part is left as it was."""
    out = _killed_sink_dir(tmp_path, finished, 0)
    cfg = _cfg_for(finished, out)
    part = part_path(out / "tracks.mcap")
    before = _digest(part)
    result, clock, t = _run_alone(cfg, "sink")
    _drive(clock, t)
    err = result.get("error")
    assert isinstance(err, UpstreamGone), result
    assert str(err) == (f"stage sink: run {cfg.run}: upstream gone before the end of stream: no live source or "
                        f"tracker for 5 s and no cache holds the rest of the run, and nothing to recover (no "
                        f"readable frame in {part}): nothing written")
    assert _digest(part) == before
    assert not (out / SUMMARY_NAME).exists() and not (out / "tracks.mcap").exists()


def test_a_silent_live_upstream_or_a_fresh_sink_never_gives_up(tmp_path, finished):
    """The rule needs both a restart and an upstream gone: a restarted sink whose source is
    alive (token, no data) waits past upstream_gone_s, and finalizes once the source leaves;
    a fresh sink (no .part: the others may start later) waits for as long as it takes."""
    out = _killed_sink_dir(tmp_path, finished, 4)
    cfg = _cfg_for(finished, out)
    net = MemoryNetwork()
    source = net.bus(cfg.run, "source")
    source.declare_alive()
    result, clock, t = _run_alone(cfg, "sink", net)
    wait_until(lambda: "sink" in net.alive.get((cfg.run, "alive"), ()), 30, "the sink to declare itself alive")
    _drive(clock, t, until=NEVER_S)
    assert t.is_alive() and "code" not in result
    source.close()  # the source leaves: from now on the sink is alone
    t_left = clock.monotonic()
    _drive(clock, t)
    assert result["code"] == EXIT_DATA and result["t"] >= t_left + GONE_S
    assert json.loads((out / SUMMARY_NAME).read_text())["recovered_frames"] == 4

    fresh = _cfg_for(finished, tmp_path / "fresh")
    result, clock, t = _run_alone(fresh, "sink")
    _drive(clock, t, until=NEVER_S)
    assert t.is_alive() and "code" not in result
    result["ctx"].stop.set()
    _drive(clock, t)
    assert result["code"] == EXIT_STOPPED


def test_a_sink_restarted_alone_after_a_complete_run_keeps_it_and_exits_0(tmp_path, finished):
    """sink.json of this run says complete: nothing is reopened, and with nobody there the
    sink exits 0 once its linger is over (on its clock), every file byte for byte as it was."""
    cfg, _ = finished
    out = Path(cfg.out)
    files = [out / "tracks.mcap", out / SUMMARY_NAME]
    before = [_digest(p) for p in files]
    result, clock, t = _run_alone(cfg, "sink")
    _drive(clock, t)
    # linger_s (0.5 s here) bounds the wait; the clock moves 0.5 s per poll of the test
    assert result["code"] == EXIT_OK and result["t"] <= max(cfg.supervisor.linger_s, 1.0) + 1.0
    assert [_digest(p) for p in files] == before


def test_a_tracker_resumed_alone_keeps_its_snapshot_and_journal_and_exits_3(tmp_path, finished):
    """A tracker killed mid-run (a snapshot without an end of stream) started again after the
    source left: after upstream_gone_s it exits EXIT_DATA, publishing no end of stream, its
    snapshot and journal unchanged."""
    import shutil

    cfg0, _ = finished
    out = tmp_path / "out"
    shutil.copytree(cfg0.out, out)
    snap = read_snapshot(out / SNAPSHOT_NAME)
    (out / SNAPSHOT_NAME).write_bytes(msgspec.msgpack.encode(msgspec.structs.replace(snap, eos=None)))
    before = {p: _digest(out / p) for p in (SNAPSHOT_NAME, "tracker.journal")}
    cfg = msgspec.structs.replace(cfg0, out=str(out))
    net = MemoryNetwork()
    result, clock, t = _run_alone(cfg, "tracker", net)
    _drive(clock, t)
    assert "error" not in result, result.get("error")
    assert result["code"] == EXIT_DATA and result["t"] >= GONE_S
    assert {p: _digest(out / p) for p in before} == before
    topics = [tp for _r, tp, *_ in net.history]
    assert "eos/tracker" not in topics and topics.count("tracks") == 12  # its journal, published again


def test_upstream_watch_counts_from_the_last_live_upstream_and_asks_the_caches():
    """UpstreamWatch on a bare fake bus: a live upstream restarts the count; once the time is
    up, a publisher's cache that answers (Bus.head) restarts it too."""
    class Bus:
        tokens: set = set()
        heads: dict = {}

        def alive(self):
            return set(self.tokens)

        def head(self, topic):
            return self.heads.get(topic)

    clock = ManualClock()
    bus = Bus()
    w = UpstreamWatch(bus, ["source", "tracker"], ["measurements", "tracks"], 5.0, clock.monotonic)
    clock.advance(4.9)
    assert not w.gone()
    bus.tokens = {"tracker"}
    clock.advance(1.0)
    assert not w.gone()  # alive: counts again from t = 5.9
    bus.tokens = {"sink"}
    clock.advance(4.9)
    assert not w.gone()
    bus.heads = {"tracks": 41}
    clock.advance(0.1)
    assert not w.gone()  # the tracker's cache still answers: from t = 10.9 again
    bus.heads = {}
    clock.advance(5.0)
    assert w.gone()
    assert w.reason() == ("upstream gone before the end of stream: no live source or tracker for 5 s "
                          "and no cache holds the rest of the run")
