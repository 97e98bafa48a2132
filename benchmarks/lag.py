"""Fixed-lag output (``--lag N``, :mod:`tracker.lag`) against the online output, over many seeds.

Each seed runs the tracker once; its online estimates are then re-published through the
fixed-lag layer for each lag (the layer is a pure function of the tracker's estimates and the
frames), so every row of a seed scores the same tracker run.  Prints mean OSPA, OSPA(2)
(window 10), mean abs(N_hat - N), crossing pairs kept, and the layer's ms per frame.

    python benchmarks/lag.py --trackers ddp --scenario random --seeds 20 --lags 0 1 3
    python benchmarks/lag.py --trackers ddp --scenario vo2017 --set 'params.birth=[]' --lags 0 3
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import os
import pickle
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(__file__))

from accuracy import setup  # noqa: E402
from bnptrack.sinks.crossings import crossing_label_keeping  # noqa: E402
from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.tracker.lag import SWAP_MARGIN, FixedLag  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402


class _Replay:
    """A tracker that returns a recorded run's estimates in order."""

    name = "replay"

    def __init__(self, estimates):
        self.estimates = estimates

    def initial_state(self):
        return 0

    def step(self, state, frame, rng):
        return state + 1, self.estimates[state]


def score(sc, frames, ests):
    o = [ospa(f.truth.positions, e.positions, c=100.0, p=1.0).total for f, e in zip(frames, ests)]
    card = [abs(len(e.tracks) - len(f.truth.ids)) for f, e in zip(frames, ests)]
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [{t.label: t.position for t in e.tracks} for e in ests]
    o2 = ospa2_series(est_tracks, true_tracks, window=10, c=100.0, p=1.0)
    kept = [p.kept for p in crossing_label_keeping(true_tracks, est_tracks, sc.crossings).pairs]
    return dict(ospa=float(np.mean(o)), ospa2=float(np.mean(o2)), card=float(np.mean(card)), kept=kept)


def lagged(tracker_params, frames, online, lag, smooth, margin):
    layer = FixedLag(_Replay(online), tracker_params, lag, smooth=smooth, swap_margin=margin)
    state, out = layer.initial_state(), []
    t0 = time.process_time()
    for f in frames:
        state, st = layer.step(state, f, None)
        if st.lagged is not None:
            out.append(st.lagged)
    out.extend(e for _f, e in layer.flush(state))
    return out, (time.process_time() - t0) * 1e3 / len(frames)


@functools.cache
def code_version() -> str:
    """A digest of the tracker's and the simulator's source and built-in parameter files: a
    cached run is reused only by the code that made it."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    h = hashlib.sha256()
    for top in ("tracker", "sources"):
        for folder, dirs, files in sorted(os.walk(os.path.join(root, top))):
            dirs.sort()
            for name in sorted(files):
                if name.endswith((".py", ".toml")):
                    with open(os.path.join(folder, name), "rb") as fh:
                        h.update(name.encode() + fh.read())
    return h.hexdigest()[:12]


def online_run(tracker_name, params_name, scenario, seed, overrides):
    """The scene, tracker, frames, online estimates and tracker ms per frame of one seed (kept
    in the folder ``$LAG_CACHE`` when set, so another lag or a calibration table reuses them;
    the file name holds :func:`code_version`)."""
    sc, tracker, frames = setup(tracker_name, params_name, scenario, seed, overrides)
    cache = os.environ.get("LAG_CACHE")
    key = "_".join(overrides).replace("/", "-").replace(" ", "")
    path = cache and os.path.join(cache, f"{tracker_name}-{params_name}-{scenario}-{seed}-{key}-{code_version()}.pkl")
    if path and os.path.exists(path):
        with open(path, "rb") as fh:
            online, online_ms = pickle.load(fh)
    else:
        online, t0 = [], time.process_time()
        for _f, e, _s in run(tracker, frames, seed):
            online.append(e)
        online_ms = (time.process_time() - t0) * 1e3 / len(frames)
        if path:
            os.makedirs(cache, exist_ok=True)
            with open(path, "wb") as fh:
                pickle.dump((online, online_ms), fh)
    return sc, tracker, frames, online, online_ms


def one_seed(job):
    tracker_name, params_name, scenario, seed, overrides, configs = job
    sc, tracker, frames, online, online_ms = online_run(tracker_name, params_name, scenario, seed, overrides)
    params = tracker.params if hasattr(tracker, "params") else None
    rows = {}
    for lag, smooth, margin in configs:
        if lag == 0:
            rows[(lag, smooth, margin)] = dict(score(sc, frames, online), ms=online_ms)
        else:
            ests, ms = lagged(params, frames, online, lag, smooth, margin)
            rows[(lag, smooth, margin)] = dict(score(sc, frames, ests), ms=ms)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trackers", nargs="+", default=["ddp"])
    ap.add_argument("--params", default="vo2017")
    ap.add_argument("--scenario", default="random")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--lags", type=int, nargs="+", default=[0, 1, 3])
    ap.add_argument("--swap-margins", nargs="+", default=[str(SWAP_MARGIN)],
                    help="swap margins of the layer (tracker.lag.SWAP_MARGIN), 'none': no crossing resolution")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    margins = [None if m.lower() == "none" else float(m) for m in args.swap_margins]
    configs = [(0, False, None)] + [(lag, s, m) for lag in args.lags if lag > 0 for s in (False, True)
                                    for m in margins]
    print(f"scenario {args.scenario}, seeds {seeds.start}..{seeds.stop - 1}, overrides {args.overrides or 'none'}")
    print("| tracker | lag | smoothing | swap margin | OSPA | OSPA(2) | abs(N_hat-N) | crossings kept | ms/frame (online: tracker; lagged: layer) |")
    print("|---|---|---|---|---|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:
        for tr in args.trackers:
            res = list(pool.map(one_seed, [(tr, args.params, args.scenario, s, args.overrides, configs) for s in seeds]))
            for c in configs:
                rs = [r[c] for r in res]
                kept = [k for r in rs for k in r["kept"]]
                kept_txt = f"{sum(kept)}/{len(kept)}" if kept else "n/a"
                m = {k: np.mean([r[k] for r in rs]) for k in ("ospa", "ospa2", "card", "ms")}
                print(f"| {tr} | {c[0]} | {'RTS' if c[1] else '-'} | {'none' if c[2] is None else c[2]} | {m['ospa']:.2f} | {m['ospa2']:.2f} | "
                      f"{m['card']:.3f} | {kept_txt} | {m['ms']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
