"""An oracle bound for the generated families (``random``, ``random-cv``).

The oracle of :mod:`benchmarks.dropped_bound` (:class:`OracleTracker`): it knows which
detection is which object's (no clutter confusion, no association error), when each object is
born and when it dies; it starts an object at its first detection with the BNP trackers' base
distribution ``H`` conditioned on it (``birth_velocity_std``, ``birth_turn_std_deg`` of the
``ddp`` preset) and filters it with the trackers' own UKF and models (``params.motion``,
the frame sensor's measurement model).  Its labels are the true ids, so it never swaps.

``--confirm N`` reports an object from its ``N``-th detection on: 1 is the pure localisation
floor of these models; 2 and 3 add the looks a tracker in clutter needs to confirm a newborn
(DDP-EMM reports a newborn about 2.3 scans after its first, docs/trackers.md "Births
anywhere").  Scored as ``benchmarks/accuracy.py`` scores the trackers: mean OSPA (c = 100 m,
p = 1, split into localisation and cardinality parts), OSPA(2) (window 10), mean
``|N_hat - N|``.

    nice -n 10 python3 benchmarks/random_bound.py --scenario random --first-seed 101 --seeds 20
    nice -n 10 python3 benchmarks/random_bound.py --scenario random --seeds 20 --set sigma_accel=1
    nice -n 10 python3 benchmarks/random_bound.py --scenario vo2017 --seeds 20 --set 'birth=[]'

The overrides apply after the scenario's own settings (as in ``benchmarks/accuracy.py``), so
``--set 'birth=[]'`` takes ``vo2017``'s birth regions away (the oracle's ``H`` is then uniform).

``--decompose TRACKER`` runs the tracker on the same frames and walks from the oracle reporting
from detection ``--confirm`` (the first value; 3 by default) to the tracker's own output, one
kind of error at a time (:func:`hybrids`; each step's OSPA / OSPA(2) increment is that kind's
share, and the last step is the tracker's own scores exactly).  Per frame, tracks are matched to
objects by the optimal assignment with cut-off c (as OSPA pairs them).  The steps:

1. ``delay``: the oracle reports each object from the scan the tracker first matches it
   (never, if the tracker never does) instead of from its ``confirm``-th detection;
2. ``gaps``: ... only at the scans the tracker matches it (losses after the first report,
   label swaps onto another object, tracks that end before the object dies);
3. ``young``, ``positions``: the tracker's positions of those matched tracks instead of the
   oracle's (localisation vs the oracle at the tracker's own reporting pattern), first for the
   scans up to :data:`YOUNG` (3) after each object's first match, then for the rest;
4. ``labels``: the tracker's labels instead of the true ids (OSPA(2) only: identity);
5. ``dead``: plus the unmatched tracks whose last matched object has died (late termination);
6. ``false``: plus every other unmatched track (clutter, duplicates): the tracker's output.

It also prints, per object, at which of its detections the tracker first matched it, per
run the track-scans of steps 5 and 6 and the object-scans lost in step 2, and the
``CoastingOracle`` (coast 1) from the same detection for reference.  ``--set`` overrides the
model parameters of both (as above), ``--tracker-set`` the tracker's settings.

``--coast N`` scores :class:`CoastingOracle` instead of the oracle: deaths seen only through
missed detections, as a tracker sees them (an object reported while it has missed at most N
scans in a row; a dead object's track reported for N scans after its last detection).

    nice -n 10 python3 benchmarks/random_bound.py --scenario random --first-seed 101 --decompose ddp
    nice -n 10 python3 benchmarks/random_bound.py --scenario vo2017 --set 'birth=[]' --decompose ddp-mb
    nice -n 10 python3 benchmarks/random_bound.py --scenario random --decompose ddp-mb --tracker-set urn_normaliser=false
    nice -n 10 python3 benchmarks/random_bound.py --scenario random --seeds 20 --coast 1
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks.dropped_bound import OracleTracker, labelled_detections  # noqa: E402
from bnptrack.tracker.types import Frame, frame_dt  # noqa: E402
from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.sources.scenarios import get_scenario, is_generated  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402

C = 100.0


def one_run(job) -> dict[int, dict[str, float]]:
    """``{confirm: scores}`` of one seed, every ``confirm`` on the same frames and detections;
    ``job[4]`` (optional): ``coast`` of :class:`CoastingOracle`, ``None`` = the true deaths."""
    seed, scenario, overrides, confirms = job[:4]
    coast = job[4] if len(job) > 4 else None
    sc = get_scenario(scenario, seed if is_generated(scenario) else None)
    params = apply_overrides(sc.adapt_params(load_params("vo2017")), overrides)  # after the scenario's, as accuracy.py
    frames = simulate_all(sc, params, seed)
    dets = [labelled_detections(params, f, seed) for f in frames]
    truth = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    out = {}
    for n in confirms:
        oracle = OracleTracker(params, confirm=n) if coast is None else CoastingOracle(params, confirm=n, coast=coast)
        est = oracle.run(frames, dets)
        rows = []
        for f, (ids, s) in zip(frames, est):
            o = ospa(f.truth.positions, s[:, [0, 2]], c=C, p=1.0)
            rows.append((o.total, o.localisation, o.cardinality, abs(len(ids) - len(f.truth.ids))))
        labelled = [dict(zip(ids, s[:, [0, 2]])) for ids, s in est]
        r = np.array(rows)
        out[n] = dict(ospa=r[:, 0].mean(), loc=r[:, 1].mean(), card=r[:, 2].mean(), card_err=r[:, 3].mean(),
                      ospa2=float(np.mean(ospa2_series(labelled, truth, window=10, c=C, p=1.0))))
    return out


@dataclass(frozen=True)
class CoastingOracle(OracleTracker):
    """The oracle with deaths seen only through missed detections: an object is reported while
    it has missed at most ``coast`` scans in a row, and a dead object's track goes on being
    predicted (and reported, a false track) for ``coast`` scans after its last detection.  With
    P_D = 0.98 one miss says little (P(dead | one miss) is about 1/2 at a 2 % death hazard), so
    ``coast`` = 1 is what the trackers' existence does (0.66 after one miss, dropped after two);
    ``coast`` = 0 stops reporting a live object at each of its misses.  A track's filter goes
    on, unreported, while it has missed at most ``max(coast, 1) + 1`` scans in a row (as the
    trackers keep a twice-missed cluster, existence ~0.04, and drop it after the third miss);
    an object detected again after that starts anew from ``H``."""

    coast: int = 1

    def run(self, frames: Sequence[Frame], detections: Sequence[dict[str, np.ndarray]]
            ) -> list[tuple[tuple[str, ...], np.ndarray]]:
        tracks: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        looks: dict[str, int] = {}
        misses: dict[str, int] = {}
        prev_frame, prev_stamp, out = -1, 0, []
        for frame, dets in zip(frames, detections):
            dt = frame_dt(prev_frame, prev_stamp, frame.frame, frame.stamp_ns, self.params.T)
            prev_frame, prev_stamp = frame.frame, frame.stamp_ns
            tracks = {i: self._predict(g, dt) for i, g in tracks.items() if misses[i] <= max(self.coast, 1) + 1}
            sensor = self.params.frame_sensor(frame)
            meas, clutter = self.params.measurement(frame.kind, sensor), self.params.clutter(frame.kind, sensor)
            for i in tracks:
                misses[i] += 1
            for i, z in dets.items():
                looks[i], misses[i] = looks.get(i, 0) + 1, 0
                if i in tracks:
                    tracks[i] = self._update(meas, tracks[i], z)
                else:
                    m, P = self.base.posterior(meas, clutter, z[None], frame.kind)
                    tracks[i] = (m[0], P[0])
            ids = tuple(i for i in tracks if looks[i] >= self.confirm and misses[i] <= self.coast)
            out.append((ids, np.array([tracks[i][0] for i in ids]).reshape(-1, 5)))
        return out


STEPS = ("oracle", "delay", "gaps", "young", "positions", "labels", "dead", "false")
YOUNG = 3
"""Scans since the tracker first matched an object up to which its track counts as young."""


@dataclass(frozen=True)
class Scan:
    """One frame as the decomposition sees it (positions are ``(2,)`` arrays)."""

    truth: dict[str, np.ndarray]
    """Live object id -> true position."""
    oracle: dict[str, np.ndarray]
    """Object id -> the oracle's filtered position (live objects detected at least once)."""
    looks: dict[str, int]
    """Object id -> its detections so far (this frame's included)."""
    tracks: dict[str, np.ndarray]
    """The tracker's reported label -> position."""


def match(scan: Scan, c: float = C) -> dict[str, str]:
    """Tracker label -> object id: the optimal assignment on ``min(distance, c)``, pairs nearer
    than ``c`` (as OSPA pairs them)."""
    ids, labels = list(scan.truth), list(scan.tracks)
    if not ids or not labels:
        return {}
    D = np.linalg.norm(np.array([scan.truth[i] for i in ids])[:, None]
                       - np.array([scan.tracks[j] for j in labels])[None], axis=2)
    rows, cols = linear_sum_assignment(np.minimum(D, c))
    return {labels[j]: ids[i] for i, j in zip(rows, cols) if D[i, j] < c}


def hybrids(scans: Sequence[Scan], confirm: int = 3, c: float = C) -> dict[str, list[dict[str, np.ndarray]]]:
    """Per step of :data:`STEPS`, the labelled estimate of every scan (module docstring): from
    the oracle reporting from detection ``confirm`` to the tracker's own output."""
    out: dict[str, list] = {k: [] for k in STEPS}
    first: dict[str, int] = {}
    owner: dict[str, str] = {}
    for k, scan in enumerate(scans):
        m = match(scan, c)
        now = {i: j for j, i in m.items()}  # object id -> its matched label
        for i in now:
            first.setdefault(i, k)
        pos = {i: scan.oracle.get(i, scan.tracks[now[i]] if i in now else None) for i in scan.truth}
        out["oracle"].append({i: scan.oracle[i] for i in scan.truth
                              if i in scan.oracle and scan.looks.get(i, 0) >= confirm})
        out["delay"].append({i: pos[i] for i in scan.truth if first.get(i, k + 1) <= k and pos[i] is not None})
        out["gaps"].append({i: pos[i] for i in now})
        out["young"].append({i: scan.tracks[j] if k - first[i] <= YOUNG else pos[i] for i, j in now.items()})
        out["positions"].append({i: scan.tracks[j] for i, j in now.items()})
        out["labels"].append({j: scan.tracks[j] for j in m})
        dead = {j: p for j, p in scan.tracks.items()
                if j not in m and j in owner and owner[j] not in scan.truth}
        out["dead"].append({**out["labels"][-1], **dead})
        out["false"].append(dict(scan.tracks))
        owner.update(m)
    return out


def first_report_looks(scans: Sequence[Scan], c: float = C) -> dict[str, int]:
    """Object id -> its detections so far at the first scan the tracker matched it (0: before
    its first detection); objects never matched are absent."""
    out: dict[str, int] = {}
    for scan in scans:
        for i in match(scan, c).values():
            out.setdefault(i, scan.looks.get(i, 0))
    return out


def score_steps(scans: Sequence[Scan], steps: dict[str, list[dict[str, np.ndarray]]], c: float = C) -> dict:
    """Per step: mean OSPA, OSPA(2) (window 10) and ``|N_hat - N|`` over the scans."""
    truth = [s.truth for s in scans]
    T = [np.array(list(s.truth.values())).reshape(-1, 2) for s in scans]
    out = {}
    for k, est in steps.items():
        E = [np.array(list(e.values())).reshape(-1, 2) for e in est]
        out[k] = dict(ospa=float(np.mean([ospa(t, e, c=c, p=1.0).total for t, e in zip(T, E)])),
                      ospa2=float(np.mean(ospa2_series(est, truth, window=10, c=c, p=1.0))),
                      card_err=float(np.mean([abs(len(t) - len(e)) for t, e in zip(T, E)])))
    return out


def tracker_scans(tracker_name: str, scenario: str, seed: int, overrides, tracker_overrides) -> list[Scan]:
    """The scans of one seed: truth, the oracle (reporting from the first detection), the looks
    and ``tracker_name``'s output, on the frames ``benchmarks/accuracy.py`` gives it."""
    from benchmarks.accuracy import setup
    from bnptrack.tracker.state import run
    sc, tracker, frames = setup(tracker_name, "vo2017", scenario, seed,
                                [f"params.{o}" for o in overrides] + list(tracker_overrides))
    params = tracker.params
    dets = [labelled_detections(params, f, seed) for f in frames]
    oracle = OracleTracker(params, confirm=1).run(frames, dets)
    looks: dict[str, int] = {}
    scans = []
    for (f, e, _), d, (ids, states) in zip(run(tracker, frames, seed), dets, oracle):
        for i in d:
            looks[i] = looks.get(i, 0) + 1
        scans.append(Scan(truth=dict(zip(f.truth.ids, f.truth.positions)),
                          oracle=dict(zip(ids, states[:, [0, 2]])), looks=dict(looks),
                          tracks={t.label: t.position for t in e.tracks}))
    return scans


def decompose_run(job) -> dict:
    """One seed's step scores, first-report looks and per-run counts (module docstring)."""
    tracker_name, scenario, seed, overrides, tracker_overrides, confirm = job
    scans = tracker_scans(tracker_name, scenario, seed, overrides, tracker_overrides)
    steps = hybrids(scans, confirm)
    objects = set().union(*(s.truth for s in scans))
    ended = {i for i in objects if i not in scans[-1].truth}
    n = {k: sum(len(e) for e in v) for k, v in steps.items()}
    coasting = one_run((seed, scenario, overrides, [confirm], 1))[confirm]
    return dict(scores=score_steps(scans, steps), first=first_report_looks(scans), objects=len(objects), coasting=coasting,
                died=len(ended), gap_scans=n["delay"] - n["gaps"], dead_scans=n["dead"] - n["labels"],
                false_scans=n["false"] - n["dead"])


def run_jobs(fn, jobs: list, workers: int) -> list:
    """``fn`` over ``jobs``, in ``workers`` processes when more than one (results in job order)."""
    if workers <= 1:
        return [fn(j) for j in jobs]
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers) as ex:
        return list(ex.map(fn, jobs))


def print_decomposition(args, seeds) -> None:
    jobs = [(args.decompose, args.scenario, s, args.overrides, args.tracker_set, args.confirm[0]) for s in seeds]
    res = run_jobs(decompose_run, jobs, args.workers)
    print(f"{args.decompose} vs the oracle reporting from detection {args.confirm[0]}, {args.scenario}, seeds "
          f"{seeds.start}-{seeds.stop - 1}, set {args.overrides or '-'}, tracker set {args.tracker_set or '-'}")
    print("| step | OSPA | + | OSPA(2) | + | mean abs(N_hat-N) |")
    print("|---|---|---|---|---|---|")
    prev = None
    for k in STEPS:
        m = {q: np.mean([r["scores"][k][q] for r in res]) for q in ("ospa", "ospa2", "card_err")}
        inc = ("-", "-") if prev is None else (f"{m['ospa'] - prev['ospa']:+.2f}", f"{m['ospa2'] - prev['ospa2']:+.2f}")
        print(f"| {k} | {m['ospa']:.2f} | {inc[0]} | {m['ospa2']:.2f} | {inc[1]} | {m['card_err']:.3f} |")
        prev = m
    ref = {q: np.mean([r["coasting"][q] for r in res]) for q in ("ospa", "ospa2", "card_err")}
    print(f"reference: the oracle from detection {args.confirm[0]} with deaths seen only through misses "
          f"(CoastingOracle, coast 1): {ref['ospa']:.2f} / {ref['ospa2']:.2f} / {ref['card_err']:.3f}")
    looks = np.array([v for r in res for v in r["first"].values()])
    objects = sum(r["objects"] for r in res)
    bins = [f"{b}: {np.sum(looks == b) / objects:.3f}" for b in range(0, 5)]
    print(f"first matched at detection (fraction of {objects} objects): " + ", ".join(bins)
          + f", 5+: {np.sum(looks >= 5) / objects:.3f}, never: {1 - looks.size / objects:.3f}; "
          f"mean {looks.mean():.2f}")
    died = sum(r["died"] for r in res)
    print(f"per run: object-scans lost after the first report {np.mean([r['gap_scans'] for r in res]):.1f}, "
          f"dead-object track-scans {np.mean([r['dead_scans'] for r in res]):.1f} "
          f"({sum(r['dead_scans'] for r in res) / max(died, 1):.2f} per object that died, {died} died), "
          f"other false track-scans {np.mean([r['false_scans'] for r in res]):.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--confirm", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="model parameter override (e.g. sigma_accel=1)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--coast", type=int, default=None, help="deaths seen only through misses: report an "
                    "object while it has missed at most COAST scans in a row (CoastingOracle); default: true deaths")
    ap.add_argument("--decompose", metavar="TRACKER", help="decompose TRACKER's gap to the oracle instead")
    ap.add_argument("--tracker-set", action="append", default=[], metavar="KEY=VALUE",
                    help="tracker setting override, with --decompose (e.g. urn_normaliser=false)")
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    if args.decompose:
        if args.confirm == [1, 2, 3]:
            args.confirm = [3]
        return print_decomposition(args, seeds)
    jobs = [(s, args.scenario, args.overrides, args.confirm, args.coast) for s in seeds]
    res = run_jobs(one_run, jobs, args.workers)
    print(f"oracle (UKF, true associations, births and deaths), {args.scenario}, seeds {seeds.start}-"
          f"{seeds.stop - 1}, set {args.overrides or '-'}, "
          + ("true deaths" if args.coast is None else f"deaths seen through misses, coast {args.coast}"))
    print("| reported from detection | OSPA | loc | card | OSPA(2) w=10 | mean abs(N_hat-N) |")
    print("|---|---|---|---|---|---|")
    for n in args.confirm:
        m = {k: np.mean([r[n][k] for r in res]) for k in ("ospa", "loc", "card", "ospa2", "card_err")}
        print(f"| {n} | {m['ospa']:.2f} | {m['loc']:.2f} | {m['card']:.2f} | {m['ospa2']:.2f} | {m['card_err']:.3f} |")


if __name__ == "__main__":
    main()
