"""Throughput and added latency of the Zenoh pipeline, next to the same tracker offline.

Builds a measurement log (``--runs`` vo2017 runs of 100 frames, seeds 1.., frame numbers and
stamps made consecutive), then measures, in one invocation:

1. **Throughput**, in ``--rounds`` interleaved rounds (so that a change of machine load hits
   both sides alike).  Each round runs

   * *offline*: the tracker over the frames in this process (``tracker.state.run``: no I/O,
     frames already decoded, warmed up), frames / elapsed time;
   * *pipeline*: ``bnptrack replay LOG --as-fast-as-possible`` (source, tracker and sink
     processes, launched with the embedded router); frames recorded by the sink / (last
     ``/tracks`` receipt - first frame publication).  During it, the CPU time of each stage
     process is sampled from ``/proc``.

   and, between the two, the *tracker stage's code without transport* (a ``TrackerStage`` on
   an in-memory bus in this process: decoding, validation, step, encoding, journal, snapshots).
   The ratio reported is the median over the rounds of pipeline / offline.  ``bnptrack track``
   (MCAP in and out) runs once for reference.
2. **Added latency**, in one *paced* run at ``--rate`` frames per second (well below the
   tracker's capacity, so that frames do not queue behind each other).  For each frame:
   end-to-end = the sink's receipt of its ``/tracks`` - the source's publication of its
   ``/measurements`` (same host, same clock); *added* = end-to-end - the tracker's own compute
   for that frame (its ``ms`` diagnostic: the wall time of ``tracker.step``).  Added is what the
   pipeline costs on top of the computation: two Zenoh hops, decoding and validation, encoding,
   the journal, scheduling.  The per-hop breakdown comes from the tracker's ``t_in``/``t_out``.
3. **Transport floors**: after each paced run, the *two-hop floor*, the pipeline's path with
   nothing on it (a publisher process, a relay process republishing each sample at once, a
   subscriber process, a router in this process, the stages' ``Bus``), with the pipeline's
   traffic (/measurements and /truth per frame, /tracks back, the pipeline's sizes, the
   subscriber subscribed as the sink is) and the sink's receipt stamp (the subscription
   callback's), as many samples as the run had frames: the target's floor.  Beside it,
   the one-topic floor (one topic per hop, stamped on the subscriber's main thread).  Paced runs
   and floors run without the ``/proc`` CPU sampler.  With both parts measured, also one hop
   between two bare processes in client and peer mode, and the operating system's own hop (a
   socketpair).  ``--first-puts SIZE [TOPIC|shm]`` times the first puts on a fresh session
   (``shm``: with Zenoh's shared memory turned back on, the default before this was found).
4. **Machine floor**: the offline tracker alone and beside bare Zenoh traffic (a router and a
   publisher in one process, a subscriber in another, three samples of the pipeline's sizes
   per frame at the offline frame rate: no tracker, codec or file), in ``--rounds``
   interleaved rounds.  On a machine whose cores are independent the ratio is about 1; where
   the transport's mere presence slows the tracker, no pipeline can reach a higher
   throughput ratio than this one.

    python benchmarks/pipeline_latency.py                    # 5 x 100 frames, ddp, 3 rounds
    python benchmarks/pipeline_latency.py --tracker dpyp --rounds 5 --json out.json
    python benchmarks/pipeline_latency.py --only acl-floor --paced 4      # the floor, bare / launcher's router
    python benchmarks/pipeline_latency.py --only session-floor --paced 4  # the floor, one session / one each
    python benchmarks/pipeline_latency.py --only frame-path --rounds 5    # the stage's own work, in process

Each paced run also prints the frame path's segments, from the tracker's stamps
read back from its journal: source -> tracker, hand-off, before the step, the step, after the
step, the put and tracker -> sink.

The sink writes no ``.rrd`` (``sink.rerun=false``) unless ``--rerun``.  Timings on a shared
machine vary: the load average is printed beside the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.pipeline.launch import launch  # noqa: E402
from bnptrack.pipeline.offline import open_sinks, track_to_sinks
from bnptrack.pipeline.resolve import tracker_setup
from bnptrack.sources.scenarios import scenario_params
from bnptrack.pipeline.config import load_pipeline  # noqa: E402
from bnptrack.pipeline.stages.summary import load_summary  # noqa: E402
from bnptrack.sinks.mcap_writer import McapLogWriter  # noqa: E402
from bnptrack.sinks.records import SinkOptions  # noqa: E402
from bnptrack.sources.mcap_log import iter_frames, read_metadata  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402

STAGES = ("source", "tracker", "sink")
HOPS = ("source_to_tracker_ms", "in_tracker_ms", "tracker_to_sink_ms")
#: Finer splits: the tracker's callback -> main thread hand-off, and
#: the frame's /measurements from the source to the sink (the same sample's other receiver).
SPLITS = ("tracker_handoff_ms", "source_to_sink_measurements_ms")


def make_log(path: Path, runs: int) -> int:
    """``runs`` vo2017 runs back to back (seeds 1..runs), frames renumbered 1..100*runs."""
    params = scenario_params("vo2017", "vo2017")
    sc = get_scenario("vo2017")
    meta = {"scenario": "vo2017", "params": "vo2017", "seed": "1..%d" % runs}
    n = 0
    with McapLogWriter(path, meta) as w:
        for r in range(runs):
            for f in simulate(sc, params, r + 1):
                n += 1
                w.write_frame(replace(f, frame=n, stamp_ns=n * 10**9))
    return n


def load_avg() -> float:
    return os.getloadavg()[0]


def pct(a, q: float) -> float:
    return float(np.percentile(np.asarray(a, float), q))


# --------------------------------------------------------------------------- offline


class Offline:
    """The tracker over the log's frames in this process (decoded beforehand)."""

    def __init__(self, log: Path, tracker_name: str, seed: int) -> None:
        self.log, self.seed, self.tracker_name = log, seed, tracker_name
        self.meta = read_metadata(log)
        self.setup = tracker_setup(tracker_name, metadata=self.meta)
        self.tracker = self.setup.tracker
        self.frames = list(iter_frames(log))
        for _ in run(self.tracker, self.frames[:20], seed):  # warm up (numba JIT), as the stage does
            pass

    def fps(self) -> tuple[float, float, list[float]]:
        """Frames per second, CPU ms per frame, and each frame's step time (ms)."""
        t0, c0 = time.perf_counter(), time.process_time()
        ms = [est.diagnostics["ms"] for _, est, _ in run(self.tracker, self.frames, self.seed)]
        n = len(self.frames)
        return n / (time.perf_counter() - t0), 1e3 * (time.process_time() - c0) / n, ms

    def stage_fps(self, out: Path) -> tuple[float, float]:
        """The tracker stage's own code without transport: a ``TrackerStage`` on an in-memory
        bus fed the encoded frames in this process (decode, validation, step, encoding,
        journal, snapshots).  Frames per second and CPU ms per frame."""
        from bnptrack.tracker.messages import encode
        from bnptrack.pipeline.membus import MemoryNetwork
        from bnptrack.pipeline.config import PipelineConfig, TrackerStageConfig, resolve_run
        from bnptrack.pipeline.stages import StageContext, StageInfo, TrackerStage
        from bnptrack.pipeline.events import Event

        cfg = resolve_run(PipelineConfig(run="inproc", out=str(out), tracker=TrackerStageConfig(
            tracker=self.tracker_name, seed=self.seed)))
        stage = TrackerStage(StageContext(cfg, MemoryNetwork().bus("inproc", "tracker"), name="tracker"))
        stage._restore()
        stage._build(StageInfo(stage="source", run="inproc", metadata=self.meta))
        events = [Event("measurements", encode(f, "inproc"), {"seq": i, "t": 0, "frame": f.frame}, 0)
                  for i, f in enumerate(self.frames)]
        t0, c0 = time.perf_counter(), time.process_time()
        for ev in events:
            stage._on_data(ev)
        stage.writer.flush()
        n = len(events)
        fps, cpu = n / (time.perf_counter() - t0), 1e3 * (time.process_time() - c0) / n
        stage._close_journal()
        return fps, cpu

    def track_log_fps(self, out: Path, rerun: bool = False) -> tuple[float, float]:
        """``bnptrack track LOG --out OUT`` (``--rrd`` with ``rerun``) in this process, its
        tracker warmed up: read and decode the frames from the MCAP log, track, score each
        frame (OSPA, OSPA(2)), write ``tracks.mcap`` with the input channels: the pipeline's
        outputs, in one process.  Frames per second over the whole call (opening and closing
        the files included), and CPU ms per frame (this process)."""
        outputs = {"mcap": out, **({"rerun": out.with_suffix(".rrd")} if rerun else {})}
        options = SinkOptions(out, params=self.setup.params, process=True, source=str(self.log))
        t0, c0 = time.perf_counter(), time.process_time()
        track_to_sinks(self.log, open_sinks(outputs, options), self.tracker, self.seed, self.meta)
        n = len(self.frames)
        return n / (time.perf_counter() - t0), 1e3 * (time.process_time() - c0) / n


# --------------------------------------------------------------------------- pipeline


class CpuSampler:
    """Samples the CPU time (user + system) of the stage processes listed in
    ``<out>/stages.json`` every ``period`` seconds, with wall-clock stamps."""

    def __init__(self, out: Path, period: float = 0.05) -> None:
        self.out, self.period = out, period
        self.samples: list[tuple[float, dict[str, float]]] = []
        self._stop = threading.Event()
        self._tck = os.sysconf("SC_CLK_TCK")
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def __enter__(self) -> "CpuSampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _cpu(self, pid: int, task: str = "") -> float | None:
        try:
            f = Path(f"/proc/{pid}{task}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            return None
        return (int(f[11]) + int(f[12])) / self._tck

    def _loop(self) -> None:
        while not self._stop.wait(self.period):
            try:
                pids = {k: v["pid"] for k, v in json.loads((self.out / "stages.json").read_text()).items()}
            except (OSError, ValueError):
                continue
            row = {k: c for k, pid in pids.items() if (c := self._cpu(pid)) is not None}
            # the tracker's main thread alone (the frame loop; the rest are Zenoh's threads
            # and the snapshot writer)
            if "tracker" in pids and (c := self._cpu(pids["tracker"], f"/task/{pids['tracker']}")) is not None:
                row["tracker_main"] = c
            self.samples.append((time.time(), row))

    def used(self, t_a: float, t_b: float) -> dict[str, float]:
        """CPU seconds each stage used between wall-clock times ``t_a`` and ``t_b``."""
        ts = [t for t, _ in self.samples]
        i = max(0, int(np.searchsorted(ts, t_a)) - 1)
        j = min(len(ts) - 1, int(np.searchsorted(ts, t_b)))
        a, b = self.samples[i][1], self.samples[j][1]
        return {k: b[k] - a[k] for k in b if k in a}


def pipeline(log: Path, tracker_name: str, seed: int, out: Path, rate: float, rerun: bool,
             sets: list[str], sample_cpu: bool = True) -> dict:
    """One ``replay`` of ``log`` (in this process's launcher); the sink's figures.  With
    ``sample_cpu``, the stages' CPU time is read from ``/proc`` every 50 ms meanwhile (a
    thread of this process, which also holds the router: the paced runs go without it, as
    their floors do)."""
    cfg = load_pipeline(None, [
        "source.kind='mcap'", f"source.log='{log}'", f"source.rate={rate}",
        f"tracker.tracker='{tracker_name}'", f"tracker.seed={seed}", f"sink.rerun={str(rerun).lower()}",
        *sets,
    ])
    import msgspec

    cfg = msgspec.structs.replace(cfg, out=str(out), run=f"bench-{out.name}-{os.getpid()}")
    cpu = CpuSampler(out)
    if sample_cpu:
        with cpu:
            res = launch(cfg, timeout=1800, handle_signals=True)
    else:
        res = launch(cfg, timeout=1800, handle_signals=True)
    if not res.ok:
        raise SystemExit(f"pipeline failed: {res.error or res.incomplete}")
    s = load_summary(out / "sink.json")
    lat = s.latency
    e2e, step = np.array(lat["e2e_ms"], float), np.array(lat["tracker_ms"], float)
    window = (s.t_first_pub_ns / 1e9, s.t_last_recv_ns / 1e9)
    used = cpu.used(*window) if sample_cpu else {}
    n = s.tracks_written
    return {
        "segments_ms": frame_segments(out, lat),
        "frames": n,
        "gaps": sum(len(v) for v in s.gaps.values()),
        "fps": s.throughput_fps,
        "e2e_ms": e2e.tolist(),
        "added_ms": (e2e - step).tolist(),
        "step_ms": step.tolist(),
        "hops_ms": {k: lat[k] for k in HOPS + SPLITS if k in lat},
        "cpu_ms_per_frame": {k: 1e3 * v / n for k, v in used.items()},
        "cpu_cores": {k: v / max(window[1] - window[0], 1e-9) for k, v in used.items()},
        "load_avg": load_avg(),
    }


#: The frame path cut at the tracker's stamps: source publish -> tracker callback
#: (``t_in``), the callback -> main thread hand-off (``t_deq``), the main thread's work before
#: the step (intake: decoding and validation, sequencing, ``to_frame``, the bounds check, the
#: frame's generator; ``t_s0``), the step (``t_s1``), the work after it up to the put (encoding,
#: the attachment; ``t_out``), the put and the second hop to the sink's receipt stamp.
SEGMENTS = ("source_to_tracker", "handoff", "pre_step", "step", "post_step", "tracker_to_sink")


def frame_segments(out: Path, lat: dict) -> dict[str, list[float]]:
    """Per frame, the milliseconds of each :data:`SEGMENTS` (empty lists when the tracker's
    journal lacks the stamps, e.g. a checkout whose tracker does not journal them): the tracker's stamps are read
    back from its journal (``<out>/tracker.journal``, the attachment of every /tracks
    published), joined on ``seq`` with the sink's receipt (``sink.json``'s ``e2e_ms``)."""
    from bnptrack.pipeline.journal import read_journal

    path = out / "tracker.journal"
    metas = {r.seq: r.meta for r in read_journal(path)} if path.exists() else {}
    seg: dict[str, list[float]] = {k: [] for k in SEGMENTS}
    for s, e2e in zip(lat.get("seq", []), lat["e2e_ms"]):
        m = metas.get(s)
        if m is None or not all(isinstance(m.get(k), int) for k in ("t", "t_in", "t_deq", "t_s0", "t_s1", "t_out")):
            continue
        stamps = [m["t"], m["t_in"], m["t_deq"], m["t_s0"], m["t_s1"], m["t_out"]]
        for k, a, b in zip(SEGMENTS, stamps, stamps[1:]):
            seg[k].append((b - a) / 1e6)
        seg["tracker_to_sink"].append(e2e - (m["t_out"] - m["t"]) / 1e6)
    return seg


#: Bins of the time between the sink's receipt of a frame's /measurements and of its /tracks
#: (ms): in the first, the sink's main thread may still hold the GIL for that frame's
#: /measurements and /truth when the /tracks callback wants it.
SINK_GAP_BINS = ((-1e9, 1.0, "< 1"), (1.0, 3.0, "1-3"), (3.0, 5.0, "3-5"), (5.0, 1e9, ">= 5"))


def sink_gap_split(paced: dict) -> list[tuple[str, int, float, float]]:
    """Per :data:`SINK_GAP_BINS` bin of the gap (sink receipt of /tracks minus that of the
    frame's /measurements): ``(label, frames, tracker -> sink p50, p90)``; empty when the
    per-frame lists are not aligned (a frame without one of the stamps)."""
    h = paced["hops_ms"]
    e2e = np.asarray(paced["e2e_ms"], float)
    meas = np.asarray(h.get("source_to_sink_measurements_ms", []), float)
    t2s = np.asarray(h.get("tracker_to_sink_ms", []), float)
    if not e2e.size or not e2e.size == meas.size == t2s.size:
        return []
    gap = e2e - meas
    out = []
    for lo, hi, label in SINK_GAP_BINS:
        sel = t2s[(gap >= lo) & (gap < hi)]
        if sel.size:
            out.append((label, int(sel.size), pct(sel, 50), pct(sel, 90)))
    return out


def report_sink_gap(paced: dict) -> None:
    """One line: tracker -> sink by :func:`sink_gap_split`'s bins."""
    rows = sink_gap_split(paced)
    if rows:
        print("  tracker -> sink p50 (p90) by the sink's /measurements -> /tracks gap: " + "; ".join(
            f"{label} ms: {n} frames {a:.2f} ({b:.2f})" for label, n, a, b in rows))


def report_segments(seg: dict[str, list[float]]) -> None:
    """One line: p50 (p99) of each segment of the frame path."""
    if not seg or not seg.get("step"):
        return
    print("  segments p50 (p99), ms: " + "; ".join(
        f"{k} {pct(seg[k], 50):.3f} ({pct(seg[k], 99):.2f})" for k in SEGMENTS))


# --------------------------------------------------------------------------- frame path, in process


class _FixedTracker:
    """A tracker whose step returns a precomputed estimate at once (the stage's own code alone)."""

    def __init__(self, ests: list) -> None:
        self.ests = {e.frame: e for e in ests}

    def initial_state(self) -> None:
        return None

    def step(self, state, frame, rng):
        return state, self.ests[frame.frame]


class _NullBus:
    """Publishes nothing: encodes the attachment as the Zenoh bus does and keeps it."""

    def __init__(self) -> None:
        import msgspec

        self.enc, self.metas = msgspec.json.Encoder(), []

    def publish(self, topic: str, payload: bytes, meta: dict | None = None) -> None:
        if meta is not None:
            self.enc.encode(meta)
            self.metas.append(meta)


def frame_path_inputs(tracker_name: str) -> tuple[list, list, list]:
    """vo2017 seed 1 (100 frames): the frames, the tracker's estimates, and per frame its
    received ``(measurements, truth, tracks)`` samples (events)."""
    from bnptrack.pipeline.events import Event
    from bnptrack.tracker.messages import encode, from_truth

    frames = [replace(f, frame=i + 1, stamp_ns=(i + 1) * 10**9)
              for i, f in enumerate(simulate(get_scenario("vo2017"), scenario_params("vo2017", "vo2017"), 1))]
    setup = tracker_setup(tracker_name, metadata={"scenario": "vo2017", "params": "vo2017"})
    ests = [est for _, est, _ in run(setup.tracker, frames, 0)]
    events = [(Event("measurements", encode(f, "inproc"), {"seq": i, "t": 0, "frame": f.frame}, 0),
               Event("truth", encode(from_truth(f.frame, f.stamp_ns, f.truth, "inproc")), {"seq": i, "t": 0}, 0),
               Event("tracks", encode(e, "inproc"), {"seq": i, "t": 0, "frame": f.frame}, 0))
              for i, (f, e) in enumerate(zip(frames, ests))]
    return frames, ests, events


def stage_segments(ests: list, events: list, out: Path, sleep: float) -> dict[str, list[float]]:
    """A ``TrackerStage`` (in-memory bus, a step that costs nothing) fed ``events`` one by one
    as its loop does (``t_deq``, then ``_on_event``), ``sleep`` seconds apart; per frame, the
    microseconds before the step (``t_s0 - t_deq``: intake, sequencing, ``to_frame``, the
    generator) and after it (``t_out - t_s1``: the encoding, the attachment)."""
    from bnptrack.pipeline.config import PipelineConfig, TrackerStageConfig, resolve_run
    from bnptrack.pipeline.membus import MemoryNetwork
    from bnptrack.pipeline.stages import StageContext, TrackerStage

    cfg = resolve_run(PipelineConfig(run="inproc", out=str(out), tracker=TrackerStageConfig(seed=0)))
    stage = TrackerStage(StageContext(cfg, MemoryNetwork().bus("inproc", "tracker"), name="tracker"))
    stage._restore()
    stage.tracker, stage.state = _FixedTracker(ests), None
    stage.bus = stage.intake.bus = _NullBus()
    for ev, _truth, _tracks in events:
        if sleep:
            time.sleep(sleep)
        stage.t_deq_ns = time.time_ns()
        stage._on_event(ev)
    stage.writer.flush()
    stage._close_journal()
    metas = stage.bus.metas
    return {"pre_step": [(m["t_s0"] - m["t_deq"]) / 1e3 for m in metas],
            "post_step": [(m["t_out"] - m["t_s1"]) / 1e3 for m in metas]}


def piece_times(ests: list, events: list, sleep: float) -> dict[str, list[float]]:
    """Per frame, the microseconds of the frame path's codec pieces (the tracker's
    ``Intake.check`` of /measurements: decoding and validation; ``to_frame``; ``encode`` of the
    estimate; the sink's ``Intake.check`` of /truth and /tracks), ``sleep`` seconds apart (0:
    back to back, caches warm)."""
    from bnptrack.pipeline.stages.delivery import Intake
    from bnptrack.pipeline.stages.health import Counters
    from bnptrack.tracker.messages import encode, to_frame

    intake = Intake("tracker", "inproc", _NullBus(), Counters(), 10**8)
    out: dict[str, list[float]] = {"intake.check": [], "to_frame": [], "encode": [], "sink check /truth": [],
                                   "sink check /tracks": []}
    pc = time.perf_counter_ns
    for (ev, truth, tracks), est in zip(events, ests):
        if sleep:
            time.sleep(sleep)
        t = [pc()]
        acc = intake.check(ev)
        t.append(pc())
        to_frame(acc.msg)
        t.append(pc())
        encode(est, "inproc")
        t.append(pc())
        assert intake.check(truth) is not None
        t.append(pc())
        assert intake.check(tracks) is not None
        t.append(pc())
        for k, a, b in zip(out, t, t[1:]):
            out[k].append((b - a) / 1e3)
    return out


def frame_path(args) -> dict:
    """``--only frame-path``: the tracker stage's own work on a frame, in process: the codec's
    pieces and the stage's segments before and after the step, back to back (``hot``, best of
    ``--rounds`` passes) and one frame every 1/``--rate`` s (``paced``: the caches go cold
    between frames, as in a paced run).  Medians (p99) in microseconds."""
    frames, ests, events = frame_path_inputs(args.tracker)
    res: dict = {}
    with tempfile.TemporaryDirectory() as d:
        for mode, sleep, reps in (("hot", 0.0, args.rounds), ("paced", 1.0 / args.rate, 1)):
            rows: dict[str, list[float]] = {}
            for r in range(reps):
                for k, v in {**piece_times(ests, events, sleep),
                             **stage_segments(ests, events, Path(d) / f"{mode}{r}", sleep)}.items():
                    rows.setdefault(k, []).extend(v)
            res[mode] = {k: (pct(v, 50), pct(v, 99)) for k, v in rows.items()}
            print(f"frame path, {mode} ({len(events)} frames x {reps}, load {load_avg():.2f}), us p50 (p99): "
                  + "; ".join(f"{k} {a:.1f} ({b:.1f})" for k, (a, b) in res[mode].items()), flush=True)
    return res


# --------------------------------------------------------------------------- transport floor


#: The two-hop floor's process names; with ``--only acl-floor``'s access control, the stages'
#: (the ACL lets the user named like a stage put on that stage's keys and hold its tokens).
FLOOR_NAMES = {"pub": "pub", "relay": "relay", "sub": "sub"}
ACL_FLOOR_NAMES = {"pub": "source", "relay": "tracker", "sub": "sink"}


def _floor_name(role: str) -> str:
    """A floor process's name (``BNPTRACK_FLOOR_ACL`` set: the stage's, for the ACL)."""
    return (ACL_FLOOR_NAMES if os.environ.get("BNPTRACK_FLOOR_ACL") else FLOOR_NAMES)[role]


def _floor_subscriber(mode: str, endpoint: str, n: int, run_id: str = "floor",
                      topic: str = "measurements", traffic: str = "bare") -> None:
    """(child process) receive ``n`` samples of ``topic``; print their latencies (since the
    first publication, ``meta["t"]``) as JSON.  ``bare``: subscribed to
    ``topic`` alone, the latency taken when the main thread gets the sample.  ``pipeline``
    (the sink's place): subscribed to what the sink subscribes to (``measurements``, ``truth``,
    ``tracks``), the latency taken when the sample arrives (``Event.t_recv_ns``, stamped in the
    subscription callback): exactly the sink's receipt time of ``/tracks``."""
    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus

    with Bus(run_id, _floor_name("sub"), ZenohConfig(mode=mode, connect=[endpoint]), DeliveryConfig()) as bus:
        bus.subscribe(["measurements", "truth", "tracks"] if traffic == "pipeline" else [topic])
        bus.declare_alive("ready")
        lat, first = [], []
        while len(lat) < n:
            ev = bus.recv(10)
            if ev is None:
                break
            if ev.topic == topic:
                t_recv = ev.t_recv_ns if traffic == "pipeline" else time.time_ns()
                lat.append((t_recv - ev.meta["t"]) / 1e6)
            elif ev.topic == "measurements":  # the first hop, publisher -> here (not the relay's)
                first.append((ev.t_recv_ns - ev.meta["t"]) / 1e6)
    print(json.dumps(lat))
    print(json.dumps(first))


def transport_floor(mode: str, rate: float, n: int = 400) -> dict:
    """One Zenoh hop between two processes (client mode: through a router; peer mode: direct,
    found through the router), ~1 KB samples at ``rate`` per second."""
    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus, Router

    with Router(ZenohConfig()) as router:
        ep = router.endpoints[0]
        child = subprocess.Popen([sys.executable, __file__, "--floor-subscriber", mode, ep, str(n)],
                                 stdout=subprocess.PIPE, text=True)
        with Bus("floor", "pub", ZenohConfig(mode=mode, connect=[ep]), DeliveryConfig()) as bus:
            if bus.wait_alive(["sub"], 60, "ready"):
                raise SystemExit("floor subscriber did not start")
            time.sleep(0.5)  # let the peers link up
            for i in range(n):
                bus.publish("measurements", b"x" * 950, {"seq": i, "t": time.time_ns()})
                time.sleep(1.0 / rate)
            out, _ = child.communicate(timeout=60)
    lat = json.loads(out.splitlines()[0])
    return {"p50": pct(lat, 50), "p99": pct(lat, 99), "load_avg": load_avg()}


def _floor_relay(mode: str, endpoint: str) -> None:
    """(child process) the tracker's place with no tracker: republish every ``measurements``
    sample at once as a ``tracks`` sample of the pipeline's size, keeping its ``t``; serve
    until stdin closes (so that the last samples are delivered)."""
    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus

    with Bus("floor2", _floor_name("relay"), ZenohConfig(mode=mode, connect=[endpoint]), DeliveryConfig()) as bus:
        bus.declare(["tracks"])
        bus.subscribe(["measurements"])
        bus.declare_alive("ready")
        stop = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
        out = b"x" * TRAFFIC_SIZES[2]
        while not stop.is_set():
            ev = bus.recv(0.1)
            if ev is not None:
                bus.publish("tracks", out, {"seq": ev.meta["seq"], "t": ev.meta["t"]})


def _floor_publish(mode: str, endpoint: str, n: int, rate: float, traffic: str = "bare") -> None:
    """Publish ``n`` ``measurements`` samples of the pipeline's size at ``rate`` per second,
    each stamped with its publication time, once the relay and the subscriber are ready;
    with ``traffic="pipeline"`` each followed by a ``truth`` sample of the pipeline's size
    stamped alike, as the source stage publishes a frame."""
    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus

    with Bus("floor2", _floor_name("pub"), ZenohConfig(mode=mode, connect=[endpoint]), DeliveryConfig()) as bus:
        bus.declare(["measurements", "truth"] if traffic == "pipeline" else ["measurements"])
        if bus.wait_alive([_floor_name("sub"), _floor_name("relay")], 60, "ready"):
            raise SystemExit("two-hop floor: relay or subscriber did not start")
        time.sleep(0.5)  # let the peers link up
        payload, truth = b"x" * TRAFFIC_SIZES[0], b"x" * TRAFFIC_SIZES[1]
        for i in range(n):
            t = time.time_ns()
            bus.publish("measurements", payload, {"seq": i, "t": t})
            if traffic == "pipeline":
                bus.publish("truth", truth, {"seq": i, "t": t})
            time.sleep(1.0 / rate)
        time.sleep(1.0)  # keep the session a moment: the last samples leave


def two_hop_floor(mode: str, rate: float, n: int = 500, traffic: str = "pipeline", acl: bool = False,
                  sessions: bool = False) -> dict:
    """The pipeline's two hops with nothing else: a publisher process (the source's place) ->
    a relay process (the tracker's: republishes each sample at once, ``_floor_relay``) -> a
    subscriber process (the sink's), ``n`` samples at ``rate`` per second with the pipeline's
    payload sizes (/measurements in, /tracks out), through a router in this process
    (``client``, like the launcher's embedded router) or peer to peer (``peer``), with the
    stages' ``Bus`` (the same publisher and subscriber settings).

    ``traffic="pipeline"`` (the target's floor): the pipeline's traffic and receipt time too;
    the publisher also puts a /truth sample per frame, the subscriber subscribes to
    /measurements, /truth and /tracks as the sink does, and the latency is taken when the
    /tracks sample arrives (the subscription callback's stamp, the sink's ``t_recv_ns``).
    ``traffic="bare"``: the bare floor (one topic per hop, the latency taken when the
    subscriber's main thread gets the sample: one thread wake-up later than the sink's stamp).

    ``acl``: the router as ``launch`` opens it by default (per-run usernames and passwords,
    the pipeline's access control, :func:`pipeline.supervisor.open_embedded_router`), each
    process logged in as the stage whose place it takes.

    ``sessions``: each floor process in a session of its own, as the launcher starts the stages
    (``start_new_session``); with Linux's autogroup scheduling (``kernel.sched_autogroup_enabled``)
    a session is a scheduling group, so the floor's processes then no longer share one group
    with the router (and the benchmark)."""
    router, env = _floor_router(acl)
    with router:
        ep = router.connect_endpoints[0]
        sub = subprocess.Popen([sys.executable, __file__, "--floor-subscriber2", mode, ep, str(n), traffic],
                               stdout=subprocess.PIPE, text=True, env=env["sub"], start_new_session=sessions)
        relay = subprocess.Popen([sys.executable, __file__, "--floor-relay", mode, ep], stdin=subprocess.PIPE,
                                 env=env["relay"], start_new_session=sessions)
        try:
            pub = subprocess.Popen([sys.executable, __file__, "--floor-publisher2", mode, ep, str(n), str(rate),
                                    traffic], env=env["pub"], start_new_session=sessions)
            out, _ = sub.communicate(timeout=120 + 2 * n / rate)
            pub.wait(60)
        finally:
            relay.stdin.close()
            relay.wait(30)
    lines = out.splitlines()
    lat, first = json.loads(lines[0]), json.loads(lines[1]) if len(lines) > 1 else []
    return {"p50": pct(lat, 50), "p99": pct(lat, 99), "n": len(lat), "load_avg": load_avg(), "traffic": traffic,
            "first_hop_ms": first}


def _floor_router(acl: bool) -> tuple:
    """The two-hop floor's router and each floor process's environment: a bare router, or with
    ``acl`` the launcher's (credentials and access control) and each process's login."""
    from bnptrack.pipeline.config import ZenohConfig
    from bnptrack.pipeline.transport import Router

    if not acl:
        return Router(ZenohConfig()), {role: None for role in FLOOR_NAMES}
    from bnptrack.pipeline.supervisor import open_embedded_router

    out = Path(tempfile.mkdtemp(prefix="acl-floor-"))
    router, _z, cred = open_embedded_router(ZenohConfig(), out, list(ACL_FLOOR_NAMES.values()))
    env = {role: {**os.environ, "BNPTRACK_FLOOR_ACL": "1", "BNPTRACK_ZENOH_USER": name,
                  "BNPTRACK_ZENOH_PASSWORD": cred[name]} for role, name in ACL_FLOOR_NAMES.items()}
    return router, env


def floor_variant_rounds(args) -> list[dict]:
    """``--only acl-floor``: ``--paced`` rounds of the two-hop floor through a bare router and
    through the launcher's (authentication and access control), interleaved: what the router's
    access control costs the two hops, with no stage code at all.  ``--only session-floor``: the
    floor's processes in the benchmark's session and each in a session of its own (as the
    launcher starts the stages), interleaved."""
    variant = "acl" if args.only == "acl-floor" else "sessions"
    rounds = []
    for r in range(args.paced):
        pair = {"bare": two_hop_floor("client", args.rate),
                variant: two_hop_floor("client", args.rate, **{variant: True})}
        rounds.append(pair)
        print(f"  round {r + 1}: " + "; ".join(
            f"{k} p50 {v['p50']:.2f} p99 {v['p99']:.2f} ms (first hop p50 {pct(v['first_hop_ms'], 50):.2f} p99 "
            f"{pct(v['first_hop_ms'], 99):.2f}; load {v['load_avg']:.2f})" for k, v in pair.items()), flush=True)
    for k in ("bare", variant):
        print(f"  two-hop floor, {k} router: median p50 {np.median([p[k]['p50'] for p in rounds]):.2f} ms, "
              f"median p99 {np.median([p[k]['p99'] for p in rounds]):.2f} ms")
    return rounds


def socket_floor(rate: float, n: int = 400) -> dict:
    """The operating system's own hop for comparison: 8-byte messages between two processes
    over a socketpair, the receiver blocked in ``recv``, at ``rate`` per second."""
    a, b = socket.socketpair()
    pid = os.fork()
    if pid == 0:  # the receiver
        a.close()
        lat = []
        for _ in range(n):
            sent = struct.unpack("q", b.recv(8))[0]  # (received before the clock is read)
            lat.append((time.time_ns() - sent) / 1e6)
        b.sendall(json.dumps(lat).encode() + b"\n")
        os._exit(0)
    b.close()
    for _ in range(n):
        a.send(struct.pack("q", time.time_ns()))
        time.sleep(1.0 / rate)
    lat = json.loads(a.makefile("rb").readline())
    os.waitpid(pid, 0)
    a.close()
    return {"p50": pct(lat, 50), "p99": pct(lat, 99), "load_avg": load_avg()}


def first_puts(size: int, warm: str | None, n: int = 30, period: float = 0.025) -> list[float]:
    """Wall time (ms) of each of the first ``n`` puts of ``size`` bytes on a fresh ``tracks``
    publisher (a router, the publisher's session and a subscriber's session in this process,
    the stages' ``Bus``), one every ``period`` s; with ``warm``, three 20 KB samples on that
    topic first (the subscriber subscribes to it too); ``warm == "shm"`` instead turns Zenoh's
    shared-memory transport back on in the three sessions.  With it, one of the first puts of a
    sample of several KB on a fresh session can block for 5 to 120 ms, because Zenoh's shared
    memory (on by default) sends samples above 3 KB through a pool that the first such put
    creates (``pipeline.transport.SHM_OFF``).  Without it no put of 5.8 KB took over 0.6 ms in
    three runs (docs/pipeline.md, Performance)."""
    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus, Router

    extra = {"transport/shared_memory/enabled": "true"} if warm == "shm" else {}
    warm = None if warm == "shm" else warm
    with Router(ZenohConfig(extra=extra)) as router:
        ep = router.endpoints[0]
        with Bus("puts", "sub", ZenohConfig(connect=[ep], extra=extra), DeliveryConfig()) as sub, \
                Bus("puts", "pub", ZenohConfig(connect=[ep], extra=extra), DeliveryConfig()) as pub:
            sub.subscribe(["tracks"] + ([warm] if warm else []))
            pub.declare(["tracks"])
            time.sleep(1.0)  # both sessions up, the subscriptions known to the router
            for _ in range(3 if warm else 0):
                pub.publish(warm, b"y" * 20_000)
                time.sleep(period)
            out = []
            for i in range(n):
                t0 = time.perf_counter()
                pub.publish("tracks", b"x" * size, {"seq": i, "t": 0})
                out.append((time.perf_counter() - t0) * 1e3)
                time.sleep(period)
    return out


# --------------------------------------------------------------------------- machine floor


#: Payload sizes (bytes) of one frame's samples in the vo2017 pipeline: /measurements,
#: /truth, /tracks (JSON; measured on seed 1, frame 50).
TRAFFIC_SIZES = (1200, 500, 5800)


def _traffic_publisher(endpoint_file: str, rate: float, seconds: float) -> None:
    """(child process) A router and, in the same process, a publisher putting one frame's
    samples (``TRAFFIC_SIZES``, on three topics) ``rate`` times per second for ``seconds``;
    writes the router's endpoint to ``endpoint_file`` first and waits for the subscriber."""
    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus, Router

    with Router(ZenohConfig()) as router:
        Path(endpoint_file).write_text(router.endpoints[0])
        with Bus("traffic", "pub", ZenohConfig(connect=[router.endpoints[0]]), DeliveryConfig()) as bus:
            bus.declare(["measurements", "truth", "tracks"])
            if bus.wait_alive(["sub"], 60, "ready"):
                raise SystemExit("traffic subscriber did not start")
            payloads = [(t, b"x" * n) for t, n in zip(("measurements", "truth", "tracks"), TRAFFIC_SIZES)]
            t0 = time.perf_counter()
            i = 0
            while time.perf_counter() - t0 < seconds:
                for topic, payload in payloads:
                    bus.publish(topic, payload, {"seq": i, "t": time.time_ns()})
                i += 1
                wait = t0 + i / rate - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
            print(i, flush=True)


def _traffic_subscriber(endpoint: str) -> None:
    """(child process) Receive everything on the traffic run until stdin closes."""
    from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
    from bnptrack.pipeline.transport import Bus

    with Bus("traffic", "sub", ZenohConfig(connect=[endpoint]), DeliveryConfig()) as bus:
        bus.subscribe(["measurements", "truth", "tracks"])
        bus.declare_alive("ready")
        stop = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
        n = 0
        while not stop.is_set():
            if bus.recv(0.1) is not None:
                n += 1
        print(n, flush=True)


def machine_floor(off: Offline, rounds: int, tmp: Path) -> dict:
    """The offline tracker alone, and beside bare Zenoh traffic (no tracker, no codec, no
    files: a router, a publisher and a subscriber in two other processes) carrying the
    pipeline's three samples per frame at the offline frame rate; interleaved rounds.  The
    ratio is what the machine charges a tracker for the transport's mere presence: a
    pipeline on this machine cannot reach a higher throughput ratio than it."""
    out = []
    for r in range(rounds):
        fps_alone = off.fps()[0]
        seconds = 1.5 * len(off.frames) / fps_alone + 1.0
        ep_file = tmp / f"traffic{r}.ep"
        pub = subprocess.Popen([sys.executable, __file__, "--traffic-publisher", str(ep_file), str(fps_alone),
                                str(seconds)], stdout=subprocess.PIPE, text=True)
        while not ep_file.exists() or not ep_file.read_text():
            time.sleep(0.02)
        sub = subprocess.Popen([sys.executable, __file__, "--traffic-subscriber", ep_file.read_text()],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        time.sleep(1.0)  # both up and streaming
        fps_beside = off.fps()[0]
        sent = int(pub.communicate(timeout=120)[0].split()[-1])
        got = int(sub.communicate("", timeout=60)[0].split()[-1])
        out.append({"alone_fps": fps_alone, "beside_fps": fps_beside, "ratio": fps_beside / fps_alone,
                    "frames_sent": sent, "samples_received": got, "load_avg": load_avg()})
        print(f"  floor round {r + 1}: offline alone {fps_alone:6.1f} frames/s, beside Zenoh traffic "
              f"{fps_beside:6.1f} frames/s = {fps_beside / fps_alone:.2f} x  ({got}/{3 * sent} samples "
              f"received; load {load_avg():.2f})", flush=True)
    return {"rounds": out, "ratio_median": float(np.median([r["ratio"] for r in out]))}


# --------------------------------------------------------------------------- report


def same_outputs(a: Path, b: Path) -> bool:
    """Whether two ``tracks.mcap`` hold the same frames, truth and tracks (the tracks without
    their timing diagnostic ``ms``): the two sides of the comparison do the same work."""
    from bnptrack.sources.mcap_log import read_log

    def rows(path: Path) -> tuple:
        log = read_log(path)
        tracks = [(e.frame, e.labels, e.assignments, e.assignment_prob,
                   {k: v for k, v in e.diagnostics.items() if k != "ms"},
                   [(t.state.tolist(), t.covariance.tolist(), t.existence) for t in e.tracks]) for e in log.tracks]
        frames = [(f.frame, f.stamp_ns, f.z.tolist(), None if f.truth is None else repr(f.truth)) for f in log.frames]
        return frames, tracks

    return rows(a) == rows(b)


def throughput_rounds(off: Offline, log: Path, args, tmp: Path) -> dict:
    rounds = []
    for r in range(args.rounds):
        fps_off, cpu_off, ms = off.fps()
        fps_stage, cpu_stage = off.stage_fps(tmp / f"stage{r}")
        fps_track, cpu_track = off.track_log_fps(tmp / f"track{r}.mcap", args.rerun)
        fast = pipeline(log, args.tracker, args.seed, tmp / f"fast{r}", 0.0, args.rerun, args.set)
        if not same_outputs(tmp / f"track{r}.mcap", tmp / f"fast{r}" / "tracks.mcap"):
            raise SystemExit(f"round {r + 1}: the pipeline's tracks.mcap differs from bnptrack track's")
        rounds.append({"offline_fps": fps_off, "offline_cpu_ms_per_frame": cpu_off, "offline_step_ms": ms,
                       "stage_fps": fps_stage, "stage_cpu_ms_per_frame": cpu_stage, "track_fps": fps_track,
                       "pipeline": fast, "ratio": fast["fps"] / fps_off, "ratio_track": fast["fps"] / fps_track,
                       "track_cpu_ms_per_frame": cpu_track,
                       "cpu_ratio": cpu_off / fast["cpu_ms_per_frame"]["tracker"],
                       "cpu_ratio_track": cpu_track / fast["cpu_ms_per_frame"]["tracker"]})
        print(f"  round {r + 1}: bnptrack track {fps_track:6.1f} frames/s, pipeline {fast['fps']:6.1f} frames/s "
              f"= {fast['fps'] / fps_track:.2f} x; tracker alone in process {fps_off:6.1f} frames/s "
              f"({fast['fps'] / fps_off:.2f} x)  (load {fast['load_avg']:.2f})", flush=True)
    return {"rounds": rounds, "ratio_median": float(np.median([r["ratio"] for r in rounds])),
            "ratio_track_median": float(np.median([r["ratio_track"] for r in rounds])),
            "cpu_ratio_median": float(np.median([r["cpu_ratio"] for r in rounds])),
            "cpu_ratio_track_median": float(np.median([r["cpu_ratio_track"] for r in rounds]))}


def report_throughput(args, thr: dict) -> bool:
    """Print the throughput rounds' figures; True if the target is met (pipeline >= 0.9 x
    ``bnptrack track``, median of the rounds)."""
    rounds = thr["rounds"]
    med, med_track = thr["ratio_median"], thr["ratio_track_median"]
    off_fps = np.median([r["offline_fps"] for r in rounds])
    pipe_fps = np.median([r["pipeline"]["fps"] for r in rounds])
    track_fps = np.median([r["track_fps"] for r in rounds])
    step = np.concatenate([r["offline_step_ms"] for r in rounds])
    print(f"throughput (median of {len(rounds)} interleaved rounds):")
    print(f"  offline, tracker in process:        {off_fps:7.1f} frames/s (step p50 {pct(step, 50):.2f} ms, "
          f"mean {step.mean():.2f} ms; frames decoded beforehand, no output)")
    stage_fps = np.median([r["stage_fps"] for r in rounds])
    stage_cpu = np.median([r["stage_cpu_ms_per_frame"] for r in rounds])
    print(f"  tracker stage code, no transport:   {stage_fps:7.1f} frames/s ({stage_cpu:.2f} ms CPU per frame; "
          "in process, in-memory bus)")
    print(f"  offline, bnptrack track:            {track_fps:7.1f} frames/s (MCAP in, scores, tracks.mcap out"
          f"{', run.rrd' if args.rerun else ''}: the pipeline's outputs)")
    print(f"  pipeline, as fast as possible:      {pipe_fps:7.1f} frames/s = {med_track:.2f} x bnptrack track "
          f"(per round: {', '.join(format(r['ratio_track'], '.2f') for r in rounds)}); = {med:.2f} x the tracker "
          f"alone in process (per round: {', '.join(format(r['ratio'], '.2f') for r in rounds)})")
    cpu = {k: np.median([r["pipeline"]["cpu_ms_per_frame"].get(k, np.nan) for r in rounds])
           for k in (*STAGES, "tracker_main")}
    cores = {k: np.median([r["pipeline"]["cpu_cores"].get(k, np.nan) for r in rounds]) for k in STAGES}
    cpu_off = np.median([r["offline_cpu_ms_per_frame"] for r in rounds])
    print(f"  CPU per frame: offline {cpu_off:.2f} ms; pipeline stages while streaming: " + ", ".join(
        f"{k} {cpu[k]:.2f} ms ({cores[k]:.2f} core)" for k in STAGES))
    print(f"  of which the tracker's main thread (the frame loop): {cpu['tracker_main']:.2f} ms")
    pstep = np.concatenate([r["pipeline"]["step_ms"] for r in rounds])
    print(f"  tracker.step wall time: offline p50 {pct(step, 50):.2f} ms, mean {step.mean():.2f} ms; in the "
          f"pipeline's tracker stage p50 {pct(pstep, 50):.2f} ms, mean {pstep.mean():.2f} ms")
    cpu_track = np.median([r["track_cpu_ms_per_frame"] for r in rounds])
    print(f"  CPU per frame of bnptrack track: {cpu_track:.2f} ms; bnptrack track's / the tracker stage's: "
          f"{thr['cpu_ratio_track_median']:.2f} (per round: "
          f"{', '.join(format(r['cpu_ratio_track'], '.2f') for r in rounds)}); the tracker alone's / the tracker "
          f"stage's: {thr['cpu_ratio_median']:.2f} (the throughput ratios if the tracker stage had a core of its "
          "own: the load-independent figure)")
    return med_track >= 0.9


def report_latency(args, paced_runs: list[dict], floors: dict) -> bool:
    """Print the paced runs' figures beside their two-hop floors (measured right after each
    run); True if the target is met (median over the runs of added p99 - floor p99 <= 1 ms)."""
    for paced, two in zip(paced_runs, floors["two_hop"]):
        added, e2e = paced["added_ms"], paced["e2e_ms"]
        print(f"latency, paced at {args.rate:g} frames/s ({paced['frames']} frames, load {paced['load_avg']:.2f}):")
        print(f"  source publish -> sink receipt:     p50 {pct(e2e, 50):.2f} ms, p99 {pct(e2e, 99):.2f} ms")
        print(f"  added (minus tracker.step time):    p50 {pct(added, 50):.2f} ms, p99 {pct(added, 99):.2f} ms "
              f"(step p50 {pct(paced['step_ms'], 50):.2f} ms)")
        h = paced["hops_ms"]
        print("  per hop p50 (p99): source -> tracker {:.2f} ({:.2f}) ms; in the tracker (decode, step, encode) "
              "{:.2f} ({:.2f}) ms; tracker -> sink {:.2f} ({:.2f}) ms".format(
                  *(v for k in HOPS for v in (pct(h[k], 50), pct(h[k], 99)))))
        report_segments(paced.get("segments_ms", {}))
        report_sink_gap(paced)
        if all(h.get(k) for k in SPLITS):
            print("  of which the tracker's hand-off (callback -> main thread) {:.2f} ({:.2f}) ms; the same "
                  "/measurements source -> sink {:.2f} ({:.2f}) ms".format(
                      *(v for k in SPLITS for v in (pct(h[k], 50), pct(h[k], 99)))))
        print(f"  two-hop floor ({two['mode']} mode, bare relay, the pipeline's traffic and receipt stamp, "
              f"{args.rate:g}/s, load {two['load_avg']:.2f}): p50 {two['p50']:.2f} ms, p99 {two['p99']:.2f} ms  <->  "
              f"added p99 {pct(added, 99):.2f} ms = floor + {pct(added, 99) - two['p99']:.2f} ms")
        if two.get("first_hop_ms"):
            f = two["first_hop_ms"]
            print(f"  the floor's /measurements publisher -> subscriber (one hop, as the sink gets it): "
                  f"p50 {pct(f, 50):.2f} ms, p99 {pct(f, 99):.2f} ms")
        old = two["bare"]
        print(f"  the one-topic floor (one topic per hop, stamped on the main thread): p50 {old['p50']:.2f} ms, "
              f"p99 {old['p99']:.2f} ms  <->  added p99 = floor + {pct(added, 99) - old['p99']:.2f} ms")
    if "client" in floors:
        print("  transport floor, one hop p50 (p99): " + "; ".join(
            f"{m} {f['p50']:.2f} ({f['p99']:.2f}) ms" for m, f in floors.items() if m in ("client", "peer"))
            + " (the pipeline makes two); the OS's own hop (socketpair): "
            f"{floors['socket']['p50']:.2f} ({floors['socket']['p99']:.2f}) ms")
    over = [pct(p["added_ms"], 99) - f["p99"] for p, f in zip(paced_runs, floors["two_hop"])]
    print(f"  added p99 - two-hop floor p99 per run: {', '.join(format(o, '.2f') for o in over)} ms; median "
          f"{np.median(over):.2f} ms (target: <= 1 ms)")
    old = [pct(p["added_ms"], 99) - f["bare"]["p99"] for p, f in zip(paced_runs, floors["two_hop"])]
    print(f"  ... against the one-topic floor: {', '.join(format(o, '.2f') for o in old)} ms; median "
          f"{np.median(old):.2f} ms")
    return float(np.median(over)) <= 1.0


def report_machine(machine: dict) -> None:
    mf = machine["rounds"]
    print(f"machine floor: offline tracker beside bare Zenoh traffic (3 samples per frame at the offline rate; "
          f"no tracker, codec or files) = {machine['ratio_median']:.2f} x alone (median of {len(mf)} rounds: "
          f"{', '.join(format(r['ratio'], '.2f') for r in mf)}): the highest throughput ratio this machine "
          "leaves a pipeline")


def _pipeline_mode(overrides: list[str]) -> str:
    """The Zenoh mode of the pipeline runs (``--set zenoh.mode=...``; default client)."""
    for item in overrides:
        key, _, value = item.partition("=")
        if key.strip() == "zenoh.mode":
            return value.strip().strip("'\"")
    return "client"


def _child_mode() -> bool:
    """Run the child-process mode named by ``sys.argv`` (a floor's or the traffic's process,
    ``--first-puts``); False when the command line is the benchmark's own."""
    if len(sys.argv) == 5 and sys.argv[1] == "--floor-subscriber":
        _floor_subscriber(sys.argv[2], sys.argv[3], int(sys.argv[4]))
        return True
    if len(sys.argv) == 6 and sys.argv[1] == "--floor-subscriber2":
        _floor_subscriber(sys.argv[2], sys.argv[3], int(sys.argv[4]), "floor2", "tracks", sys.argv[5])
        return True
    if len(sys.argv) == 7 and sys.argv[1] == "--floor-publisher2":
        _floor_publish(sys.argv[2], sys.argv[3], int(sys.argv[4]), float(sys.argv[5]), sys.argv[6])
        return True
    if len(sys.argv) == 4 and sys.argv[1] == "--floor-relay":
        _floor_relay(sys.argv[2], sys.argv[3])
        return True
    if len(sys.argv) == 5 and sys.argv[1] == "--traffic-publisher":
        _traffic_publisher(sys.argv[2], float(sys.argv[3]), float(sys.argv[4]))
        return True
    if len(sys.argv) >= 3 and sys.argv[1] == "--first-puts":  # --first-puts SIZE [WARM_TOPIC|shm]
        d = first_puts(int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else None)
        print(f"first puts of {sys.argv[2]} B: max {max(d):.2f} ms (put #{int(np.argmax(d))}), median "
              f"{np.median(d):.2f} ms; puts over 2 ms: {[(i, round(x, 1)) for i, x in enumerate(d) if x > 2]}")
        return True
    if len(sys.argv) == 3 and sys.argv[1] == "--traffic-subscriber":
        _traffic_subscriber(sys.argv[2])
        return True
    return False


def main() -> None:
    if _child_mode():
        return
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5, help="vo2017 runs of 100 frames in the log")
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rounds", type=int, default=3, help="interleaved offline/pipeline throughput rounds")
    ap.add_argument("--paced", type=int, default=1, help="paced runs, each followed by its two-hop floor")
    ap.add_argument("--rate", type=float, default=20.0, help="paced run (and floors): frames per second")
    ap.add_argument("--only", choices=("throughput", "latency", "acl-floor", "session-floor", "frame-path"),
                    default=None,
                    help="measure only this (default: both, the one-hop floors and the machine floor)")
    ap.add_argument("--rerun", action="store_true", help="also write run.rrd (the sink; bnptrack track --rrd)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="pipeline override for the pipeline runs, e.g. zenoh.mode='client'")
    ap.add_argument("--json", type=Path, default=None, help="write every figure here")
    args = ap.parse_args()

    load0 = load_avg()
    figures: dict = {"args": vars(args), "load_avg_start": load0}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        log = tmp / "bench.mcap"
        n = make_log(log, args.runs)
        print(f"log: {n} frames ({args.runs} x vo2017), tracker {args.tracker}; load average {load0:.2f}", flush=True)
        if args.only in ("acl-floor", "session-floor"):
            figures[args.only] = floor_variant_rounds(args)
            return
        if args.only == "frame-path":
            figures["frame_path"] = frame_path(args)
            if args.json:
                args.json.write_text(json.dumps(figures, indent=1, default=str))
            return
        off = Offline(log, args.tracker, args.seed)
        if args.only != "latency":
            figures["throughput"] = throughput_rounds(off, log, args, tmp)
        if args.only != "throughput":
            figures["paced"], figures["transport_floor"] = paced_rounds(log, args, tmp)
        if args.only is None:
            figures["machine_floor"] = machine_floor(off, args.rounds, tmp)
    print(f"\nlog {n} frames, tracker {args.tracker}, seed {args.seed}; load average at start {load0:.2f}, "
          f"at end {load_avg():.2f} (2 cores)")
    targets = []
    if "throughput" in figures:
        met = report_throughput(args, figures["throughput"])
        targets.append(f"throughput >= 0.9 x bnptrack track: {'met' if met else 'NOT met'}")
    if "paced" in figures:
        met = report_latency(args, figures["paced"], figures["transport_floor"])
        targets.append(f"added p99 <= two-hop floor p99 + 1 ms: {'met' if met else 'NOT met'}")
    if "machine_floor" in figures:
        report_machine(figures["machine_floor"])
    print("targets (medians over the runs): " + "; ".join(targets))
    if args.json:
        figures["load_avg_end"] = load_avg()
        args.json.write_text(json.dumps(figures, indent=1, default=str))


def paced_rounds(log: Path, args, tmp: Path) -> tuple[list[dict], dict]:
    """``--paced`` paced pipeline runs, each followed at once by the two-hop floor at the same
    rate and payload sizes (so that each pair sees about the same machine load); with both
    parts measured, also the one-hop floors and the operating system's."""
    mode = _pipeline_mode(args.set)
    runs, two = [], []
    for r in range(args.paced):
        runs.append(pipeline(log, args.tracker, args.seed, tmp / f"paced{r}", args.rate, args.rerun, args.set,
                             sample_cpu=False))
        n = runs[-1]["frames"]  # as many samples as the run has frames: p99s of the same rank
        two.append({**two_hop_floor(mode, args.rate, n), "mode": mode})
        two[-1]["bare"] = two_hop_floor(mode, args.rate, n, traffic="bare")
        print(f"  paced run {r + 1}: added p50 {pct(runs[-1]['added_ms'], 50):.2f} p99 "
              f"{pct(runs[-1]['added_ms'], 99):.2f} ms, two-hop floor p50 {two[-1]['p50']:.2f} p99 "
              f"{two[-1]['p99']:.2f} ms (the one-topic floor: p50 {two[-1]['bare']['p50']:.2f} p99 "
              f"{two[-1]['bare']['p99']:.2f} ms; load {two[-1]['load_avg']:.2f})", flush=True)
    floors: dict = {"two_hop": two}
    if args.only is None:
        floors.update({m: transport_floor(m, args.rate) for m in ("client", "peer")})
        floors["socket"] = socket_floor(args.rate)
    return runs, floors


if __name__ == "__main__":
    main()
