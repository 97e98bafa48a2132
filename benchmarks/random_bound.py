"""An oracle bound for the generated families (``random``, ``random-cv``; issue 11).

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
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks.dropped_bound import OracleTracker, labelled_detections  # noqa: E402
from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.sources.scenarios import get_scenario, is_generated  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402

C = 100.0


def one_run(job) -> dict[int, dict[str, float]]:
    """``{confirm: scores}`` of one seed, every ``confirm`` on the same frames and detections."""
    seed, scenario, overrides, confirms = job
    sc = get_scenario(scenario, seed if is_generated(scenario) else None)
    params = apply_overrides(sc.adapt_params(load_params("vo2017")), overrides)  # after the scenario's, as accuracy.py
    frames = simulate_all(sc, params, seed)
    dets = [labelled_detections(params, f, seed) for f in frames]
    truth = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    out = {}
    for n in confirms:
        est = OracleTracker(params, confirm=n).run(frames, dets)
        rows = []
        for f, (ids, s) in zip(frames, est):
            o = ospa(f.truth.positions, s[:, [0, 2]], c=C, p=1.0)
            rows.append((o.total, o.localisation, o.cardinality, abs(len(ids) - len(f.truth.ids))))
        labelled = [dict(zip(ids, s[:, [0, 2]])) for ids, s in est]
        r = np.array(rows)
        out[n] = dict(ospa=r[:, 0].mean(), loc=r[:, 1].mean(), card=r[:, 2].mean(), card_err=r[:, 3].mean(),
                      ospa2=float(np.mean(ospa2_series(labelled, truth, window=10, c=C, p=1.0))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--confirm", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="model parameter override (e.g. sigma_accel=1)")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    jobs = [(s, args.scenario, args.overrides, args.confirm) for s in seeds]
    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(args.workers) as ex:
            res = list(ex.map(one_run, jobs))
    else:
        res = [one_run(j) for j in jobs]
    print(f"oracle (UKF, true associations, births and deaths), {args.scenario}, seeds {seeds.start}-"
          f"{seeds.stop - 1}, set {args.overrides or '-'}")
    print("| reported from detection | OSPA | loc | card | OSPA(2) w=10 | mean abs(N_hat-N) |")
    print("|---|---|---|---|---|---|")
    for n in args.confirm:
        m = {k: np.mean([r[n][k] for r in res]) for k in ("ospa", "loc", "card", "ospa2", "card_err")}
        print(f"| {n} | {m['ospa']:.2f} | {m['loc']:.2f} | {m['card']:.2f} | {m['ospa2']:.2f} | {m['card_err']:.3f} |")


if __name__ == "__main__":
    main()
