"""How DDP-EMM scales with the number of objects: ms/frame, fps, peak RSS, OSPA, tracked fraction.

    taskset -c 0 nice -n 5 python3 benchmarks/scale.py [--ns 10,100,300,1000,3000] [--frames 30]

**Scene family ``scale-N``** (the vo2017 geometry grown so that density stays constant):

* the vo2017 bearing-range sensor at the origin, field of view bearing +-90 deg x range
  [0, R] with ``R = 2000 m * sqrt(N / 10)`` (vo2017 has about 10 objects in its 2000 m half
  disc, so object density is the paper's for every N);
* bearing noise ``2 deg * 2000 m / R`` (cross-range noise at the edge of the field stays the
  vo2017 figure, 70 m; a fixed 2 deg at 60 km would be 2 km), range noise 10 m;
* N objects, uniform over the half disc between 0.05 R and 0.95 R and bearing +-80 deg,
  straight lines (constant velocity, no turn) at 5-15 m/s in a uniform heading; they exist
  for the whole run; an object is truth (and can be detected) while it is inside the field;
* P_D = 0.98, clutter ``N`` per scan (``--clutter-ratio`` x N) uniform over the field, so a
  frame of 1000 objects holds about 2000 measurements; anywhere-birth rate 0.01 N per scan
  (vo2017's 0.1 at N = 10);
* the tracker starts empty (births anywhere: every object is born from its measurements).

**Figures per N** (one subprocess per N, so peak RSS is that N's): ``ms_per_frame`` the median
wall time of ``step`` over frames 1.. (frame 0 loads numba's cache), ``fps = 1000 / ms``,
``cpu_ms_per_frame`` the median CPU time of the same steps (``time.thread_time``: on a shared
machine wall time also counts the time other processes hold the core),
``rss_mib`` the process's peak resident set (``resource.getrusage``), ``ospa`` (c = 100 m,
p = 1) averaged over the last 20 frames, ``tracked_fraction`` the fraction of true objects
with a reported track within 100 m, averaged over the last 20 frames.  ``--budget-s`` stops
a run early (the row says how many frames it ran).  ``growth`` is the mean ms/frame of the
last 5 frames over that of frames 1-5 (does the per-frame cost stay flat over the run?),
``growth_cpu`` the same of the CPU times.  The
last line printed is one JSON object ``{"results": [...]}``.

**Scene family ``dense-N``** (``--mode dense``): the vo2017 sensor's own field whatever N (the
2000 m half disc, bearing noise 2 deg, range noise 10 m, P_D 0.98, 15 clutter per scan, births
anywhere: the vo2017 model unchanged), N objects placed and moving as above, so at N = 1000 a
frame holds about 1000 measurements in a field vo2017 fills with 10.  The tracker starts with
one track at each true state (existence 1), one period before frame 0, of position and velocity
std ``--seed-std`` (10 m, 2 m/s: tighter than the filter holds in this field, about 20 m and
8 m/s from frame 6 on, so frames 1-5 gate fewer pairs than the rest of the run).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import time

import msgspec
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

LAST = 20  # frames averaged for OSPA and tracked_fraction
SEED_FRAME = -1_000_000  # the frame in the labels of the dense scene's initial tracks


def scene_params(n: int, clutter_ratio: float):
    from bnptrack.tracker.models.params import load_params

    R = 2000.0 * np.sqrt(n / 10.0)
    return msgspec.structs.replace(load_params("vo2017"), range_max=float(R), clutter_rate=float(clutter_ratio * n),
                                   sigma_bearing_deg=float(2.0 * 2000.0 / R), birth_rate=0.01 * n)


def dense_params():
    """The ``dense-N`` scene's model: vo2017's own (its 2 km half disc, bearing-range, P_D 0.98,
    15 clutter per scan, births anywhere), whatever N."""
    from bnptrack.tracker.models.params import load_params

    return load_params("vo2017")


def simulate(n: int, frames: int, seed: int, clutter_ratio: float, dense: bool = False):
    """Frames of the ``scale-N`` (or ``dense-N``) scene (module docstring) and the true states
    one period before frame 0 (``(n, 5)``, what :func:`seeded_state` starts from)."""
    from bnptrack.tracker.types import Frame, Truth

    params = dense_params() if dense else scene_params(n, clutter_ratio)
    meas = params.measurement("bearing_range")
    R, half = params.range_max, np.deg2rad(90.0)
    rng = np.random.default_rng(seed)
    rad = R * np.sqrt(rng.uniform(0.05**2, 0.95**2, n))
    brg = rng.uniform(-np.deg2rad(80.0), np.deg2rad(80.0), n)
    speed, heading = rng.uniform(5.0, 15.0, n), rng.uniform(-np.pi, np.pi, n)
    pos0 = np.stack([rad * np.sin(brg), rad * np.cos(brg)], axis=1)
    vel = np.stack([speed * np.sin(heading), speed * np.cos(heading)], axis=1)
    ids = np.array([f"o{i}" for i in range(n)])
    out, before = [], np.column_stack([pos0[:, 0] - params.T * vel[:, 0], vel[:, 0],
                                       pos0[:, 1] - params.T * vel[:, 1], vel[:, 1], np.zeros(n)])
    for k in range(frames):
        pos = pos0 + k * params.T * vel
        states = np.column_stack([pos[:, 0], vel[:, 0], pos[:, 1], vel[:, 1], np.zeros(n)])
        h = meas.h(states)
        inside = (np.abs(h[:, 0]) <= half) & (h[:, 1] <= R)
        det = inside & (rng.random(n) < params.p_detect)
        z_obj = meas.sample(rng, states[det])
        n_c = rng.poisson(params.clutter_rate)
        z_c = np.column_stack([rng.uniform(-half, half, n_c), rng.uniform(0.0, R, n_c)])
        z = np.concatenate([z_obj, z_c])[rng.permutation(det.sum() + n_c)]
        out.append(Frame(k, int(k * params.T * 1e9), "radar0", "bearing_range", z,
                         Truth(tuple(ids[inside].tolist()), states[inside])))
    return params, out, before


def seeded_state(tracker, x: np.ndarray, pos_std: float = 10.0, vel_std: float = 2.0):
    """The tracker's initial state holding one track per row of ``x`` (existence 1, popularity
    1, covariance ``pos_std`` m / ``vel_std`` m/s / 0.01 rad/s; the group level's clusters empty;
    a GLMB with one hypothesis holding them all)."""
    import dataclasses

    state = tracker.initial_state()
    n = len(x)
    cov = np.repeat(np.diag([pos_std**2, vel_std**2, pos_std**2, vel_std**2, 0.01**2])[None], n, axis=0)
    # "<frame>.<index>" as births are, of a frame long before the run: tracks that exist before
    # it are not births of its first frames (the object level's alpha posterior counts the
    # births of frame k - birth_lag, which would count these 1000s if labelled frame -1)
    labels = tuple(f"{SEED_FRAME}.{i}" for i in range(n))
    names = {f.name for f in dataclasses.fields(state)}
    if "hyp_tracks" in names:
        return dataclasses.replace(state, labels=labels, mean=x.copy(), cov=cov,
                                   hyp_tracks=np.arange(n, dtype=np.int64)[None], log_w=np.zeros(1))
    extra = {k: np.full(n, -1, dtype=np.int64) for k in ("cluster", "counted") if k in names}
    return dataclasses.replace(state, labels=labels, mean=x.copy(), cov=cov, existence=np.ones(n),
                               popularity=np.ones(n), **extra)


def tracked_fraction(truth_pos: np.ndarray, track_pos: np.ndarray, radius: float = 100.0) -> float:
    """Fraction of true positions with a track position within ``radius``."""
    from scipy.spatial import cKDTree

    if len(truth_pos) == 0:
        return 1.0
    if len(track_pos) == 0:
        return 0.0
    d, _ = cKDTree(track_pos).query(truth_pos, k=1)
    return float(np.mean(d <= radius))


def run_one(n: int, frames: int, seed: int, clutter_ratio: float, budget_s: float, name: str = "ddp-mb",
            dense: bool = False, seed_std: tuple[float, float] = (10.0, 2.0)) -> dict:
    from bnptrack.sinks.metrics import ospa
    from bnptrack.tracker.registry import build
    from bnptrack.tracker.state import tracker_frame_rng

    params, fr, before = simulate(n, frames, seed, clutter_ratio, dense)
    tracker = build(name, params)
    state = seeded_state(tracker, before, *seed_std) if dense else tracker.initial_state()
    ms, cpu, ospas, fracs, t_start = [], [], [], [], time.perf_counter()
    digest = hashlib.sha1()
    n_meas = []
    for f in fr:
        t0, c0 = time.perf_counter(), time.thread_time()
        state, est = tracker.step(state, f, tracker_frame_rng(seed, f.frame))
        ms.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.thread_time() - c0) * 1e3)
        n_meas.append(f.n_measurements)
        for t in est.tracks:
            digest.update(t.label.encode() + np.asarray(t.state, dtype=float).tobytes())
        if f.frame >= frames - LAST:
            X = f.truth.positions
            Y = np.array([t.position for t in est.tracks]).reshape(-1, 2)
            ospas.append(ospa(X, Y, c=100.0, p=1.0).total)
            fracs.append(tracked_fraction(X, Y))
        if time.perf_counter() - t_start > budget_s:
            break
    med = float(np.median(ms[1:] if len(ms) > 1 else ms))
    growth = [float(np.mean(x[-5:]) / np.mean(x[1:6])) if len(x) >= 11 else None for x in (ms, cpu)]
    return {"n": n, "frames": len(ms), "measurements_per_frame": float(np.mean(n_meas)),
            "ms_per_frame": round(med, 2), "fps": round(1e3 / med, 2),
            "cpu_ms_per_frame": round(float(np.median(cpu[1:] if len(cpu) > 1 else cpu)), 2),
            "tracked_fraction": round(float(np.mean(fracs)), 4) if fracs else None,
            "rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
            "ospa": round(float(np.mean(ospas)), 2) if ospas else None,
            "n_tracks_last": len(est.tracks), "tracks_sha1": digest.hexdigest()[:16],
            "growth": None if growth[0] is None else round(growth[0], 3),
            "growth_cpu": None if growth[1] is None else round(growth[1], 3),
            "ms_first": [round(x, 1) for x in ms[:10]], "ms_last": [round(x, 1) for x in ms[-5:]]}


def _seed_std(text: str) -> tuple[float, float]:
    """``--seed-std POS,VEL``: two positive numbers."""
    try:
        pos, vel = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected POS,VEL (two numbers), got {text!r}") from None
    if not (pos > 0 and vel > 0 and np.isfinite(pos) and np.isfinite(vel)):
        raise argparse.ArgumentTypeError(f"POS and VEL must be positive and finite, got {text!r}")
    return pos, vel


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ns", default="10,100,300,1000,3000")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--clutter-ratio", type=float, default=1.0)
    ap.add_argument("--budget-s", type=float, default=600.0, help="stop a run after this many seconds")
    ap.add_argument("--tracker", default="ddp-mb", help="a registry name: ddp-mb (single level, the figures "
                    "of docs/performance.md) or ddp (the two-level default of the commands)")
    ap.add_argument("--mode", choices=("scale", "dense"), default="scale",
                    help="scale: the field grows with N (constant density); dense: the vo2017 field for every N")
    ap.add_argument("--seed-std", type=_seed_std, default=(10.0, 2.0), metavar="POS,VEL",
                    help="dense mode: the initial tracks' position (m) and velocity (m/s) std (default 10,2)")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(run_one(args.one, args.frames, args.seed, args.clutter_ratio, args.budget_s, args.tracker,
                                 args.mode == "dense", args.seed_std)))
        return
    results = []
    print("| N | meas/frame | frames | ms/frame (median) | fps | CPU ms/frame (median) | peak RSS MiB | OSPA "
          "| tracked_fraction | growth (wall, CPU) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n in [int(x) for x in args.ns.split(",")]:
        cmd = [sys.executable, __file__, "--one", str(n), "--frames", str(args.frames), "--seed", str(args.seed),
               "--clutter-ratio", str(args.clutter_ratio), "--budget-s", str(args.budget_s), "--tracker", args.tracker,
               "--mode", args.mode, "--seed-std", ",".join(map(str, args.seed_std))]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            print(f"| {n} | failed: {out.stderr.strip().splitlines()[-1:]} |", flush=True)
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        results.append(r)
        print(f"| {n} | {r['measurements_per_frame']:.0f} | {r['frames']} | {r['ms_per_frame']} | {r['fps']} "
              f"| {r['cpu_ms_per_frame']} "
              f"| {r['rss_mib']} | {r['ospa']} | {r['tracked_fraction']} | {r['growth']}, {r['growth_cpu']} |", flush=True)
    print(json.dumps({"results": results}))


if __name__ == "__main__":
    main()
