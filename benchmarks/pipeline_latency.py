"""End-to-end latency and throughput of the Zenoh pipeline, next to the same tracker offline.

Builds a long measurement log (``--runs`` vo2017 runs of 100 frames, seeds 1.., frame numbers
and stamps made consecutive), then:

1. **offline**: the tracker over those frames in this process (``tracker.state.run``: no I/O;
   warmed up, best of 3), and ``track_log`` (what ``bnptrack track`` does: read the MCAP log,
   write tracks.mcap);
2. **pipeline, as fast as possible**: ``bnptrack replay LOG --as-fast-as-possible`` (source,
   tracker and sink processes over the launcher's embedded router); throughput = frames
   recorded by the sink / (last ``/tracks`` receipt - first frame publication);
3. **pipeline, paced** at ``--rate`` frames per second (below the tracker's capacity, so
   frames do not queue): per-frame latency from the source's publication to the sink's
   receipt of the frame's ``/tracks``, and the *added* latency = that minus the tracker's own
   compute time for the frame (its ``ms`` diagnostic), with the per-hop breakdown;
4. **transport floor**: one Zenoh hop between two bare processes through a router, at the
   same rate (the pipeline makes two such hops).

    python benchmarks/pipeline_latency.py                    # 5 x 100 frames, ddp
    python benchmarks/pipeline_latency.py --runs 10 --rate 50 --tracker dpyp --json out.json

The sink writes no ``.rrd`` here (``sink.rerun=false``) unless ``--rerun``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from pipeline.launch import launch  # noqa: E402
from pipeline.offline import (  # noqa: E402
    build_tracker,
    resolve_config,
    resolve_params,
    resolve_simulation_params,
    track_log,
)
from pipeline.pipeline_config import load_pipeline  # noqa: E402
from sources.mcap_log import McapLogWriter, iter_frames, read_metadata  # noqa: E402
from sources.scenarios import get_scenario  # noqa: E402
from sources.synthetic import simulate  # noqa: E402
from tracker.state import run  # noqa: E402


def make_log(path: Path, runs: int) -> int:
    """``runs`` vo2017 runs back to back (seeds 1..runs), frames renumbered 1..100*runs."""
    params = resolve_simulation_params("vo2017", "vo2017")
    sc = get_scenario("vo2017")
    meta = {"scenario": "vo2017", "params": "vo2017", "seed": "1..%d" % runs}
    n = 0
    with McapLogWriter(path, meta) as w:
        for r in range(runs):
            for f in simulate(sc, params, r + 1):
                n += 1
                w.write_frame(replace(f, frame=n, stamp_ns=n * 10**9))
    return n


def offline(log: Path, tracker_name: str, seed: int, tmp: Path) -> dict:
    meta = read_metadata(log)
    choice = resolve_params(None, meta)
    config, _ = resolve_config(tracker_name, None)
    tracker = build_tracker(tracker_name, choice.params, config)
    frames = list(iter_frames(log))
    for _ in run(tracker, frames[:20], seed):  # warm up (numba JIT), as the tracker stage does
        pass
    t_core, ms = math.inf, []
    for _ in range(3):  # best of 3
        t0 = time.perf_counter()
        ms_i = [est.diagnostics["ms"] for _, est, _ in run(tracker, frames, seed)]
        if time.perf_counter() - t0 < t_core:
            t_core, ms = time.perf_counter() - t0, ms_i
    t0 = time.perf_counter()
    track_log(log, tmp / "offline.mcap", tracker, seed, meta)
    t_log = time.perf_counter() - t0
    return {
        "frames": len(frames),
        "fps_core": len(frames) / t_core,
        "fps_track_log": len(frames) / t_log,
        "step_ms_p50": float(np.median(ms)),
        "step_ms_p99": float(np.percentile(ms, 99)),
    }


def pipeline(log: Path, tracker_name: str, seed: int, out: Path, rate: float, rerun: bool) -> dict:
    cfg = load_pipeline(None, [
        "source.kind='mcap'", f"source.log='{log}'", f"source.rate={rate}",
        f"tracker.tracker='{tracker_name}'", f"tracker.seed={seed}", f"sink.rerun={str(rerun).lower()}",
    ])
    cfg = replace_struct(cfg, out=str(out), run=f"bench-{int(time.time())}-{int(rate)}")
    t0 = time.perf_counter()
    res = launch(cfg, timeout=1800, handle_signals=True)
    wall = time.perf_counter() - t0
    if not res.ok:
        raise SystemExit(f"pipeline failed: {res.error}")
    s = json.loads((out / "sink.json").read_text())
    e2e = np.array(s["latency"]["e2e_ms"], float)
    step = np.array(s["latency"]["tracker_ms"], float)
    added = e2e - step
    lat = s["latency"]
    hops = {k: float(np.percentile(np.array(lat[k], float), q))
            for k in ("source_to_tracker_ms", "in_tracker_ms", "tracker_to_sink_ms") if lat.get(k)
            for q in (50,)}
    hops99 = {k: float(np.percentile(np.array(lat[k], float), 99))
              for k in ("source_to_tracker_ms", "in_tracker_ms", "tracker_to_sink_ms") if lat.get(k)}
    return {
        "hops_p50": hops,
        "hops_p99": hops99,
        "frames": s["tracks_written"],
        "gaps": sum(len(v) for v in s["gaps"].values()),
        "fps": s["throughput_fps"],
        "wall_s_including_startup": wall,
        "e2e_ms_p50": float(np.percentile(e2e, 50)),
        "e2e_ms_p99": float(np.percentile(e2e, 99)),
        "added_ms_p50": float(np.percentile(added, 50)),
        "added_ms_p99": float(np.percentile(added, 99)),
        "step_ms_p50": float(np.median(step)),
    }


def _floor_subscriber(endpoint: str, n: int) -> None:
    """(child process) receive ``n`` samples and print their one-hop latencies as JSON."""
    from pipeline.pipeline_config import DeliveryConfig, ZenohConfig
    from pipeline.transport import Bus

    with Bus("floor", "sub", ZenohConfig(connect=[endpoint]), DeliveryConfig()) as bus:
        bus.subscribe(["measurements"])
        bus.declare_alive("ready")
        lat = []
        while len(lat) < n:
            ev = bus.recv(10)
            if ev is None:
                break
            lat.append((ev.t_recv_ns - ev.meta["t"]) / 1e6)
    print(json.dumps(lat))


def transport_floor(rate: float, n: int = 400) -> dict:
    """One Zenoh hop between two processes through a router (the same Bus the stages use),
    ~700-byte samples at ``rate`` per second: the floor under the pipeline's per-hop latency."""
    import subprocess

    from pipeline.pipeline_config import DeliveryConfig, ZenohConfig
    from pipeline.transport import Bus, Router

    with Router(ZenohConfig()) as router:
        ep = router.endpoints[0]
        child = subprocess.Popen([sys.executable, __file__, "--floor-subscriber", ep, str(n)],
                                 stdout=subprocess.PIPE, text=True)
        with Bus("floor", "pub", ZenohConfig(connect=[ep]), DeliveryConfig()) as bus:
            if bus.wait_alive(["sub"], 60, "ready"):
                raise SystemExit("floor subscriber did not start")
            for i in range(n):
                bus.publish("measurements", b"x" * 700, {"seq": i, "t": time.time_ns()})
                time.sleep(1.0 / rate)
            out, _ = child.communicate(timeout=60)
    lat = np.array(json.loads(out), float)
    return {"hop_ms_p50": float(np.percentile(lat, 50)), "hop_ms_p99": float(np.percentile(lat, 99))}


def replace_struct(cfg, **kw):
    import msgspec

    return msgspec.structs.replace(cfg, **kw)


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--floor-subscriber":
        _floor_subscriber(sys.argv[2], int(sys.argv[3]))
        return
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5, help="vo2017 runs of 100 frames in the log")
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=40.0, help="paced run: frames per second")
    ap.add_argument("--rerun", action="store_true", help="also write run.rrd in the sink")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        log = tmp / "bench.mcap"
        n = make_log(log, args.runs)
        print(f"log: {n} frames ({args.runs} x vo2017), tracker {args.tracker}, seed {args.seed}")
        off = offline(log, args.tracker, args.seed, tmp)
        fast = pipeline(log, args.tracker, args.seed, tmp / "fast", 0.0, args.rerun)
        paced = pipeline(log, args.tracker, args.seed, tmp / "paced", args.rate, args.rerun)
    floor = transport_floor(args.rate)
    ratio = fast["fps"] / off["fps_core"]
    print(f"offline, in process (tracker.step only):  {off['fps_core']:7.1f} frames/s "
          f"(step p50 {off['step_ms_p50']:.2f} ms, p99 {off['step_ms_p99']:.2f} ms)")
    print(f"offline, bnptrack track (MCAP in/out):    {off['fps_track_log']:7.1f} frames/s")
    print(f"pipeline, as fast as possible:            {fast['fps']:7.1f} frames/s "
          f"= {ratio:.2f} x offline in-process ({fast['frames']} frames, {fast['gaps']} gaps)")
    print(f"pipeline, paced at {args.rate:g} frames/s: source -> sink latency p50 "
          f"{paced['e2e_ms_p50']:.2f} ms, p99 {paced['e2e_ms_p99']:.2f} ms; added to the tracker's "
          f"compute: p50 {paced['added_ms_p50']:.2f} ms, p99 {paced['added_ms_p99']:.2f} ms")
    h50, h99 = paced["hops_p50"], paced["hops_p99"]
    if h50:
        print("  breakdown p50 (p99): source -> tracker {:.2f} ({:.2f}) ms, in the tracker (queue, "
              "decode, step, encode; step alone p50 {:.2f}) {:.2f} ({:.2f}) ms, tracker -> sink {:.2f} "
              "({:.2f}) ms".format(
                  h50["source_to_tracker_ms"], h99["source_to_tracker_ms"], paced["step_ms_p50"],
                  h50["in_tracker_ms"], h99["in_tracker_ms"], h50["tracker_to_sink_ms"],
                  h99["tracker_to_sink_ms"]))
    print(f"  transport floor: one Zenoh hop between two processes via a router, p50 "
          f"{floor['hop_ms_p50']:.2f} ms, p99 {floor['hop_ms_p99']:.2f} ms (the pipeline has two hops)")
    target_ok = ratio >= 0.9 and paced["added_ms_p99"] <= 2.0
    print(f"target (>= 0.9 x throughput, <= 2 ms p99 added): {'met' if target_ok else 'NOT met'}")
    if args.json:
        args.json.write_text(json.dumps({"offline": off, "fast": fast, "paced": paced, "ratio": ratio,
                                         "transport_floor": floor, "load_avg": os.getloadavg(),
                                         "rate": args.rate, "tracker": args.tracker}, indent=1))


if __name__ == "__main__":
    main()
