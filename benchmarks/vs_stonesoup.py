"""bnptrack's trackers side by side with Stone Soup anchors, on the same frames, same metrics.

Every tracker (bnptrack's ``ddp``, ``dpyp``, ``glmb``; ``ddp-mb``, ``dpyp-mb`` on request; built as ``benchmarks/accuracy.py``
builds them) and every anchor (Stone Soup GM-PHD (UKF) with measurement-driven birth
``ss-gmphd``, Stone Soup JPDA (UKF) with a multi-measurement initiator ``ss-jpda``; see
``benchmarks/stonesoup_anchors.py``) runs on the frames ``sources/synthetic.py`` simulates for
each seed, and is scored by ``sinks/metrics.py``: OSPA (c=100 m, p=1, positions), OSPA(2)
(window 10), mean |N_hat - N|, crossing-pair label keeping (if the scenario has crossing pairs),
CPU ms per scan (``time.process_time`` around each step, one thread) and that time as a ratio
of the best anchor's (the anchor with the lowest mean OSPA).

Stone Soup is the optional ``compare`` extra: ``pip install -e '.[compare]'``.

    nice -n 5 python benchmarks/vs_stonesoup.py --scenario vo2017 --set 'birth=[]' --seeds 20
    python benchmarks/vs_stonesoup.py --selftest
    nice -n 5 python benchmarks/vs_stonesoup.py --scenario random --anchor-cache ~/.cache/bnptrack/anchors

``--anchor-cache DIR`` keeps each anchor run's per-scan output (labels, positions, CPU ms) in
``DIR``, keyed by a hash of the anchor, its settings, the frames it was given (their
measurements and stamps), its code (``stonesoup_anchors.py``, ``anchor_convert.py``) and Stone
Soup's version; a later run with the same key reuses it and re-scores it (the anchors are
deterministic).  The table then marks those anchors ``(cached)``: their ms come from the run
that filled the cache, so their time ratio is not from one sitting.

Anchor settings (``--anchor-set phd.birth_rate=0.2 --anchor-set jpda.min_points=4``) default
to the values tuned on seeds 101-110 (docs/vs_stonesoup.md).

``--lag N`` adds fixed-lag rows (``benchmarks/lagged_anchors.py``): each bnptrack tracker through
the fixed-lag layer (``NAME --lag N``) and the JPDA anchor smoothed by Stone Soup's unscented RTS
smoother over the same ``N`` scans (``ss-jpda --lag N``), so lagged figures meet lagged anchors.

    nice -n 5 python benchmarks/vs_stonesoup.py --scenario random --trackers ddp --anchors ss-jpda --lag 3
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import msgspec  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks.anchor_convert import JpdaSettings, PhdSettings  # noqa: E402
from benchmarks.accuracy import label_switches  # noqa: E402
from bnptrack.sinks.crossings import crossing_label_keeping  # noqa: E402
from bnptrack.sinks.metrics import ospa, ospa2_series  # noqa: E402
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.registry import build, kind  # noqa: E402
from bnptrack.tracker.state import tracker_frame_rng  # noqa: E402

ANCHORS = ("ss-gmphd", "ss-jpda")
MISSING = "Stone Soup is not installed: pip install -e '.[compare]' (or pip install 'stonesoup>=1.9')"


@dataclass(frozen=True)
class Job:
    """One tracker on one seed."""

    tracker: str
    scenario: str
    seed: int
    params: str
    param_sets: tuple[str, ...]
    tracker_sets: tuple[str, ...]
    anchor_sets: tuple[str, ...]
    anchor_cache: str = ""
    """Directory of cached anchor runs ("" = no cache; :func:`anchor_cache_key`)."""
    lag: int = 0
    """Scans of hindsight (0: online; ``N``: the fixed-lag row, ``benchmarks/lagged_anchors.py``)."""

    @property
    def name(self) -> str:
        return self.tracker if not self.lag else f"{self.tracker} --lag {self.lag}"


@dataclass(frozen=True)
class Scan:
    """One tracker output: labels and ``(n, 2)`` positions, and the CPU time of the step."""

    labels: tuple[str, ...]
    positions: np.ndarray
    ms: float


def anchor_settings(overrides: tuple[str, ...]) -> tuple[PhdSettings, JpdaSettings]:
    """``phd.key=value`` / ``jpda.key=value`` overrides applied to the tuned defaults."""
    phd = [o.split(".", 1)[1] for o in overrides if o.startswith("phd.")]
    jpda = [o.split(".", 1)[1] for o in overrides if o.startswith("jpda.")]
    bad = [o for o in overrides if not o.startswith(("phd.", "jpda."))]
    if bad:
        raise ValueError(f"--anchor-set {bad[0]!r}: keys start with 'phd.' or 'jpda.'")
    return apply_overrides(PhdSettings(), phd), apply_overrides(JpdaSettings(), jpda)


def _run_anchor(job: Job, params, frames) -> tuple[list[Scan], int]:
    """The anchor's scans and the number of warnings Stone Soup raised (UKF fallbacks)."""
    from benchmarks.stonesoup_anchors import make_anchor

    phd, jpda = anchor_settings(job.anchor_sets)
    anchor = make_anchor(job.tracker, params, phd, jpda)
    out = []
    with warnings.catch_warnings(record=True) as caught:  # Stone Soup's UKF fallbacks, counted
        warnings.simplefilter("always")
        for f in frames:
            t0 = time.process_time()
            est = anchor.step(f)
            ms = (time.process_time() - t0) * 1e3
            pos = np.array([p for _, p in est], dtype=float).reshape(-1, 2)
            out.append(Scan(tuple(lab for lab, _ in est), pos, ms))
    return out, len(caught)


def anchor_cache_key(job: Job, params, frames, version: str) -> str:
    """Hash of what an anchor's output depends on: its name and settings, the model parameters,
    every frame's stamp and measurements, the anchor code and Stone Soup's ``version``."""
    h = hashlib.sha256()
    h.update(repr((job.tracker, job.anchor_sets, version)).encode())
    h.update(msgspec.json.encode(params))
    for f in frames:
        h.update(np.int64(f.stamp_ns).tobytes())
        h.update(np.ascontiguousarray(f.z, dtype=np.float64).tobytes())
    for name in ("stonesoup_anchors.py", "anchor_convert.py"):
        h.update(Path(__file__).with_name(name).read_bytes())
    return h.hexdigest()[:24]


def _cached_anchor(job: Job, params, frames) -> tuple[list[Scan], int, bool]:
    """:func:`_run_anchor` through the cache directory ``job.anchor_cache``; also returns
    whether the scans came from the cache."""
    from importlib.metadata import version

    path = Path(job.anchor_cache).expanduser() / f"{job.tracker}-{anchor_cache_key(job, params, frames, version('stonesoup'))}.json"
    if path.exists():
        d = json.loads(path.read_text())
        scans = [Scan(tuple(s["labels"]), np.asarray(s["positions"], float).reshape(-1, 2), s["ms"]) for s in d["scans"]]
        return scans, d["warnings"], True
    scans, n_warn = _run_anchor(job, params, frames)
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = [dict(labels=list(s.labels), positions=s.positions.tolist(), ms=s.ms) for s in scans]
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(dict(warnings=n_warn, scans=rows)))
    tmp.replace(path)
    return scans, n_warn, False


def _run_bnp(job: Job, params, frames) -> tuple[list[Scan], int]:
    config = apply_overrides(kind(job.tracker).presets[job.tracker], list(job.tracker_sets))
    tracker = build(job.tracker, params, config)
    state = tracker.initial_state()
    out = []
    for f in frames:
        rng = tracker_frame_rng(job.seed, f.frame)
        t0 = time.process_time()
        state, est = tracker.step(state, f, rng)
        ms = (time.process_time() - t0) * 1e3
        out.append(Scan(tuple(t.label for t in est.tracks), np.asarray(est.positions, float).reshape(-1, 2), ms))
    return out, 0


def _run_lagged(job: Job, params, frames) -> tuple[list[Scan], int]:
    """The fixed-lag scans of a bnptrack tracker or of the smoothed JPDA anchor."""
    from benchmarks.lagged_anchors import lagged_bnp, smoothed_jpda

    if job.tracker in ANCHORS:
        _online, smoothed, n_warn = smoothed_jpda(params, anchor_settings(job.anchor_sets)[1], frames, job.lag, Scan)
        return smoothed, n_warn
    config = apply_overrides(kind(job.tracker).presets[job.tracker], list(job.tracker_sets))
    return lagged_bnp(build(job.tracker, params, config), params, frames, job.seed, job.lag, Scan), 0


def score(frames, scans: list[Scan], crossings=()) -> dict:
    """The project's metrics of one run (one tracker, one seed)."""
    o = [ospa(f.truth.positions, s.positions, c=100.0, p=1.0).total for f, s in zip(frames, scans)]
    card = [abs(len(s.labels) - len(f.truth.ids)) for f, s in zip(frames, scans)]
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [dict(zip(s.labels, s.positions)) for s in scans]
    o2 = ospa2_series(est_tracks, true_tracks, window=10, c=100.0, p=1.0)
    return dict(ospa=float(np.mean(o)), ospa2=float(np.mean(o2)), card_err=float(np.mean(card)),
                switches=float(label_switches(frames, [_Est(s) for s in scans])),
                crossing=crossing_kept(frames, scans, crossings), ms=[s.ms for s in scans])


class _Est:
    """Adapter so ``benchmarks.accuracy.label_switches`` reads a :class:`Scan`."""

    def __init__(self, scan: Scan):
        self.positions = scan.positions
        self.tracks = tuple(_Lab(lab) for lab in scan.labels)


@dataclass(frozen=True)
class _Lab:
    label: str


def crossing_kept(frames, scans: list[Scan], crossings) -> list[bool]:
    """Per crossing pair of the scene: did both objects keep their labels through it
    (``sinks.metrics.crossing_label_keeping``: labels at c-5 and c+5, gate 100 m)?"""
    if not crossings:
        return []
    true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    est_tracks = [dict(zip(s.labels, s.positions)) for s in scans]
    res = crossing_label_keeping(true_tracks, est_tracks, crossings, first_scan=frames[0].frame)
    return [bool(p.kept) for p in res.pairs]


def split_sets(param_sets: tuple[str, ...]) -> tuple[list[str], list[str]]:
    """``--set`` overrides: ``scene.KEY=V`` go to a generated scenario, the rest to the model params."""
    scene = [o.split(".", 1)[1] for o in param_sets if o.startswith("scene.")]
    return scene, [o for o in param_sets if not o.startswith("scene.")]


def run_job(job: Job) -> dict:
    scene, model = split_sets(job.param_sets)
    sc = get_scenario(job.scenario, seed=job.seed, scene=scene)  # a generated family: this seed's scene
    params = sc.adapt_params(load_params(job.params, model))
    frames = simulate_all(sc, params, job.seed)
    cached = False
    if job.lag:
        scans, n_warn = _run_lagged(job, params, frames)
    elif job.tracker in ANCHORS and job.anchor_cache:
        scans, n_warn, cached = _cached_anchor(job, params, frames)
    else:
        scans, n_warn = (_run_anchor if job.tracker in ANCHORS else _run_bnp)(job, params, frames)
    return dict(tracker=job.name, seed=job.seed, warnings=n_warn, cached=cached,
                **score(frames, scans, sc.crossings))


def summarise(results: list[dict], names: list[str]) -> dict[str, dict]:
    """Mean of each metric over seeds, per tracker; ``ratio``: mean ms / best anchor's mean ms."""
    out = {}
    for name in names:
        rs = [r for r in results if r["tracker"] == name]
        cross = [k for r in rs for k in r["crossing"]]
        ms = np.concatenate([r["ms"] for r in rs])
        out[name] = dict(ospa=float(np.mean([r["ospa"] for r in rs])), ospa2=float(np.mean([r["ospa2"] for r in rs])),
                         card_err=float(np.mean([r["card_err"] for r in rs])),
                         switches=float(np.mean([r["switches"] for r in rs])),
                         crossing=float(np.mean(cross)) if cross else None, crossing_pairs=len(cross),
                         ms_mean=float(ms.mean()), ms_median=float(np.median(ms)), seeds=len(rs),
                         warnings=int(sum(r.get("warnings", 0) for r in rs)),
                         cached=int(sum(bool(r.get("cached")) for r in rs)))
    anchors = [n for n in names if n in ANCHORS]
    best = min(anchors, key=lambda n: out[n]["ospa"]) if anchors else None
    for name in names:
        out[name]["time_vs_best_anchor"] = out[name]["ms_mean"] / out[best]["ms_mean"] if best else None
        out[name]["best_anchor"] = best
    return out


def print_table(summary: dict[str, dict], header: str) -> None:
    print(header)
    best = next(iter(summary.values()))["best_anchor"]
    print(f"| tracker | OSPA | OSPA(2) w=10 | mean abs(N_hat-N) | label switches/run | crossing pairs kept "
          f"| CPU ms/scan mean | median | time / {best or 'anchor'} |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, s in summary.items():
        cross = "n/a" if s["crossing"] is None else f"{s['crossing']:.2f} ({round(s['crossing'] * s['crossing_pairs'])}/{s['crossing_pairs']})"
        ratio = "n/a" if s["time_vs_best_anchor"] is None else f"{s['time_vs_best_anchor']:.3f}"
        label = f"{name} (cached)" if s.get("cached") else name
        print(f"| {label} | {s['ospa']:.2f} | {s['ospa2']:.2f} | {s['card_err']:.3f} | {s['switches']:.2f} | {cross} "
              f"| {s['ms_mean']:.2f} | {s['ms_median']:.2f} | {ratio} |", flush=True)


def _tiny_scene(params, n: int = 5) -> list:
    """One object at (200, 1000) m moving (10, -5) m/s, turning 1 deg/s; noiseless measurements
    in bnptrack's convention, no clutter; ``n`` frames."""
    from bnptrack.tracker.types import Frame, Truth

    motion, sensor = params.motion(), params.measurement("bearing_range")
    x = np.array([[200.0, 10.0, 1000.0, -5.0, np.deg2rad(1.0)]])
    frames = []
    for k in range(1, n + 1):
        frames.append(Frame(frame=k, stamp_ns=k * 10**9, sensor="self", kind="bearing_range",
                            z=sensor.h(x), truth=Truth(("o",), x.copy())))
        x = motion.f(x)
    return frames


def selftest() -> int:
    """Check the Stone Soup side of the conventions and run both anchors on 5 frames."""
    import datetime

    from stonesoup.types.state import State

    from benchmarks.anchor_convert import to_stonesoup_measurements
    from benchmarks.stonesoup_anchors import _models, make_anchor

    params = load_params("vo2017", ["birth=[]"])
    transition, sensor, _, _ = _models(params)
    x = np.array([300.0, 12.0, 900.0, -7.0, np.deg2rad(2.0)])
    dt = datetime.timedelta(seconds=params.T)
    checks = {
        "transition f = bnptrack CT f": np.allclose(
            np.ravel(transition.function(State(x.reshape(-1, 1)), time_interval=dt)), params.motion().f(x[None])[0]),
        "transition Q = bnptrack G G^T": np.allclose(transition.covar(dt), params.motion().Q),
        "bearing-range h after bearing conversion": np.allclose(
            np.cos(np.ravel(sensor.function(State(x.reshape(-1, 1)))).astype(float)
                   - to_stonesoup_measurements(params.measurement().h(x[None]))[0]), 1.0),
    }
    frames = _tiny_scene(params)
    phd = PhdSettings()
    for name in ANCHORS:
        a = make_anchor(name, params, phd, JpdaSettings())
        outs = [a.step(f) for f in frames]
        last, truth = outs[-1], frames[-1].truth.positions[0]
        near = [lab for lab, p in last if np.linalg.norm(p - truth) < 25.0]
        checks[f"{name}: one estimate within 25 m at frame 5"] = len(last) == 1 and len(near) == 1
        checks[f"{name}: label kept over frames 4-5"] = [lab for lab, _ in outs[-2]] == near
    from benchmarks.lagged_anchors import smoothed_jpda

    online, same, _ = smoothed_jpda(params, JpdaSettings(), frames, 0, Scan)
    checks["ss-jpda: smoothing over 0 scans changes nothing"] = all(
        a.labels == b.labels and np.array_equal(a.positions, b.positions) for a, b in zip(online, same))
    _, smoothed, _ = smoothed_jpda(params, JpdaSettings(), frames, 2, Scan)
    checks["ss-jpda --lag 2: the smoothed track within 25 m at frame 3"] = len(smoothed[2].labels) == 1 and \
        np.linalg.norm(smoothed[2].positions[0] - frames[2].truth.positions[0]) < 25.0
    for what, ok in checks.items():
        print(f"{'ok  ' if ok else 'FAIL'} {what}")
    return 0 if all(checks.values()) else 1


def _args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="vo2017")
    ap.add_argument("--seeds", type=int, default=20, help="number of seeds")
    ap.add_argument("--seed-start", type=int, default=1, help="first seed")
    ap.add_argument("--trackers", nargs="*", default=["ddp", "dpyp", "glmb"])
    ap.add_argument("--anchors", nargs="*", default=list(ANCHORS), choices=ANCHORS)
    ap.add_argument("--params", default="vo2017", help="parameter set (name or TOML)")
    ap.add_argument("--set", dest="param_sets", action="append", default=[],
                    help="model parameter override for all trackers and anchors, e.g. --set 'birth=[]'; "
                         "scene.KEY=VALUE sets a generated scenario's family parameter")
    ap.add_argument("--tracker-set", action="append", default=[], help="bnptrack tracker config override")
    ap.add_argument("--anchor-set", action="append", default=[], help="anchor setting, e.g. phd.gate=5")
    ap.add_argument("--anchor-cache", default="", help="directory of cached anchor runs (reused when the key matches)")
    ap.add_argument("--lag", type=int, default=0, metavar="N",
                    help="also the fixed-lag rows: trackers through the lag layer, ss-jpda smoothed (RTS) over N scans")
    ap.add_argument("--workers", type=int, default=1, help="process pool size (default 1)")
    ap.add_argument("--json", action="store_true", help="also print one JSON line with the summary")
    ap.add_argument("--selftest", action="store_true", help="run the anchors on a tiny scene and check them")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = _args(argv)
    if (args.anchors or args.selftest) and importlib.util.find_spec("stonesoup") is None:
        print(MISSING, file=sys.stderr)
        return 2
    if args.selftest:
        return selftest()
    anchor_settings(tuple(args.anchor_set))  # validate before starting the pool
    if args.lag < 0:
        print(f"--lag must be >= 0, got {args.lag}", file=sys.stderr)
        return 2
    from benchmarks.lagged_anchors import SMOOTHED_ANCHORS

    runs = [(n, 0) for n in list(args.trackers) + list(args.anchors)]
    if args.lag:
        runs += [(n, args.lag) for n in args.trackers] + [(n, args.lag) for n in args.anchors if n in SMOOTHED_ANCHORS]
    seeds = range(args.seed_start, args.seed_start + args.seeds)
    jobs = [Job(n, args.scenario, s, args.params, tuple(args.param_sets), tuple(args.tracker_set),
                tuple(args.anchor_set), args.anchor_cache, lag) for s in seeds for n, lag in runs]
    names = [j.name for j in jobs[:len(runs)]]
    with ProcessPoolExecutor(args.workers) as pool:
        results = []
        for r in pool.map(run_job, jobs):
            results.append(r)
            print(f"{len(results)}/{len(jobs)} {r['tracker']} seed {r['seed']}: OSPA {r['ospa']:.2f}",
                  file=sys.stderr, flush=True)
    summary = summarise(results, names)
    print_table(summary, f"scenario {args.scenario}, params {args.params}, seeds {seeds.start}..{seeds.stop - 1}, "
                         f"--set {args.param_sets or 'none'}, tracker overrides {args.tracker_set or 'none'}, "
                         f"anchor settings {args.anchor_set or 'defaults'}")
    if args.json:
        print(json.dumps(dict(scenario=args.scenario, params=args.params, seeds=[seeds.start, seeds.stop - 1],
                              param_sets=args.param_sets, anchor_sets=args.anchor_set, summary=summary)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
