"""Bring your own sensor: one scene measured several ways (issue 13 targets).

The vo2017 scene (seeds 1..N; its birth regions) tracked by DDP-EMM (or ``--tracker``), mean
OSPA (c = 100 m, p = 1) over the evaluated frames:

* ``plain``      bearing-range from the origin facing +y, dt = 1 s (the reference);
* ``posed``      bearing-range from a sensor at pose (1500, -700, 40 deg), the world truth (and
                 the birth regions) moved rigidly with it (``sources.synthetic.move_truth``);
* ``xy``         Cartesian detections, R = 10^2 I, same field of view and clutter rate;
* ``irregular``  stamps with dt ~ U[0.5, 1.5] s (truth at those times, ``truth_at_time``);
* ``dropped``    every third frame dropped (evaluated on the frames kept);
* ``camera``     xy detections from a second sensor at (1000, 2200) facing 200 deg (range 3000 m);
* ``two``        ``plain`` radar + ``camera`` interleaved in one stream (evaluated after both
                 frames of each scan): should beat either alone.

Targets: posed, xy, irregular, dropped within 10 % of plain; two below plain and camera.

    nice -n 5 python benchmarks/sensors.py --seeds 10
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sinks.metrics import ospa  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import (  # noqa: E402
    measurement_frame_rng, measure_with, move_truth, simulate_all, simulate_sensors, truth_at_time)
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import BirthComponent, load_params  # noqa: E402
from bnptrack.tracker.registry import build, kind  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402
from bnptrack.tracker.types import Frame, Truth  # noqa: E402

POSE = (1500.0, -700.0, float(np.deg2rad(40.0)))
CAMERA = ["sensors.cam.kind='xy'", "sensors.cam.x=1000.0", "sensors.cam.y=2200.0",
          "sensors.cam.heading_deg=200.0", "sensors.cam.range_max=3000.0"]
VARIANTS = ("plain", "posed", "xy", "irregular", "dropped", "camera", "two")
S = 10**9


def _moved_birth(params, pose):
    out = []
    for c in params.birth:
        m = move_truth(Truth(("b",), np.array([c.mean])), pose).states[0]
        out.append(BirthComponent(c.r, m.tolist(), c.std))  # std isotropic in position and velocity
    return out


def _frames_posed(sc, params, seed, overrides, pose, sensor_kind):
    """The scene's truth moved by ``pose``, measured by sensor ``s`` declared at ``pose``."""
    deg = np.rad2deg(pose[2])
    p = apply_overrides(params, overrides + [f"sensors.s.kind='{sensor_kind}'", f"sensors.s.x={pose[0]}",
                                             f"sensors.s.y={pose[1]}", f"sensors.s.heading_deg={deg}"])
    frames = []
    for k, tr in enumerate(sc.truth(1.0), start=1):
        moved = move_truth(tr, pose)
        z, kd, ps = measure_with(measurement_frame_rng(seed, k), moved, p, "bearing_range", "s")
        frames.append(Frame(k, k * S, "s", kd, z, moved, pose=ps))
    return frames, p


def _frames_irregular(sc, params, seed):
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0x1E,)))
    t, frames = 1.0, []
    while t <= sc.K:
        j = len(frames) + 1
        tr = truth_at_time(sc, t)
        z, kd, _ = measure_with(measurement_frame_rng(seed, j), tr, params, "bearing_range", "sim0")
        frames.append(Frame(j, int(round(t * S)), "sim0", kd, z, tr))
        t += rng.uniform(0.5, 1.5)
    return frames


def _setup(variant, sc, base, seed):
    """``(params, frames, evaluate(frame) -> bool)`` of one variant."""
    every = lambda f: True  # noqa: E731
    if variant in ("plain", "dropped"):
        frames = simulate_all(sc, base, seed)
        if variant == "dropped":
            frames = [f for f in frames if f.frame % 3]
        return base, frames, every
    if variant == "posed":
        p = apply_overrides(base, [])
        import msgspec
        p = msgspec.structs.replace(p, birth=_moved_birth(p, POSE))
        frames, p = _frames_posed(sc, p, seed, [], POSE, "bearing_range")
        return p, frames, every
    if variant == "xy":
        frames, p = _frames_posed(sc, base, seed, ["sigma_xy=10.0"], (0.0, 0.0, 0.0), "xy")
        return p, frames, every
    if variant == "irregular":
        return base, _frames_irregular(sc, base, seed), every
    p = apply_overrides(base, CAMERA + ["sensors.radar.kind='bearing_range'"])
    if variant == "camera":
        return p, list(simulate_sensors(sc, p, seed, ["cam"])), every
    return p, list(simulate_sensors(sc, p, seed, ["radar", "cam"])), (lambda f: f.sensor == "cam")


def one_run(job) -> tuple[str, int, float]:
    variant, seed, tracker_name = job
    sc = get_scenario("vo2017")
    base = sc.adapt_params(load_params("vo2017"))
    params, frames, evaluate = _setup(variant, sc, base, seed)
    tracker = build(tracker_name, params, kind(tracker_name).presets[tracker_name])
    d = [ospa(f.truth.positions, e.positions, c=100.0, p=1.0).total
         for f, e, _ in run(tracker, frames, seed) if evaluate(f)]
    return variant, seed, float(np.mean(d))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    args = ap.parse_args()
    variants = args.variants.split(",")
    jobs = [(v, s, args.tracker) for v in variants for s in range(1, args.seeds + 1)]
    with ProcessPoolExecutor(args.workers) as ex:
        res = list(ex.map(one_run, jobs))
    table = {v: np.array([o for vv, _, o in res if vv == v]) for v in variants}
    ref = table.get("plain")
    print(f"vo2017, {args.tracker}, seeds 1-{args.seeds}: mean OSPA (m, c=100, p=1)")
    print(f"{'variant':<10} {'mean':>7} {'sd':>6} {'vs plain':>9}  per seed")
    for v in variants:
        o = table[v]
        rel = f"{100 * (o.mean() / ref.mean() - 1):+8.1f}%" if ref is not None else ""
        print(f"{v:<10} {o.mean():7.2f} {o.std(ddof=1) if o.size > 1 else 0:6.2f} {rel:>9}  "
              + " ".join(f"{x:.1f}" for x in o))


if __name__ == "__main__":
    main()
