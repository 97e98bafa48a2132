"""Paired comparison of two trackers' group recovery (adjusted Rand index, as in
``benchmarks/groups.py``) seed by seed, with a paired t statistic, a Wilcoxon signed-rank test
and a percentile bootstrap interval of the mean difference:

    python3 benchmarks/groups_ari_paired.py --a dpyp --b ddp --scenario groups-pl --seeds 60

A pre-registered replication of the claim "DPY-STP recovers the true groups better" uses it
(its protocol was written down before any of its seeds ran):
- Sample: seeds 121-300 of ``groups-pl`` (seeds 101-120 chose the settings and are never
  reported; seeds 1-60 gave the first, exploratory figure).
- Primary test, on seeds 121-300: H1 "dpyp's ARI > ddp's", one-sided paired t and one-sided
  Wilcoxon signed-rank (equal seeds dropped), alpha 0.05 each; shown only if both reject. Also
  the 95 % percentile bootstrap interval of the mean difference (10000 resamples, generator
  seed 0).
- Secondary: the paired t on the pool of seeds 1-60 and 121-300 (``--pool-csv`` with the
  per-seed values of 1-60, or ``--pool-summary n,diff,se`` from a printed summary).
- Also reported: dpyp's inferred discount d2 (mean over frames >= 20, per seed; its mean and
  10 % quantile over seeds) and the per-seed CSV (``--csv``).

    nice -n 10 python3 benchmarks/groups_ari_paired.py --a dpyp --b ddp --scenario groups-pl \\
        --first-seed 121 --seeds 180 --workers 1 --alternative greater --csv ari_121_300.csv \\
        --pool-summary 60,0.0027,0.0016

Outcome (docs/results.md, "Objects that move in groups"): seeds 121-300, dpyp 0.8918 against ddp 0.8922,
difference -0.0004 (SE 0.0010; 95 % CI [-0.0025, +0.0016]), one-sided t p 0.63, Wilcoxon p
0.57: the first figure's lead (seeds 1-60, +0.0027, SE 0.0016) does not replicate. dpyp's d2:
mean 0.342 over seeds, smallest 0.089.

The last line printed is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.stats import t as tdist
from scipy.stats import ttest_1samp, wilcoxon

sys.path.insert(0, str(Path(__file__).resolve().parent))
from groups import one_run  # noqa: E402

FIELDS = ("seed", "ari_a", "ari_b", "d2_a", "d2_b")


def _pair(job: tuple[str, str, str, str, int]) -> tuple[int, float, float, float, float]:
    """One seed, both trackers: (seed, ARI a, ARI b, d2 a, d2 b)."""
    a, b, params, scenario, seed = job
    ra = one_run((a, params, scenario, seed, [], ()))
    rb = one_run((b, params, scenario, seed, [], ()))
    return seed, ra["ari"], rb["ari"], ra["d2"], rb["d2"]


def bootstrap_ci(d: np.ndarray, n_boot: int = 10000, seed: int = 0, level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``d`` (seeds resampled with replacement)."""
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, d.size, size=(n_boot, d.size))].mean(axis=1)
    q = (1.0 - level) / 2.0
    return float(np.quantile(means, q)), float(np.quantile(means, 1.0 - q))


def paired_stats(a: np.ndarray, b: np.ndarray, alternative: str = "two-sided", n_boot: int = 10000) -> dict:
    """Paired a - b over the seeds where both are finite: means, t (SE = sd/sqrt n, ddof 1) with
    its p, the Wilcoxon signed-rank p over the non-zero differences, counts and a bootstrap CI."""
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = np.asarray(a)[ok], np.asarray(b)[ok]
    d = a - b
    se = d.std(ddof=1) / np.sqrt(d.size)
    nonzero = d[d != 0]
    lo, hi = bootstrap_ci(d, n_boot)
    return dict(n=int(d.size), mean_a=float(a.mean()), mean_b=float(b.mean()), diff=float(d.mean()),
                se=float(se), t=float(d.mean() / se), p_t=float(ttest_1samp(d, 0.0, alternative=alternative).pvalue),
                p_wilcoxon=float(wilcoxon(nonzero, alternative=alternative).pvalue) if nonzero.size else float("nan"),
                better=int((d > 0).sum()), worse=int((d < 0).sum()), equal=int((d == 0).sum()),
                ci95=[lo, hi], alternative=alternative)


def pooled_t(n1: int, mean1: float, se1: float, d: np.ndarray, alternative: str = "two-sided") -> dict:
    """Paired t on the union of a sample known only by (n1, mean1, se1) and the differences ``d``:
    the union's mean and sd (ddof 1) rebuilt from the two samples' sums and sums of squares."""
    d = d[np.isfinite(d)]
    n = n1 + d.size
    s1 = n1 * mean1
    ss1 = (n1 - 1) * (se1 * np.sqrt(n1)) ** 2 + n1 * mean1**2
    mean = (s1 + d.sum()) / n
    var = (ss1 + (d**2).sum() - n * mean**2) / (n - 1)
    se = np.sqrt(var / n)
    t = mean / se
    p = {"two-sided": 2 * tdist.sf(abs(t), n - 1), "greater": tdist.sf(t, n - 1), "less": tdist.cdf(t, n - 1)}
    return dict(n=int(n), diff=float(mean), se=float(se), t=float(t), p_t=float(p[alternative]), alternative=alternative)


def read_rows(path: str) -> list[tuple]:
    """Per-seed rows of a ``--csv`` file."""
    with open(path, newline="") as fh:
        return [(int(r["seed"]), *(float(r[k]) for k in FIELDS[1:])) for r in csv.DictReader(fh)]


def run_seeds(args, seeds: range) -> list[tuple]:
    """Both trackers seed by seed, in seed order; each row is appended to ``--csv`` as it arrives."""
    jobs = [(args.a, args.b, args.params, args.scenario, s) for s in seeds]
    fh = open(args.csv, "w", newline="") if args.csv else None
    w = csv.writer(fh) if fh else None
    if w:
        w.writerow(FIELDS)
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(_pair, jobs):
            rows.append(row)
            if w:
                w.writerow(row)
                fh.flush()
    if fh:
        fh.close()
    return rows


def report(label: str, s: dict, a: str, b: str) -> None:
    print(f"{label}: n {s['n']}, mean ARI {a} {s['mean_a']:.4f}, {b} {s['mean_b']:.4f}; paired difference "
          f"{s['diff']:+.4f} (SE {s['se']:.4f}, t {s['t']:.2f}, p {s['p_t']:.4f}; 95 % bootstrap CI "
          f"[{s['ci95'][0]:+.4f}, {s['ci95'][1]:+.4f}]); {a} better on {s['better']}, worse on {s['worse']}, "
          f"equal on {s['equal']} seeds; Wilcoxon signed-rank (ties dropped, {s['alternative']}): "
          f"p = {s['p_wilcoxon']:.4f}", flush=True)


def d2_summary(d2: np.ndarray) -> dict:
    """The discount (mean over frames >= 20, one value a seed) over seeds: mean, 10 % quantile, min."""
    d2 = d2[np.isfinite(d2)]
    if not d2.size:
        return dict(n=0)
    return dict(n=int(d2.size), mean=float(d2.mean()), q10=float(np.quantile(d2, 0.1)), min=float(d2.min()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--a", default="dpyp")
    ap.add_argument("--b", default="ddp")
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="groups-pl")
    ap.add_argument("--seeds", type=int, default=60)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--alternative", choices=("two-sided", "greater", "less"), default="two-sided",
                    help="H1 of both tests, on mean ARI a - b")
    ap.add_argument("--csv", help="write the per-seed rows (seed, ari_a, ari_b, d2_a, d2_b) here")
    ap.add_argument("--pool-csv", action="append", default=[],
                    help="per-seed CSV of earlier seeds: also report the pool of them and this run")
    ap.add_argument("--pool-summary", help="N,DIFF,SE of earlier seeds' paired differences: also the pooled t")
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows = np.array(run_seeds(args, seeds), dtype=float)
    out = dict(scenario=args.scenario, a=args.a, b=args.b, seeds=[seeds.start, seeds.stop - 1])
    out["primary"] = paired_stats(rows[:, 1], rows[:, 2], args.alternative)
    report(f"{args.scenario}, seeds {seeds.start}..{seeds.stop - 1}", out["primary"], args.a, args.b)
    out["d2_a"], out["d2_b"] = d2_summary(rows[:, 3]), d2_summary(rows[:, 4])
    print(f"d2 of {args.a} (mean over frames >= 20, over seeds): {out['d2_a']}")
    if args.pool_csv:
        pool = np.array([r for p in args.pool_csv for r in read_rows(p)] + rows.tolist(), dtype=float)
        if np.unique(pool[:, 0]).size != pool.shape[0]:
            raise SystemExit("--pool-csv: a seed appears twice")
        out["pooled"] = paired_stats(pool[:, 1], pool[:, 2], args.alternative)
        report(f"pooled with {', '.join(args.pool_csv)}", out["pooled"], args.a, args.b)
    if args.pool_summary:
        n1, m1, se1 = args.pool_summary.split(",")
        out["pooled_summary"] = pooled_t(int(n1), float(m1), float(se1), rows[:, 1] - rows[:, 2], args.alternative)
        print(f"pooled with the summary {args.pool_summary} (paired t only): {out['pooled_summary']}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
