"""Reliability of the published existence: per decile of predicted existence, the fraction of
published tracks that are real (matched to a true object within ``--gate`` metres, default the
OSPA cut-off of 100 m, by the optimal assignment of the frame's tracks to its true objects).
``--weights 0`` scores the existence as published; a positive weight applies
:class:`tracker.calibration.ExistenceCalibration` with that prior weight (and
``--hazard-weight``) to the published estimates (meaningful on a tracker run with
``--set objects.calibration_weight=0`` for ``ddp``/``dpyp``, ``--set calibration_weight=0`` for
``ddp-mb``/``dpyp-mb``: their published existence is then the model's).

    python benchmarks/existence_calibration.py --scenario random --seeds 20 --weights 0
    python benchmarks/existence_calibration.py --scenario vo2017 --set 'params.birth=[]' --seeds 20 --weights 0
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, os.path.dirname(__file__))

from lag import online_run  # noqa: E402

try:  # absent from versions without the calibration: the tables and the fingerprint still work
    from bnptrack.tracker.calibration import HAZARD_WEIGHT, ODDS_WEIGHT, CalibrationState, ExistenceCalibration
except ImportError:  # pragma: no cover - older versions
    HAZARD_WEIGHT = ODDS_WEIGHT = CalibrationState = ExistenceCalibration = None


def real_flags(frame, est, gate: float) -> np.ndarray:
    """Whether each track of ``est`` is matched to a true object within ``gate`` metres."""
    real = np.zeros(len(est.tracks), bool)
    if est.tracks and frame.truth is not None and frame.truth.ids:
        D = np.linalg.norm(est.positions[:, None] - frame.truth.positions[None], axis=2)
        rows, cols = linear_sum_assignment(np.minimum(D, gate))
        real[rows[D[rows, cols] < gate]] = True
    return real


def calibrated(online, params, weight: float, hazard_weight: float, odds_weight: float = ODDS_WEIGHT):
    """The estimates with the calibrated existence of prior weight ``weight`` (0: as they are)."""
    if not weight:
        return online
    cal = ExistenceCalibration(params.p_survival, params.p_detect, weight, hazard_weight, odds_weight)
    state, out = CalibrationState(), []
    for e in online:
        state, e = cal.step(state, e)
        out.append(e)
    return out


def fingerprint(online) -> str:
    """A digest of the published tracks without their existence: labels, states, covariances,
    clusters and assignments of every frame (equal digests: the same tracks were published)."""
    h = hashlib.sha256()
    for e in online:
        for t in e.tracks:
            h.update(f"{t.label}/{t.cluster}".encode())
            h.update(np.asarray(t.state, float).tobytes())
            h.update(np.asarray(t.covariance, float).tobytes())
        h.update(repr(e.assignments).encode())
    return h.hexdigest()


def one_seed(job):
    tracker, params, scenario, seed, overrides, gate, weights, hw, ow = job
    _sc, tr, frames, online, _ms = online_run(tracker, params, scenario, seed, overrides)
    real = np.array([r for f, e in zip(frames, online) for r in real_flags(f, e, gate)], bool)
    ex, ms = {}, {}
    for w in weights:
        t0 = time.process_time()
        out = calibrated(online, tr.params, w, hw, ow)
        ms[w] = (time.process_time() - t0) * 1e3 / len(online)
        ex[w] = np.array([t.existence for e in out for t in e.tracks], float)
    return ex, real, fingerprint(online), ms


def table(ex: np.ndarray, real: np.ndarray) -> None:
    print("| existence | track-frames | mean predicted | fraction real | gap |")
    print("|---|---|---|---|---|")
    edges = np.linspace(0.0, 1.0, 11)
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (ex >= lo) & ((ex < hi) if hi < 1 else (ex <= hi))
        if sel.any():
            p, q = ex[sel].mean(), real[sel].mean()
            flag = " **" if sel.sum() >= 200 and abs(q - p) > 0.07 else ""
            print(f"| [{lo:.1f}, {hi:.1f}{')' if hi < 1 else ']'} | {sel.sum()} | {p:.3f} | {q:.3f} | {q - p:+.3f}{flag} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracker", default="ddp")
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--gate", type=float, default=100.0, help="metres within which a track is real")
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0],
                    help="prior weights of a calibration applied here (0: the existence as published)")
    ap.add_argument("--hazard-weight", type=float, default=HAZARD_WEIGHT)
    ap.add_argument("--odds-weight", type=float, default=ODDS_WEIGHT)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    jobs = [(args.tracker, args.params, args.scenario, s, args.overrides, args.gate, args.weights, args.hazard_weight, args.odds_weight) for s in seeds]
    with ProcessPoolExecutor(args.workers) as pool:
        res = list(pool.map(one_seed, jobs))
    real = np.concatenate([r[1] for r in res])
    print(f"{args.tracker} on {args.scenario}, seeds {seeds.start}..{seeds.stop - 1}, overrides "
          f"{args.overrides or 'none'}, gate {args.gate:g} m: {len(real)} published track-frames "
          f"(** : 200 or more track-frames and outside +-0.07)")
    digest = hashlib.sha256("".join(r[2] for r in res).encode()).hexdigest()[:16]
    print(f"published tracks without their existence (labels, states, covariances, clusters, assignments): "
          f"fingerprint {digest}")
    for w in args.weights:
        ms = np.mean([r[3][w] for r in res])
        print(f"\n{'published existence' if not w else f'calibrated here, prior weight {w:g} ({ms:.3f} ms per frame)'}:")
        table(np.concatenate([r[0][w] for r in res]), real)


if __name__ == "__main__":
    main()
