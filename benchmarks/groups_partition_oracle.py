"""Can the prior matter?  The object -> cluster partition of the two-level tracker run on the TRUE
object states.

The measurement -> object level of :class:`bnptrack.tracker.bnp.groups.GroupTracker` is replaced by
an oracle (:class:`TruthObjects`): at every frame its objects are the true ones (labels = truth ids,
existence 1, mean = the true state ``[px, vx, py, vy, omega]``), each with the covariance
``diag(pos_std^2, vel_std^2, pos_std^2, vel_std^2, omega_std^2)``.  Everything above it is
GroupTracker's own ``step`` unchanged: the same presets (``ddp``, ``dpyp``), H_2, ``sweeps`` (6),
warm start at last frame's clusters, theta transition, (alpha_2, d) update from the history's
EPPF, sharing.  Two deviations, both forced by the oracle: ``merge = "objects"`` (the exclusive
merge reads the object level's measurement assignments, which the oracle has none of; the
oracle never merges), and the subclass :class:`OracleGroupTracker` overrides the public
``objects`` property and, to record the sampler's inputs for the sensitivity, the PRIVATE method
``GroupTracker._partition`` (it calls the original and stores its arguments and result).

Covariances ("--cov"): ``typical`` = the tracker's median reported posterior std on
``groups-pl`` seeds 101-103 (dev seeds; ``ddp``, tracks with a cluster, 2300 track-frames):
position 16.5 m, velocity 6.3 m/s per axis (a one-off script, /tmp/ari2_cov.py, not kept: the
median over track-frames of the mean of the two axes' stds); ``small`` =
1 m, 0.3 m/s.  turn-rate std 0.01 rad/s in both.  ``--noise`` also perturbs the true state by a
draw from that covariance (the tracker's own estimate error, roughly), from the tracker's frame
generator before the partition draws its uniforms, so both priors see the same noise.

ARI: :func:`benchmarks.groups.frame_ari` (the tracker benchmark's metric) on the oracle's tracks,
i.e. on all true objects, in frames where a true group has >= 2 members present; a seed's value is
its mean over those frames.

Sensitivity (``--sensitivity``): on the ``dpyp`` run, at every frame and for every object l,
the full conditional of l's table given the others' final tables (:func:`conditional`: the
urn weight :func:`urn_log_weights` times the conjugate predictive of every block, exactly the
kernel's eq. (Gibbs)) under the run's (alpha_2, d_2) and under (alpha_2, 0) -- the same state,
only the discount switched off.  Reported: the fraction of (frame, object) moves whose
probabilities differ by more than 0.05 in some table, and whose argmax differs.

PRE-REGISTERED PLAN (written before any of seeds 301-360 ran; seeds 101-120 develop only):
- Primary: ``groups-pl``, seeds 301-360 (never used), ``--cov typical``, no noise; per-seed mean
  ARI of ``dpyp`` and ``ddp``; H1 "dpyp's oracle ARI > ddp's": one-sided paired t and one-sided
  Wilcoxon signed-rank (ties dropped), alpha 0.05 each; the lead is claimed only if both reject.
  Also the 95 % bootstrap CI of the mean difference (10000 resamples, generator seed 0).
- Secondary (descriptive, no test claimed): the same seeds with ``--cov small``, with
  ``--noise`` (typical), the sensitivity fractions, and the ``groups`` family, seeds 301-320.

    nice -n 10 python3 benchmarks/groups_partition_oracle.py --scenario groups-pl --first-seed 301 \\
        --seeds 60 --cov typical --sensitivity --csv oracle_pl_typical.csv

Added at 08:05 UTC, after the dev seeds and after the primary run had started (none of its output
seen), descriptive only: ``dpyp`` with the scene's own discount fixed (``--py-set d=0.6 --py-set
infer_d=false``: the most favourable PY prior; the preset's Gamma(1, 0.1) prior on d holds d2
near 0.19 on true partitions, dev seeds), seeds 301-360; and per-prior counts of split / merged
true pairs (:func:`pair_errors`), which say whether the errors a PY prior could fix (merges: it
favours more clusters) are there to fix.

The last line printed is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import msgspec
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from groups import frame_ari  # noqa: E402
from groups_ari_paired import paired_stats  # noqa: E402

from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.bnp.filter import BnpState  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.bnp.group_sample import Block, urn_log_weights  # noqa: E402
from bnptrack.tracker.bnp.group_theta import theta_posterior  # noqa: E402
from bnptrack.tracker.bnp.groups import GROUP_PRESETS, GroupTracker  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate  # noqa: E402

#: (pos_std m, vel_std m/s) per axis; see the module docstring for where "typical" comes from.
COVS = {"typical": (16.5, 6.3), "small": (1.0, 0.3)}
OMEGA_STD = 0.01


@dataclass(frozen=True)
class TruthObjects:
    """The oracle object level: the frame's true objects with a fixed covariance (optionally
    their state perturbed by a draw from it)."""

    pos_std: float = 16.5
    vel_std: float = 6.3
    noise: bool = False

    @property
    def cov(self) -> np.ndarray:
        return np.diag([self.pos_std**2, self.vel_std**2, self.pos_std**2, self.vel_std**2, OMEGA_STD**2])

    def initial_state(self) -> BnpState:
        return BnpState()

    def step(self, state: BnpState, frame: Frame, rng: np.random.Generator) -> tuple[BnpState, Estimate]:
        ids, x = frame.truth.ids, frame.truth.states.copy()
        n = len(ids)
        if self.noise and n:
            x = x + rng.standard_normal((n, 5)) * np.sqrt(np.diag(self.cov))
        cov = np.repeat(self.cov[None], n, axis=0)
        one = np.ones(n)
        new = BnpState(frame.frame, frame.stamp_ns, tuple(ids), x, cov, one, one.copy(), 1.0, 0.0, np.zeros((0, 0)))
        tracks = tuple(TrackEstimate(lab, x[i].copy(), cov[i].copy(), 1.0) for i, lab in enumerate(ids))
        return new, Estimate(frame.frame, frame.stamp_ns, tracks, diagnostics={"n_clusters": float(n)})


@dataclass(frozen=True)
class OracleGroupTracker(GroupTracker):
    """GroupTracker with :class:`TruthObjects` as its object level; ``log`` (if a list) receives
    ``(blocks, v_star, alpha2, d2, z)`` of every frame's partition (overrides the private
    ``_partition``, calling the original)."""

    oracle: TruthObjects = TruthObjects()
    log: list | None = field(default=None, compare=False)

    @cached_property
    def objects(self) -> TruthObjects:  # type: ignore[override]
        return self.oracle

    def _partition(self, rng, state, blocks, init_ids):
        z, shares = super()._partition(rng, state, blocks, init_ids)
        if self.log is not None:
            self.log.append((blocks, state.group_count.copy(), state.alpha2, state.d2, z.copy()))
        return z, shares


def oracle_tracker(name: str, params, oracle: TruthObjects, log: list | None = None,
                   overrides: tuple[str, ...] = ()) -> OracleGroupTracker:
    """The ``name`` preset (``ddp`` / ``dpyp``) on the oracle object level (merge "objects"), with
    ``overrides`` (``KEY=V``, :func:`bnptrack.tracker.config.apply_overrides`)."""
    config = msgspec.structs.replace(apply_overrides(GROUP_PRESETS[name], list(overrides)), merge="objects")
    return OracleGroupTracker(params, config, name, oracle, log)


def conditional(blocks: list[Block], v_star: np.ndarray, alpha: float, d: float, z: np.ndarray, l: int,
                occupied: bool) -> np.ndarray:
    """Object ``l``'s full conditional given the others' tables ``z`` (eq. (Gibbs)): one entry per
    table in ``[0..G-1]`` then the others' new tables in increasing order, then a fresh new one."""
    G = v_star.size
    others = np.delete(np.arange(z.size), l)
    new_tables = np.unique(z[others][z[others] >= G])
    tables = np.concatenate([np.arange(G), new_tables]).astype(np.int64)
    n = np.array([(z[others] == t).sum() for t in tables], dtype=float)
    logw = urn_log_weights(n, np.concatenate([v_star, np.zeros(new_tables.size)]), alpha, d, occupied)
    for b in blocks:
        for k, t in enumerate(tables.tolist() + [-1]):
            if k < tables.size and n[k] + (v_star[t] if t < G else 0) == 0:
                continue  # weight 0 already
            m0, C0 = (b.prior_mean[t], b.prior_cov[t]) if 0 <= t < G else (b.h_mean, b.h_cov)
            mem = others[z[others] == t] if t >= 0 else others[:0]
            mu, C = theta_posterior(m0, C0, b.v[mem], b.R[mem]) if mem.size else (m0, C0)
            logw[k] += log_normal2(b.v[l], mu, C + b.R[l])
    w = np.exp(logw - logw.max())
    return w / w.sum()


def log_normal2(x: np.ndarray, mu: np.ndarray, S: np.ndarray) -> float:
    """log N(x; mu, S) of 2-vectors."""
    r = x - mu
    return float(-0.5 * r @ np.linalg.solve(S, r) - 0.5 * np.log(np.linalg.det(S)) - np.log(2 * np.pi))


def sensitivity(log: list, occupied: bool, tol: float = 0.05) -> dict:
    """Over every (frame, object) of a recorded run: the conditional under the run's (alpha_2, d_2)
    against (alpha_2, 0); counts of moves whose probabilities differ by > ``tol`` and of argmax flips."""
    moves = differ = flips = 0
    tv = 0.0
    for blocks, v_star, alpha, d, z in log:
        for l in range(z.size):
            p_py = conditional(blocks, v_star, alpha, d, z, l, occupied)
            p_dp = conditional(blocks, v_star, alpha, 0.0, z, l, occupied)
            moves += 1
            differ += int(np.abs(p_py - p_dp).max() > tol)
            flips += int(np.argmax(p_py) != np.argmax(p_dp))
            tv += 0.5 * np.abs(p_py - p_dp).sum()
    return dict(moves=moves, differ=differ, flips=flips, tv_sum=tv)


def pair_errors(est: Estimate, group_of: dict[str, str]) -> tuple[int, int]:
    """(split, merged): pairs of tracks in one true group but different clusters, and pairs in
    different true groups (a free object is its own group) but one cluster."""
    g = np.array([group_of.get(t.label, t.label) for t in est.tracks], dtype=object)
    c = np.array([-1 if t.cluster is None else t.cluster for t in est.tracks])
    same_g, same_c = g[:, None] == g[None], c[:, None] == c[None]
    iu = np.triu_indices(g.size, 1)
    return int((same_g & ~same_c)[iu].sum()), int((~same_g & same_c)[iu].sum())


def one_seed(job: tuple) -> dict:
    """One seed, one prior: per-frame ARI, mean d2 (frames >= 20) and, if asked, the sensitivity."""
    name, scenario, seed, oracle, sens, overrides = job
    sc = get_scenario(scenario, seed=seed, scene=())
    params = sc.adapt_params(load_params("vo2017"))
    log: list | None = [] if sens else None
    tracker = oracle_tracker(name, params, oracle, log, overrides)
    group_of = {i: f"g{k}" for k, g in enumerate(sc.groups) for i in g}
    aris, d2, errs = [], [], np.zeros(2, dtype=np.int64)
    for f, e, _ in run(tracker, simulate_all(sc, params, seed), seed):
        a = frame_ari(f.truth, e, group_of)
        errs += pair_errors(e, group_of)
        aris.append(np.nan if a is None else a)
        if f.frame >= 20:
            d2.append(e.diagnostics["d2"])
    out = dict(seed=seed, name=name, ari_frames=aris, ari=float(np.nanmean(aris)), d2=float(np.mean(d2)),
               split=int(errs[0]), merged=int(errs[1]))
    if sens:
        out["sens"] = sensitivity(log, tracker.config.urn_reading == "occupied")
    return out


def run_all(args, oracle: TruthObjects) -> list[tuple[dict, dict]]:
    """(dpyp, ddp) results seed by seed, in seed order."""
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    jobs = [(n, args.scenario, s, oracle, args.sensitivity and n == "dpyp", tuple(args.py_set) if n == "dpyp" else ())
            for s in seeds for n in ("dpyp", "ddp")]
    with ProcessPoolExecutor(args.workers) as pool:
        res = list(pool.map(one_seed, jobs))
    return list(zip(res[0::2], res[1::2]))


def write_csv(path: str, pairs: list[tuple[dict, dict]]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(("seed", "ari_dpyp", "ari_ddp", "d2_dpyp", "d2_ddp"))
        for a, b in pairs:
            w.writerow((a["seed"], a["ari"], b["ari"], a["d2"], b["d2"]))


def frame_profile(pairs: list[tuple[dict, dict]], every: int = 10) -> dict:
    """Mean ARI over seeds at frames 1, 11, 21, ... for both priors (frames without an ARI skipped)."""
    out = {}
    for k, key in ((0, "dpyp"), (1, "ddp")):
        n = min(len(p[k]["ari_frames"]) for p in pairs)
        S = np.array([p[k]["ari_frames"][:n] for p in pairs], dtype=float)
        with np.errstate(all="ignore"):
            out[key] = [round(float(np.nanmean(S[:, j])), 4) for j in range(0, n, every)]
    return out


def summarise(pairs: list[tuple[dict, dict]]) -> dict:
    a = np.array([p[0]["ari"] for p in pairs])
    b = np.array([p[1]["ari"] for p in pairs])
    out = dict(primary=paired_stats(a, b, "greater"), frames=frame_profile(pairs),
               d2_dpyp=float(np.mean([p[0]["d2"] for p in pairs])),
               frac_seeds_equal=float(np.mean(a == b)))
    fa = np.concatenate([p[0]["ari_frames"] for p in pairs])
    fb = np.concatenate([p[1]["ari_frames"] for p in pairs])
    ok = np.isfinite(fa) & np.isfinite(fb)
    out["frame_level"] = dict(n=int(ok.sum()), mean_dpyp=float(fa[ok].mean()), mean_ddp=float(fb[ok].mean()),
                              frac_equal=float(np.mean(fa[ok] == fb[ok])), frac_ari1_dpyp=float(np.mean(fa[ok] == 1)),
                              frac_ari1_ddp=float(np.mean(fb[ok] == 1)))
    out["pair_errors"] = {key: dict(split=sum(p[k]["split"] for p in pairs), merged=sum(p[k]["merged"] for p in pairs))
                          for k, key in ((0, "dpyp"), (1, "ddp"))}
    if "sens" in pairs[0][0]:
        tot = {k: sum(p[0]["sens"][k] for p in pairs) for k in ("moves", "differ", "flips", "tv_sum")}
        out["sensitivity"] = dict(moves=tot["moves"], frac_differ_005=tot["differ"] / tot["moves"],
                                  frac_argmax_flip=tot["flips"] / tot["moves"], mean_tv=tot["tv_sum"] / tot["moves"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="groups-pl")
    ap.add_argument("--first-seed", type=int, default=101)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--cov", choices=tuple(COVS), default="typical")
    ap.add_argument("--noise", action="store_true", help="perturb the true states by a draw from the covariance")
    ap.add_argument("--sensitivity", action="store_true", help="PY vs DP conditionals on the dpyp run")
    ap.add_argument("--py-set", action="append", default=[], help="KEY=V override of the dpyp preset only")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--csv")
    args = ap.parse_args()
    oracle = TruthObjects(*COVS[args.cov], noise=args.noise)
    pairs = run_all(args, oracle)
    if args.csv:
        write_csv(args.csv, pairs)
    out = dict(scenario=args.scenario, seeds=[args.first_seed, args.first_seed + args.seeds - 1], cov=args.cov,
               noise=args.noise, py_set=args.py_set, **summarise(pairs))
    s = out["primary"]
    print(f"{args.scenario} seeds {out['seeds']}, cov {args.cov}, noise {args.noise}, dpyp {args.py_set}: oracle ARI dpyp "
          f"{s['mean_a']:.4f}, ddp {s['mean_b']:.4f}, diff {s['diff']:+.4f} (SE {s['se']:.4f}, one-sided t p "
          f"{s['p_t']:.3f}, Wilcoxon p {s['p_wilcoxon']:.3f}, CI [{s['ci95'][0]:+.4f}, {s['ci95'][1]:+.4f}]); "
          f"better {s['better']}, worse {s['worse']}, equal {s['equal']}; d2 {out['d2_dpyp']:.3f}", flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
