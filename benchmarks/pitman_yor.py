"""Does the Pitman-Yor discount help?  DPY-STP (``dpyp``) against DDP-EMM (``ddp``) on the
``groups-py`` family, whose true partition is a Pitman-Yor partition of 100-300 objects with
discount ``d`` (``scene.py_discount``; d = 0 is the control), groups overlapping in space and
velocity (``sources/scene_families.py``).

Per (d, seed) both trackers run on the same scene and measurements, each as a
:class:`tracker.bnp.group_posterior.PosteriorGroupTracker` (the same estimates as the plain
tracker, plus, at frames ``--first-frame``, ``+ --every``, ..., ``--chains`` chains of
``--burn`` + ``--keep`` sweeps of the object partition).  Scored per run:

* OSPA (c 100 m, p 1), OSPA(2) (window 10), mean abs(N_hat - N), over all frames;
* ``ari``: the adjusted Rand index (``benchmarks/groups.py``'s ``frame_ari``) of the point
  estimate minimising the posterior expected Binder loss (best draw, then greedy single-item
  moves; :func:`sinks.partitions.binder_point`) of the pooled kept draws, mean over the
  summarised frames where a true group has 2 matched members; ``ari_sample``: the same on the
  tracker's own one sample at those frames;
* convergence: split R-hat of the number of clusters over the chains' kept draws, per
  summarised frame (its median, and the fraction of frames at most 1.1);
* the posterior of d per frame on the tracker's grid (mean and 95 % interval).

Every finished run is appended to ``--journal`` (JSON lines); a restarted command runs only
the (d, seed) pairs the journal lacks.  ``--analyse`` prints the paired differences
(``dpyp - ddp``; ARI: positive favours DPY-STP; OSPA, OSPA(2): negative), their standard
errors, 95 % intervals, the verdict and the runs the pre-stated effects need
(benchmarks/preregistration/pitman_yor.md).

    nice -n 5 python3 benchmarks/pitman_yor.py --first-seed 101 --seeds 4 --journal /tmp/py_dev.jsonl
    python3 benchmarks/pitman_yor.py --analyse --journal benchmarks/pitman_yor/runs.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from groups import frame_ari  # noqa: E402

from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.sinks.partitions import binder_point, n_blocks, similarity_matrix, split_rhat  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp.group_posterior import PosteriorGroupTracker, grid_interval  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.registry import build, kind  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402

TRACKERS = ("ddp", "dpyp")
FAMILY = "groups-py"
#: Metric -> +1 if larger is better for DPY-STP's claim, -1 if smaller is.
METRICS = {"ari": +1, "ospa": -1, "ospa2": -1}
D_FRAMES = (10, 20, 30, 40, 50)
#: The pre-registered effects (benchmarks/preregistration/pitman_yor.md): ARI, OSPA (m), OSPA(2) (m).
EFFECTS = {"ari": 0.02, "ospa": 0.5, "ospa2": 0.5}


def posterior_tracker(name: str, params, opts: dict, overrides: tuple[str, ...] = ()) -> PosteriorGroupTracker:
    base = build(name, params, apply_overrides(kind(name).presets[name], list(overrides)))
    return PosteriorGroupTracker(base.params, base.config, base.name, **opts)


def summary_scores(f, e, rec, group_of) -> tuple[float | None, float | None, float]:
    """(ARI of the Binder point estimate, ARI of the tracker's sample, split R-hat) at one frame."""
    draws = rec.draws.reshape(-1, rec.draws.shape[-1])
    point = binder_point(similarity_matrix(draws), draws)
    cluster_of = {lab: f"s{k}" for lab, k in zip(rec.labels, point.tolist())}
    rhat = split_rhat(n_blocks(rec.draws)) if rec.draws.shape[1] >= 4 else float("nan")
    return frame_ari(f.truth, e, group_of, cluster_of=cluster_of), frame_ari(f.truth, e, group_of), rhat


def score_tracker(tracker: PosteriorGroupTracker, sc, frames, seed: int) -> dict:
    group_of = {i: f"g{k}" for k, g in enumerate(sc.groups) for i in g}
    ospas, card, ests, ari, ari_s, rhat, d_ser = [], [], [], [], [], [], []
    for (f, e, _), rec in zip(run(tracker, frames, seed), _log_iter(tracker)):
        ospas.append(ospa(f.truth.positions, e.positions, c=100.0, p=1.0).total)
        card.append(abs(len(e.tracks) - len(f.truth.ids)))
        ests.append(e)
        d_ser.append([round(v, 4) for v in grid_interval(rec.d_grid, rec.d_prob)])
        if rec.draws is not None:
            a, a_s, r = summary_scores(f, e, rec, group_of)
            rhat.append(r)
            if a is not None:
                ari.append(a)
                ari_s.append(a_s)
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    o2 = ospa2_series([{t.label: t.position for t in e.tracks} for e in ests], true_tracks, window=10, c=100.0, p=1.0)
    rhat = np.array(rhat)
    return dict(ospa=float(np.mean(ospas)), ospa2=float(np.mean(o2)), card_err=float(np.mean(card)),
                ari=float(np.mean(ari)) if ari else float("nan"), ari_sample=float(np.mean(ari_s)) if ari_s else float("nan"),
                rhat_median=float(np.nanmedian(rhat)) if rhat.size else float("nan"),
                rhat_ok=float(np.mean(rhat <= 1.1)) if rhat.size else float("nan"), d=d_ser)


def _log_iter(tracker: PosteriorGroupTracker):
    """The tracker's log entries as they are appended (one per frame, after its step)."""
    i = 0
    while True:
        yield tracker.log[i]
        i += 1


def one_pair(job: tuple) -> dict:
    d, seed, opts, scene, overrides = job
    t0 = time.process_time()
    sc = get_scenario(FAMILY, seed=seed, scene=(f"py_discount={d}", *scene))
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, seed)
    out = {"d": d, "seed": seed, "objects": len(sc.targets), "groups": len(sc.groups), "settings": opts,
           "scene": list(scene), "set": list(overrides)}
    for name in TRACKERS:
        out[name] = score_tracker(posterior_tracker(name, params, opts, overrides), sc, frames, seed)
    out["cpu_s"] = round(time.process_time() - t0, 1)
    return out


def read_journal(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]


def run_jobs(args) -> None:
    opts = dict(chains=args.chains, burn=args.burn, keep=args.keep, first_frame=args.first_frame, every=args.every)
    done = {(r["d"], r["seed"]) for r in read_journal(args.journal)}
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    # seed-major order: a run stopped early holds every d on the same first seeds
    jobs = [(d, s, opts, tuple(args.scene), tuple(args.overrides)) for s in seeds for d in args.discounts if (d, s) not in done]
    args.journal.parent.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(args.workers) as pool, args.journal.open("a") as fh:
        for r in pool.map(one_pair, jobs):
            fh.write(json.dumps(r) + "\n")
            fh.flush()
            print(f"d {r['d']} seed {r['seed']}: {r['objects']} objects, cpu {r['cpu_s']} s; ARI ddp "
                  f"{r['ddp']['ari']:.3f} dpyp {r['dpyp']['ari']:.3f}; OSPA(2) ddp {r['ddp']['ospa2']:.2f} "
                  f"dpyp {r['dpyp']['ospa2']:.2f}", flush=True)


def paired(records: list[dict], metric: str, effect: float) -> dict:
    """dpyp - ddp over the records: mean, SE, 95 % interval (Student's t), the runs a paired test
    (two-sided 5 %, power 80 %) needs for ``effect``, and the power the runs had for it."""
    from scipy.stats import norm, t as tdist

    d = np.array([r["dpyp"][metric] - r["ddp"][metric] for r in records])
    d = d[np.isfinite(d)]
    n, sd = d.size, d.std(ddof=1)
    se = sd / np.sqrt(n)
    half = tdist.ppf(0.975, n - 1) * se
    need = int(np.ceil(((1.96 + 0.8416) * sd / effect) ** 2)) if sd > 0 else 1
    power = float(norm.cdf(effect / se - 1.96)) if se > 0 else 1.0
    return dict(n=n, mean=float(d.mean()), se=float(se), half=float(half), need=need, power=power, effect=effect,
                a=float(np.nanmean([r["dpyp"][metric] for r in records])),
                b=float(np.nanmean([r["ddp"][metric] for r in records])))


def verdict(cells: dict) -> str:
    """Holds when every interval lies on DPY-STP's side of 0; does not hold when some lies on the other; else open."""
    sides = []
    for metric, c in cells.items():
        lo, hi = c["mean"] - c["half"], c["mean"] + c["half"]
        good, bad = (lo > 0, hi < 0) if METRICS[metric] > 0 else (hi < 0, lo > 0)
        sides.append("good" if good else "bad" if bad else "open")
    return "holds" if all(s == "good" for s in sides) else "does not hold" if "bad" in sides else "not decided"


def analyse(records: list[dict], effects: dict) -> dict:
    out = {}
    for d in sorted({r["d"] for r in records}):
        rs = [r for r in records if r["d"] == d]
        cells = {m: paired(rs, m, effects[m]) for m in METRICS}
        series = np.array([r["dpyp"]["d"] for r in rs])  # (runs, frames, 3)
        d_post = {k: [float(x) for x in series[:, k - 1].mean(axis=0)] for k in D_FRAMES if k <= series.shape[1]}
        out[str(d)] = dict(runs=len(rs), cells=cells, verdict=verdict(cells), d_post=d_post,
                           seeds=[min(r["seed"] for r in rs), max(r["seed"] for r in rs)],
                           objects=float(np.mean([r["objects"] for r in rs])),
                           ari_sample={t: float(np.nanmean([r[t]["ari_sample"] for r in rs])) for t in TRACKERS},
                           rhat_ok={t: float(np.nanmean([r[t]["rhat_ok"] for r in rs])) for t in TRACKERS},
                           rhat_median={t: float(np.nanmedian([r[t]["rhat_median"] for r in rs])) for t in TRACKERS},
                           cpu_s=float(np.mean([r["cpu_s"] for r in rs])))
    return out


def markdown(result: dict) -> str:
    """The results table (docs/results.md's Pitman-Yor section)."""
    lines = ["| true d | runs (seeds) | ARI of the summary, DPY-STP / DDP-EMM | paired ARI | paired OSPA | paired OSPA(2) | verdict |",
             "|---|---|---|---|---|---|---|"]
    for d, r in result.items():
        c = r["cells"]

        def cell(m: str, unit: str) -> str:
            x = c[m]
            return (f"{x['mean']:+.3f} ± {x['half']:.3f} (SE {x['se']:.3f}; {x['need']} runs for {x['effect']:g}{unit}, "
                    f"power {x['power']:.2f})")

        lines.append(f"| {d} | {r['runs']} ({r['seeds'][0]}-{r['seeds'][1]}) | {c['ari']['a']:.3f} / {c['ari']['b']:.3f} | "
                     f"{cell('ari', '')} | {cell('ospa', ' m')} | {cell('ospa2', ' m')} | **{r['verdict']}** |")
    lines += ["", "| true d | DPY-STP's posterior of d, mean [95 % interval], at frame " + ", ".join(map(str, D_FRAMES))
              + " | ARI of one sample, DPY-STP / DDP-EMM | frames with split R-hat <= 1.1, DPY-STP / DDP-EMM |",
              "|---|---|---|---|"]
    for d, r in result.items():
        post = "; ".join(f"{k}: {v[0]:.2f} [{v[1]:.2f}, {v[2]:.2f}]" for k, v in r["d_post"].items())
        lines.append(f"| {d} | {post} | {r['ari_sample']['dpyp']:.3f} / {r['ari_sample']['ddp']:.3f} | "
                     f"{r['rhat_ok']['dpyp']:.2f} / {r['rhat_ok']['ddp']:.2f} |")
    return "\n".join(lines)


def verdict_text(result: dict) -> str:
    """One paragraph: for which true d the claim holds, does not hold or is not decided, and for
    each metric whether its interval excludes a difference as large as the pre-stated effect."""
    by = {}
    for d, r in result.items():
        by.setdefault(r["verdict"], []).append(d)
    parts = [f"true d = {', '.join(ds)}: **{v}**" for v, ds in by.items()]
    small = []
    for d, r in result.items():
        inside = [m for m, c in r["cells"].items() if -c["effect"] < c["mean"] - c["half"] and c["mean"] + c["half"] < c["effect"]]
        if inside:
            names = {"ari": "ARI", "ospa": "OSPA", "ospa2": "OSPA(2)"}
            small.append(f"d = {d}: {', '.join(names[m] for m in inside)}")
    text = "On `groups-py`, the claim \"DPY-STP beats DDP-EMM\": " + "; ".join(parts) + "."
    if small:
        text += (" Intervals inside (-effect, +effect), i.e. no difference as large as the pre-stated effect: "
                 + "; ".join(small) + ".")
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--discounts", type=float, nargs="+", default=[0.0, 0.3, 0.6])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--first-seed", type=int, default=101)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--journal", type=Path, required=True)
    ap.add_argument("--chains", type=int, default=2)
    ap.add_argument("--burn", type=int, default=20)
    ap.add_argument("--keep", type=int, default=20)
    ap.add_argument("--first-frame", type=int, default=10)
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--scene", action="append", default=[], help="further scene.* settings, KEY=VALUE (dev runs)")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="a tracker setting KEY=VALUE for both trackers (dev runs)")
    ap.add_argument("--analyse", action="store_true", help="only analyse the journal")

    args = ap.parse_args(argv)
    if not args.analyse:
        run_jobs(args)
    result = analyse(read_journal(args.journal), EFFECTS)
    print(markdown(result))
    print()
    print(verdict_text(result))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
