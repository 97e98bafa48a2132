"""Bring your own sensor: one scene measured several ways.

The vo2017 scene (seeds 1..N; its birth regions) tracked by DDP-EMM (or ``--tracker``; another
scene with ``--scenario``, a generated family drawing one scene per seed), mean OSPA
(c = 100 m, p = 1) over the evaluated frames:

* ``plain``      bearing-range from the origin facing +y, dt = 1 s (the reference);
* ``posed``      bearing-range from a sensor at pose (1500, -700, 40 deg), the world truth (and
                 the birth regions) moved rigidly with it (``sources.synthetic.move_truth``);
* ``xy``         Cartesian detections, R = 10^2 I, same field of view and clutter rate;
* ``irregular``  stamps with dt ~ U[0.5, 1.5] s (truth at those times, ``truth_at_time``);
* ``dropped``    every third frame dropped (frames 3, 6, ...): the kept frames are ``plain``'s own
                 (same truth, same measurement and tracker draws, same frame numbers), and both
                 are scored on the kept frames only (``vs plain`` of this row compares it with
                 ``plain`` on those frames; ``plain@kept`` shows that reference;
                 ``benchmarks/dropped_bound.py`` measures what an oracle tracker loses there);
* ``blanked``    (diagnostic, ``--variants``) dropped's information processed one scan at a time:
                 each dropped frame replaced by an empty scan of a blind sensor (P_D = 0, no
                 clutter), scored on the kept frames.  The dt model is consistent when
                 ``dropped`` matches it: what is left of dropped's loss is the information lost;
* ``camera``     xy detections from a second sensor at (1000, 2200) facing 200 deg (range 3000 m);
* ``two``        ``plain`` radar + ``camera`` interleaved in one stream (evaluated after both
                 frames of each scan): should beat either alone.

Targets: posed, xy, irregular, dropped within 10 % of plain; two below plain and camera.
Each table ends with the OSPA's localisation and cardinality parts (their sum is the total).

    nice -n 5 python benchmarks/sensors.py --seeds 1-20 --workers 2
    nice -n 5 python benchmarks/sensors.py --seeds 1-20 --set process_noise_dt=dwna   # ablation
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sinks.metrics import ospa  # noqa: E402
from bnptrack.sources.scenarios import get_scenario, is_generated  # noqa: E402
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
BLIND = ["sensors.blind.kind='bearing_range'", "sensors.blind.p_detect=0.0", "sensors.blind.clutter_rate=1e-9"]
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
    if variant in ("plain", "dropped", "blanked"):
        frames = simulate_all(sc, base, seed)
        if variant == "dropped":
            frames = [f for f in frames if f.frame % 3]
        if variant == "blanked":  # the same information as dropped, one scan at a time
            blank = lambda f: Frame(f.frame, f.stamp_ns, "blind", f.kind, np.zeros((0, 2)), f.truth)  # noqa: E731
            return (apply_overrides(base, BLIND), [f if f.frame % 3 else blank(f) for f in frames],
                    lambda f: f.sensor != "blind")
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


def one_run(job) -> tuple[str, int, dict[int, float]]:
    """OSPA of every evaluated frame, by frame number."""
    variant, seed, tracker_name, overrides, scenario = job
    sc = get_scenario(scenario, seed if is_generated(scenario) else None)  # a generated scene per seed
    base = sc.adapt_params(load_params("vo2017", overrides))
    params, frames, evaluate = _setup(variant, sc, base, seed)
    tracker = build(tracker_name, params, kind(tracker_name).presets[tracker_name])
    d = {f.frame: _parts(ospa(f.truth.positions, e.positions, c=100.0, p=1.0))
         for f, e, _ in run(tracker, frames, seed) if evaluate(f)}
    return variant, seed, d


def _parts(o) -> tuple[float, float, float]:
    return o.total, o.localisation, o.cardinality


def _seeds(text: str) -> list[int]:
    """``"10"`` (1..10) or ``"101-120"``."""
    lo, _, hi = text.partition("-")
    return list(range(1, int(lo) + 1)) if not hi else list(range(int(lo), int(hi) + 1))


def _table(res, variants, seeds, part: int = 0) -> dict[str, np.ndarray]:
    """Mean OSPA per seed of each variant; ``plain@kept``: plain on the frames ``dropped`` kept.
    ``part``: 0 the total, 1 its localisation part, 2 its cardinality part."""
    by = {(v, s): d for v, s, d in res}
    table = {v: np.array([np.mean([x[part] for x in by[v, s].values()]) for s in seeds]) for v in variants}
    if "plain" in variants and "dropped" in variants:
        table["plain@kept"] = np.array([np.mean([by["plain", s][k][part] for k in by["dropped", s]]) for s in seeds])
    return table


def kalman_floor(sigma_m: float = 35.0, sigma_a: float = 5.0, steps: int = 400) -> float:
    """How much dropping every third frame costs an ideal filter: the steady-state RMS position
    error of a one-axis constant-velocity Kalman filter (noise ``sigma_m``, about 2 deg at 1 km;
    the model's ``Q(dt)``; noiseless truth as in the scenes) on frames kept, dropped over plain.
    No tracker can do better than this ratio on the localisation part of OSPA."""
    from bnptrack.tracker.models.motion import process_noise_block

    def rms(dts):
        P, Pa, H, out = np.eye(2) * 1e6, np.eye(2) * 1e6, np.array([[1.0, 0.0]]), []
        for i in range(steps):
            dt = dts[i % len(dts)]
            F = np.array([[1.0, dt], [0.0, 1.0]])
            P, Pa = F @ P @ F.T + process_noise_block(dt, sigma_a, 1.0), F @ Pa @ F.T
            K = P @ H.T / (P[0, 0] + sigma_m**2)
            A = np.eye(2) - K @ H
            P, Pa = A @ P, A @ Pa @ A.T + K @ K.T * sigma_m**2
            if i > steps // 4:
                out.append(Pa[0, 0])  # the error of the estimate about a noiseless truth
        return float(np.sqrt(np.mean(out)))
    return rms([1.0, 2.0]) / rms([1.0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="10", help="N (seeds 1..N) or LO-HI")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="parameter override for every variant (e.g. process_noise_dt=dwna)")
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--scenario", default="vo2017", help="vo2017, or a generated family (random-cv: scene seed = seed)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    args = ap.parse_args()
    variants = args.variants.split(",")
    seeds = _seeds(args.seeds)
    jobs = [(v, s, args.tracker, args.overrides, args.scenario) for v in variants for s in seeds]
    with ProcessPoolExecutor(args.workers) as ex:
        res = list(ex.map(one_run, jobs))
    table = _table(res, variants, seeds)
    parts = {name: _table(res, variants, seeds, i) for i, name in ((1, "loc"), (2, "card"))}
    print(f"{args.scenario}, {args.tracker}, seeds {seeds[0]}-{seeds[-1]}, set {args.overrides or '-'}: "
          "mean OSPA (m, c=100, p=1)")
    print(f"{'variant':<10} {'mean':>7} {'sd':>6} {'vs plain':>9}  per seed")
    for v in table:
        o = table[v]
        ref = table.get("plain@kept" if v in ("dropped", "blanked") else "plain")
        rel = f"{100 * (o.mean() / ref.mean() - 1):+8.1f}%" if ref is not None else ""
        print(f"{v:<10} {o.mean():7.2f} {o.std(ddof=1) if o.size > 1 else 0:6.2f} {rel:>9}  "
              + " ".join(f"{x:.1f}" for x in o))
    print("parts (localisation + cardinality): "
          + ", ".join(f"{v} {parts['loc'][v].mean():.2f} + {parts['card'][v].mean():.2f}" for v in table))
    if "dropped" in table:
        print(f"ideal-filter floor for dropped (one-axis Kalman, 35 m noise): "
              f"{100 * (kalman_floor() - 1):+.1f}% position error")


if __name__ == "__main__":
    main()
