"""Paired comparison of two trackers' group recovery (adjusted Rand index, as in
``benchmarks/groups.py``) seed by seed, with a paired t statistic and a Wilcoxon signed-rank test:

    python3 benchmarks/groups_ari_paired.py --a dpyp --b ddp --scenario groups-pl --seeds 60

Session 8's figure (issue 14, "DPY-STP recovers the true groups better"): seeds 1-60, dpyp
0.8972 against ddp 0.8945, difference +0.0027 (SE 0.0016, t 1.70), better on 25 seeds, worse on
15, equal on 20, Wilcoxon p = 0.07.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from groups import one_run  # noqa: E402


def _ari(job: tuple[str, str, str, int]) -> float:
    tracker, params, scenario, seed = job
    return one_run((tracker, params, scenario, seed, [], ()))["ari"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--a", default="dpyp")
    ap.add_argument("--b", default="ddp")
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="groups-pl")
    ap.add_argument("--seeds", type=int, default=60)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    with ProcessPoolExecutor(args.workers) as pool:
        a = np.array(list(pool.map(_ari, [(args.a, args.params, args.scenario, s) for s in seeds])))
        b = np.array(list(pool.map(_ari, [(args.b, args.params, args.scenario, s) for s in seeds])))
    d = (a - b)[~np.isnan(a - b)]
    se = d.std(ddof=1) / np.sqrt(d.size)
    print(f"{args.scenario}, seeds {seeds.start}..{seeds.stop - 1}: mean ARI {args.a} {np.nanmean(a):.4f}, "
          f"{args.b} {np.nanmean(b):.4f}")
    print(f"paired difference {d.mean():+.4f} (SE {se:.4f}, t {d.mean() / se:.2f}); {args.a} better on "
          f"{(d > 0).sum()}, worse on {(d < 0).sum()}, equal on {(d == 0).sum()} seeds")
    from scipy.stats import wilcoxon

    nonzero = d[d != 0]
    if nonzero.size:
        print(f"Wilcoxon signed-rank (ties dropped): p = {wilcoxon(nonzero).pvalue:.3f}")


if __name__ == "__main__":
    main()
