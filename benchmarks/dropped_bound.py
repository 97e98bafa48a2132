"""A measured lower bound for the "every third frame dropped" target (every third frame dropped).

An **oracle tracker** that knows which detection is which object's (no clutter confusion), when
each object is born and when it dies: it starts an object at its first detection (the BNP
trackers' base distribution ``H`` conditioned on that detection, as their births do), filters it
with the project's own models (the UKF of :mod:`tracker.filtering` with ``params.motion(dt)``,
i.e. the composed ``Q(dt)``, and the frame sensor's measurement model: the same parameters as
the trackers) and ends it at its true death.  Missed detections are predictions only.  It is
scored like ``benchmarks/sensors.py``: OSPA (c = 100 m, p = 1) per frame, ``dropped`` (frames
3, 6, ... removed) against ``plain`` on the frames dropped keeps (same truth, the same
measurement draws: the detections are the very rows of ``sources.synthetic``'s frames).

Two scores per frame:

* ``ospa``: the full OSPA (the only cardinality error is an object not yet detected: a birth at
  a missed or dropped frame is seen one look later);
* ``card-free``: the localisation part only, OSPA between the estimates and the truth of the
  objects the oracle reports (same cardinality by construction).

The oracle's ratio dropped / plain@kept is what the information removed costs a tracker with
these models that makes no association, birth or death error; ``--confirm N`` (report an object
from its ``N``-th detection) adds the looks a tracker in clutter needs to confirm a birth, and
``--tracker-looks ddp`` measures how many looks a real tracker takes (docs/models.md, "Dropped
frames: the oracle bound").

    nice -n 10 python benchmarks/dropped_bound.py --seeds 1-20
    nice -n 10 python benchmarks/dropped_bound.py --seeds 1-20 --scenario random-cv --confirm 4
    nice -n 10 python benchmarks/dropped_bound.py --seeds 1-20 --tracker-looks ddp --workers 2
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bnptrack.sinks.metrics import ospa  # noqa: E402
from bnptrack.sources.scenarios import get_scenario, is_generated  # noqa: E402
from bnptrack.sources.synthetic import measurement_frame_rng, simulate_all  # noqa: E402
from bnptrack.tracker import filtering as kf  # noqa: E402
from bnptrack.tracker.bnp.base_measure import BaseDistribution  # noqa: E402
from bnptrack.tracker.bnp.config import TRACKER_PRESETS  # noqa: E402
from bnptrack.tracker.models.measurement import measurement_kind, wrap_angle  # noqa: E402
from bnptrack.tracker.models.params import ModelParams, load_params  # noqa: E402
from bnptrack.tracker.types import Frame, frame_dt  # noqa: E402

C, P_ORDER = 100.0, 1.0


def labelled_detections(params: ModelParams, frame: Frame, seed: int) -> dict[str, np.ndarray]:
    """The object-originated rows of ``frame`` by object id: the simulator's draws replayed
    (``measurement_frame_rng(seed, k)``, detection indicators then target noise, as
    ``sources.synthetic._Models.measure`` draws them), so they are rows of ``frame.z``."""
    truth = frame.truth
    if truth is None or not truth.states.shape[0]:
        return {}
    sensor = params.frame_sensor(frame)
    rng = measurement_frame_rng(seed, frame.frame)
    detected = params.detection(frame.kind, sensor).sample(rng, truth.states)
    if not detected.any():
        return {}
    z = params.measurement(frame.kind, sensor).sample(rng, truth.states[detected])
    for col in measurement_kind(frame.kind).wrapped:
        z[:, col] = wrap_angle(z[:, col])
    ids = [i for i, d in zip(truth.ids, detected) if d]
    return dict(zip(ids, z))


@dataclass(frozen=True)
class OracleTracker:
    """Known associations, births and deaths; each object filtered on its own (UKF or EKF)."""

    params: ModelParams
    velocity_std: float = TRACKER_PRESETS["ddp-mb"].birth_velocity_std
    turn_std_deg: float = TRACKER_PRESETS["ddp-mb"].birth_turn_std_deg
    filter: str = "ukf"
    confirm: int = 1
    """Report an object from its ``confirm``-th detection on (1: from the first; 2: the one
    look of confirmation a tracker in clutter needs at least)."""

    @cached_property
    def base(self) -> BaseDistribution:
        return BaseDistribution.from_params(self.params, self.velocity_std, np.deg2rad(self.turn_std_deg))

    def run(self, frames: Sequence[Frame], detections: Sequence[dict[str, np.ndarray]]
            ) -> list[tuple[tuple[str, ...], np.ndarray]]:
        """Per frame: the reported ids (alive and detected at least once) and their ``(n, 5)``
        filtered states."""
        tracks: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        looks: dict[str, int] = {}
        prev_frame, prev_stamp, out = -1, 0, []
        for frame, dets in zip(frames, detections):
            dt = frame_dt(prev_frame, prev_stamp, frame.frame, frame.stamp_ns, self.params.T)
            prev_frame, prev_stamp = frame.frame, frame.stamp_ns
            alive = set(frame.truth.ids)
            tracks = {i: self._predict(g, dt) for i, g in tracks.items() if i in alive}  # true deaths
            sensor = self.params.frame_sensor(frame)
            meas = self.params.measurement(frame.kind, sensor)
            clutter = self.params.clutter(frame.kind, sensor)
            for i, z in dets.items():
                looks[i] = looks.get(i, 0) + 1
                if i in tracks:
                    tracks[i] = self._update(meas, tracks[i], z)
                else:  # first detection: H conditioned on it, as a BNP birth
                    m, P = self.base.posterior(meas, clutter, z[None], frame.kind)
                    tracks[i] = (m[0], P[0])
            ids = tuple(i for i in frame.truth.ids if i in tracks and looks[i] >= self.confirm)
            out.append((ids, np.array([tracks[i][0] for i in ids]).reshape(-1, 5)))
        return out

    def _predict(self, g, dt: float):
        predict = kf.ukf_predict if self.filter == "ukf" else kf.ekf_predict
        m, P = predict(self.params.motion(dt), g[0][None], g[1][None])
        return m[0], P[0]

    def _update(self, meas, g, z):
        innovation = kf.ukf_innovation if self.filter == "ukf" else kf.ekf_innovation
        m, P = g[0][None], g[1][None]
        innov = innovation(meas, m, P)
        m_upd, P_upd = kf.kalman_update(meas, innov, m, z[None])
        return m_upd[0], P_upd[0]


def frame_scores(frame: Frame, ids: tuple[str, ...], states: np.ndarray) -> tuple[float, float]:
    """``(ospa, card-free)`` of one frame's oracle estimate."""
    pos = states[:, [0, 2]]
    total = ospa(frame.truth.positions, pos, c=C, p=P_ORDER).total
    seen = np.array([i in set(ids) for i in frame.truth.ids], dtype=bool)
    loc = ospa(frame.truth.positions[seen], pos, c=C, p=P_ORDER).total
    return total, loc


def one_run(job) -> tuple[int, dict[str, dict[int, tuple[float, float]]]]:
    """Both variants of one seed: ``{variant: {frame: (ospa, card-free)}}``."""
    seed, scenario, overrides, filt, confirm = job
    sc = get_scenario(scenario, seed if is_generated(scenario) else None)
    params = sc.adapt_params(load_params("vo2017", overrides))
    frames = simulate_all(sc, params, seed)
    oracle = OracleTracker(params, filter=filt, confirm=confirm)
    out = {}
    for variant in ("plain", "dropped"):
        fr = frames if variant == "plain" else [f for f in frames if f.frame % 3]
        dets = [labelled_detections(params, f, seed) for f in fr]
        est = oracle.run(fr, dets)
        out[variant] = {f.frame: frame_scores(f, ids, s) for f, (ids, s) in zip(fr, est)}
    return seed, out


def reported_by_look(job) -> dict[str, np.ndarray]:
    """How many looks a real tracker needs to report a newborn: per variant, ``(L, 2)`` counts
    over the object-frames of the kept frames, by the object's number of detections so far
    (1..L, the last bin L and more): ``[frames, frames it is reported]``.  Reported: matched to
    a track within c by the optimal assignment (as OSPA pairs them)."""
    from scipy.optimize import linear_sum_assignment

    from bnptrack.tracker.registry import build, kind
    from bnptrack.tracker.state import run
    seed, scenario, overrides, tracker_name, L = job
    sc = get_scenario(scenario, seed if is_generated(scenario) else None)
    params = sc.adapt_params(load_params("vo2017", overrides))
    frames, out = simulate_all(sc, params, seed), {}
    for variant in ("plain", "dropped"):
        fr = frames if variant == "plain" else [f for f in frames if f.frame % 3]
        tracker = build(tracker_name, params, kind(tracker_name).presets[tracker_name])
        looks, counts = {}, np.zeros((L, 2), dtype=np.int64)
        for f, e, _ in run(tracker, fr, seed):
            for i in labelled_detections(params, f, seed):
                looks[i] = looks.get(i, 0) + 1
            X, Y = f.truth.positions, e.positions
            hit = np.zeros(len(X), dtype=bool)
            if len(X) and len(Y):
                D = np.linalg.norm(X[:, None] - Y[None], axis=2)
                r, c = linear_sum_assignment(D)
                hit[r[D[r, c] < C]] = True
            for j, i in enumerate(f.truth.ids):
                if looks.get(i, 0) and f.frame % 3:
                    counts[min(looks[i], L) - 1] += (1, int(hit[j]))
        out[variant] = counts
    return out


def summarise(res) -> dict[str, np.ndarray]:
    """Per seed means on the kept frames: ``plain@kept`` and ``dropped``, both scores, plus
    ``plain`` on all frames."""
    rows = {k: [] for k in ("plain", "plain@kept", "dropped", "plain@kept card-free", "dropped card-free")}
    for _, d in res:
        kept = list(d["dropped"])
        rows["plain"].append(np.mean([v[0] for v in d["plain"].values()]))
        for j, suffix in ((0, ""), (1, " card-free")):
            rows["plain@kept" + suffix].append(np.mean([d["plain"][k][j] for k in kept]))
            rows["dropped" + suffix].append(np.mean([d["dropped"][k][j] for k in kept]))
    return {k: np.array(v) for k, v in rows.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-20", help="N (seeds 1..N) or LO-HI")
    ap.add_argument("--scenario", default="vo2017")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--filter", default="ukf", choices=("ukf", "ekf"))
    ap.add_argument("--confirm", type=int, default=1, help="report objects from their N-th detection")
    ap.add_argument("--tracker-looks", metavar="TRACKER", default=None,
                    help="instead: the fraction of a real tracker's newborns reported, by look")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    lo, _, hi = args.seeds.partition("-")
    seeds = list(range(1, int(lo) + 1)) if not hi else list(range(int(lo), int(hi) + 1))
    if args.tracker_looks:
        return _print_looks(args, seeds)
    jobs = [(s, args.scenario, args.overrides, args.filter, args.confirm) for s in seeds]
    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(args.workers) as ex:
            res = list(ex.map(one_run, jobs))
    else:
        res = [one_run(j) for j in jobs]
    t = summarise(res)
    print(f"oracle ({args.filter}, confirm {args.confirm}), {args.scenario}, seeds {seeds[0]}-{seeds[-1]}, set {args.overrides or '-'}: "
          f"mean OSPA (m, c={C:g}, p={P_ORDER:g})")
    print(f"{'row':<22} {'mean':>7} {'sd':>6} {'vs plain@kept':>14}")
    for k, v in t.items():
        ref = t["plain@kept card-free"] if k.endswith("card-free") else t["plain@kept"]
        rel = f"{100 * (v.mean() / ref.mean() - 1):+.1f}% ({v.mean() - ref.mean():+.2f} m)" if k.startswith("dropped") else ""
        print(f"{k:<22} {v.mean():7.2f} {v.std(ddof=1) if v.size > 1 else 0:6.2f} {rel:>14}")


def _print_looks(args, seeds) -> None:
    from concurrent.futures import ProcessPoolExecutor
    L = 6
    jobs = [(s, args.scenario, args.overrides, args.tracker_looks, L) for s in seeds]
    with ProcessPoolExecutor(max(args.workers, 1)) as ex:
        res = list(ex.map(reported_by_look, jobs))
    print(f"{args.tracker_looks}, {args.scenario}, seeds {seeds[0]}-{seeds[-1]}: objects reported, by "
          f"number of detections so far (kept frames; last column {L} and more)")
    for v in ("plain", "dropped"):
        c = sum(r[v] for r in res)
        print(f"{v:<8} " + " ".join(f"{n + 1}: {100 * h / max(t, 1):5.1f}% of {t:<5d}" for n, (t, h) in enumerate(c)))


if __name__ == "__main__":
    main()
