"""The paper's simulation study as Monte Carlo experiments: one command per experiment.

``bnptrack experiment NAME --runs N --seed S --params paper|vo2017 --out DIR`` runs every
tracker of the experiment on ``N`` simulated realisations and writes a summary table
(markdown + CSV), plots mirroring the paper's figures and, when the Rerun sink is installed,
a ``.rrd`` of one representative run per tracker.

Run ``i`` of experiment ``E`` with seed ``S`` draws its scenario and every tracker's random
stream from ``SeedSequence(S, spawn_key=(crc32(E), i))`` alone, so any single run can be redone
by itself and gives the same numbers, whichever executor ran it (local processes or a Dask
cluster).
"""

from __future__ import annotations

import importlib.util
import os
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bnptrack.pipeline.experiment_summary import (EXTRA_LABELS, METRICS, RunScores, TrackerScores, summarise,
                                                  write_summary)
from bnptrack.sinks.metrics import OSPA2_WINDOW, OSPA_C, OSPA_P
from bnptrack.tracker.config import ConfigError

if TYPE_CHECKING:
    from concurrent.futures import Executor


@dataclass(frozen=True)
class TrackerSpec:
    """One tracker of an experiment: its registry name (``ddp``, ``ddp-mb``, ``glmb``, ...),
    preset, display label."""

    name: str
    preset: str
    label: str


@dataclass(frozen=True)
class Variant:
    """One condition of an experiment (e.g. an SNR level): a label and parameter overrides."""

    label: str
    overrides: tuple[str, ...] = ()


@dataclass(frozen=True)
class FrameMetric:
    """An extra score of an experiment: ``fn(true positions, estimated positions) -> (num, den)``
    per frame; a run's value is ``sum(num) / sum(den)`` (e.g. :mod:`sinks.range_scores`)."""

    key: str
    label: str
    fn: Callable[[np.ndarray, np.ndarray], tuple[float, float]]


@dataclass(frozen=True)
class Experiment:
    name: str
    description: str
    scenario: str
    trackers: tuple[TrackerSpec, ...]
    variants: tuple[Variant, ...] = (Variant("default"),)
    metrics: tuple[FrameMetric, ...] = ()


#: The parameter set ``bnptrack experiment`` uses by default: the paper's (sigma 15 m/s^2,
#: P_S 0.95, 1 deg / 5 m; tracker/params/paper.toml).
DEFAULT_EXPERIMENT_PARAMS = "paper"

#: The paper's SNR in experiments 1, 2, 4 and 5 ("the signal-to-noise ratio (SNR) is -3 dB").
PAPER_SNR = (Variant("-3 dB", ("snr_db=-3",)),)


def _pair(name: str, preset: str, label: str, mb: str | None = None) -> tuple[TrackerSpec, TrackerSpec]:
    """The two-level tracker (``NAME``, preset ``preset``, label ``LABEL``) and its single-level
    ablation (``NAME-mb``, preset ``mb``, by default the matching ``NAME-mb...``, label ``LABEL (mb)``)."""
    mb = f"{name}-mb{preset[len(name):]}" if mb is None else mb
    return (TrackerSpec(name, preset, label), TrackerSpec(f"{name}-mb", mb, f"{label} (mb)"))


#: The paper's DDP-EMM (``ddp-paper``: the product default's identity guard ``share_after`` off):
#: the experiments test the paper's claims on its algorithm.
_PAPER_DDP = _pair("ddp", "ddp-paper", "DDP-EMM", mb="ddp-mb")


_GLMB = TrackerSpec("glmb", "glmb", "GLMB")


def _range_metrics() -> tuple[FrameMetric, ...]:
    from bnptrack.sinks.range_scores import range_ospa, within_gate

    return (FrameMetric("within100", EXTRA_LABELS["within100"], within_gate),
            FrameMetric("range_ospa", EXTRA_LABELS["range_ospa"], range_ospa))


EXPERIMENTS: dict[str, Experiment] = {
    e.name: e
    for e in (
        Experiment("ddp-vs-glmb", "DDP-EMM vs GLMB, 10 targets, SNR -3 dB (paper experiment 1)", "vo2017",
                   (*_PAPER_DDP, _GLMB), PAPER_SNR),
        Experiment("proximity", "Close proximity: 5 targets on one path, SNR -3 dB (experiment 2)", "proximity",
                   (*_pair("ddp", "ddp-proximity", "DDP-EMM"), _GLMB), PAPER_SNR),
        Experiment("snr", "Varying SNR, range-only, 11 targets (experiment 3)", "snr",
                   (*_pair("ddp", "ddp-snr", "DDP-EMM"), _GLMB),
                   (Variant("-3 dB", ("snr_db=-3",)), Variant("-5 dB", ("snr_db=-5",)),
                    Variant("-10 dB", ("snr_db=-10",))), _range_metrics()),
        Experiment("dpy-vs-glmb", "DPY-STP vs GLMB, at most 5 targets, SNR -3 dB (experiment 4)", "dpy5",
                   (*_pair("dpyp", "dpyp", "DPY-STP"), _GLMB), PAPER_SNR),
        Experiment("dpy-vs-ddp", "DPY-STP vs DDP-EMM, 10 targets, SNR -3 dB (experiment 5)", "vo2017",
                   (*_pair("dpyp", "dpyp", "DPY-STP"), *_PAPER_DDP), PAPER_SNR),
        Experiment("random", "Objects born anywhere: 20-30 objects, 3 crossing pairs, no birth "
                   "regions (generated random family; each run draws its own scene)", "random",
                   (TrackerSpec("ddp-mb", "ddp-mb", "DDP-EMM (mb)"), TrackerSpec("dpyp-mb", "dpyp-mb", "DPY-STP (mb)"),
                    TrackerSpec("glmb", "glmb", "GLMB"))),
    )
}


def get_experiment(name: str) -> Experiment:
    try:
        return EXPERIMENTS[name]
    except KeyError:
        raise ConfigError(f"unknown experiment {name!r}; valid: {', '.join(EXPERIMENTS)}") from None


def run_seed(experiment: str, seed: int, run: int) -> int:
    """The integer seed of run ``run``: from ``SeedSequence(seed, spawn_key=(crc32(name), run))``."""
    ss = np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(experiment.encode()), int(run)))
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


@dataclass(frozen=True)
class RunJob:
    experiment: str
    seed: int
    run: int
    params: str
    variant: Variant
    keep_tracks: bool = False
    #: run only these of the experiment's trackers (registry names or labels; empty: all).
    #: Every tracker draws from its own per-frame streams and the simulation from the run's
    #: seed, so a tracker's series are the same whichever others run beside it.
    trackers: tuple[str, ...] = ()


def select_trackers(exp: Experiment, names: Sequence[str]) -> tuple[TrackerSpec, ...]:
    """The trackers of ``exp`` named in ``names`` (registry name or label), in the
    experiment's order; all of them when ``names`` is empty."""
    if not names:
        return exp.trackers
    known = {s.name for s in exp.trackers} | {s.label for s in exp.trackers}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigError(f"experiment {exp.name!r} has no tracker {', '.join(map(repr, unknown))}; "
                          f"valid: {', '.join(s.name for s in exp.trackers)}")
    return tuple(s for s in exp.trackers if s.name in names or s.label in names)


@dataclass
class TrackerRun:
    """Per-frame series of one tracker on one run (arrays of length K)."""

    ospa: np.ndarray
    ospa_loc: np.ndarray
    ospa_card: np.ndarray
    ospa2: np.ndarray
    gospa: np.ndarray
    n_est: np.ndarray
    ms: np.ndarray
    estimates: list | None = None  # per frame Estimate, representative runs only (keep_tracks)
    crossings_kept: np.ndarray | None = None  # (pairs,) bool: pair kept both labels (random)
    extra: dict[str, np.ndarray] = field(default_factory=dict)  # Experiment.metrics: (K, 2) num, den


@dataclass
class RunResult:
    job: RunJob
    n_true: np.ndarray
    trackers: dict[str, TrackerRun] = field(default_factory=dict)
    frames: list | None = None  # the run's frames (with truth) when keep_tracks


def _run_setup(job: RunJob):
    """The experiment, its scenario, the model parameters and the seed of one run.

    A generated scenario (``random``) draws its scene from the run's seed (and the
    variant's ``scene.*`` overrides), so every run has its own scene."""
    from bnptrack.sources.scenarios import open_scenario

    exp = get_experiment(job.experiment)
    seed = run_seed(job.experiment, job.seed, job.run)
    opened = open_scenario(exp.scenario, job.params, seed, job.variant.overrides)
    return exp, opened.scenario, opened.params, seed


def execute_run(job: RunJob) -> RunResult:
    """One Monte Carlo run: simulate the scenario, run every tracker, score every frame."""
    from bnptrack.sources.synthetic import simulate_all

    exp, scenario, params, seed = _run_setup(job)
    frames = simulate_all(scenario, params, seed)
    n_true = np.array([len(f.truth.ids) for f in frames])
    result = RunResult(job, n_true, frames=frames if job.keep_tracks else None)
    for spec in select_trackers(exp, job.trackers):
        result.trackers[spec.label] = _score_tracker(spec, params, frames, seed, scenario.crossings,
                                                     job.keep_tracks, exp.metrics)
    return result


def _score_tracker(spec: TrackerSpec, params, frames: list, seed: int,
                   crossings: Sequence[tuple[str, str, int]], keep_tracks: bool,
                   metrics: Sequence[FrameMetric] = ()) -> TrackerRun:
    """Run one tracker over a run's frames and score every frame: OSPA, OSPA(2) and GOSPA
    (alpha 2) by one :class:`sinks.run_scorer.RunScorer` (as ``bnptrack track`` and the pipeline's
    sink; the three share each frame's distance matrix; its OSPA(2) window compiled, the
    same numbers: the trackers have loaded numba here anyway), the experiment's extra
    ``metrics`` and the label keeping through ``crossings``."""
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.sinks.crossings import crossing_label_keeping
    from bnptrack.sinks.run_scorer import RunScorer
    from bnptrack.tracker.state import run as run_tracker

    tracker = tracker_setup(spec.name, params=params, config=spec.preset).tracker
    scorer = RunScorer(c=OSPA_C, p=OSPA_P, window=OSPA2_WINDOW, gospa_alpha=2.0, compiled=True)
    rows, est_tracks, kept, extra = [], [], [], []
    for f, e, _ in run_tracker(tracker, frames, seed):
        scores = scorer.update(f, e)
        o, g = scores["ospa"], scores["gospa"]
        rows.append((o.total, o.localisation, o.cardinality, scores["ospa2"], g.total, len(e.tracks),
                     e.diagnostics.get("ms", np.nan)))
        if crossings:
            est_tracks.append({t.label: t.position for t in e.tracks})
        if keep_tracks:
            kept.append(e)
        extra.append([m.fn(f.truth.positions, e.positions) for m in metrics])
    r = np.array(rows, dtype=float)
    cross = None
    if crossings:
        true_tracks = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
        res = crossing_label_keeping(true_tracks, est_tracks, crossings)
        cross = np.array([pr.kept for pr in res.pairs], dtype=bool)
    ex = np.asarray(extra, dtype=float).reshape(len(extra), len(metrics), 2)
    return TrackerRun(r[:, 0], r[:, 1], r[:, 2], r[:, 3], r[:, 4], r[:, 5], r[:, 6],
                      kept if keep_tracks else None, cross, {m.key: ex[:, i] for i, m in enumerate(metrics)})


# --------------------------------------------------------------------------- executors


def run_jobs(jobs: Sequence[RunJob], *, workers: int | None = None, cluster: str | None = None,
             progress: Callable[[RunResult], None] | None = None, executor: Executor | None = None
             ) -> list[RunResult]:
    """Run jobs on local processes (default), a given ``executor`` (e.g. a warm pool from
    :func:`warm_pool`, kept across calls) or a Dask cluster at ``cluster``; results in job order.
    ``progress`` is called with each result as it finishes (in the order runs finish).

    One task per run: a worker keeps its imports and compiled kernels from one run to the
    next, and a task costs well under a millisecond against about half a second of run
    (docs/performance.md), so chunking runs would only unbalance the workers' last runs."""
    if cluster:
        return _run_dask(jobs, cluster, progress)
    if workers == 1 and executor is None:
        out = []
        for job in jobs:
            out.append(execute_run(job))
            if progress:
                progress(out[-1])
        return out
    if executor is not None:
        return _run_pool(executor, jobs, progress)
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=workers) as pool:
        return _run_pool(pool, jobs, progress)


def warm_pool(workers: int, experiment: str = "ddp-vs-glmb") -> Executor:
    """A process pool of ``workers`` processes, each of which has imported the trackers and
    loaded their compiled kernels (one run of ``experiment`` at start-up), for
    :func:`run_jobs`'s ``executor`` when several batches of jobs share the workers or a
    benchmark must not time the workers' start.  Close it with ``shutdown()``."""
    from concurrent.futures import ProcessPoolExecutor, wait

    pool = ProcessPoolExecutor(max_workers=workers, initializer=_warm_worker, initargs=(experiment,))
    wait([pool.submit(os.getpid) for _ in range(workers)])  # one worker started per task while none is idle
    return pool


def _warm_worker(experiment: str) -> None:
    exp = get_experiment(experiment)
    execute_run(RunJob(experiment, 0, 0, "vo2017", exp.variants[0]))


def _run_pool(pool: Executor, jobs: Sequence[RunJob], progress) -> list[RunResult]:
    from concurrent.futures import as_completed

    results: list[RunResult | None] = [None] * len(jobs)
    futures = {pool.submit(execute_run, job): i for i, job in enumerate(jobs)}
    for fut in as_completed(futures):
        i = futures[fut]
        results[i] = fut.result()
        if progress:
            progress(results[i])
    return results  # type: ignore[return-value]


def _run_dask(jobs: Sequence[RunJob], address: str, progress) -> list[RunResult]:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ConfigError("--cluster needs Dask's distributed scheduler, an optional extra: "
                          "pip install 'bnptrack[dask]' (local worker processes need nothing extra)") from None

    with Client(address) as client:
        futures = client.map(execute_run, list(jobs), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list[RunResult | None] = [None] * len(jobs)
        for fut in as_completed(futures):
            i = index[fut.key]
            results[i] = fut.result()
            if progress:
                progress(results[i])
    return results  # type: ignore[return-value]


# --------------------------------------------------------------------------- summaries


def run_scores(result: RunResult) -> RunScores:
    """The numbers of one run that its experiment's table needs (:mod:`pipeline.experiment_summary`)."""
    trackers = {}
    for t, tr in result.trackers.items():
        values = (tr.ospa.mean(), tr.ospa_loc.mean(), tr.ospa_card.mean(), tr.ospa2.mean(), tr.gospa.mean(),
                  np.abs(tr.n_est - result.n_true).mean(), np.nanmedian(tr.ms))
        kept = () if tr.crossings_kept is None else tuple(bool(k) for k in tr.crossings_kept)
        extra = {k: (float(x[:, 0].sum()), float(x[:, 1].sum())) for k, x in tr.extra.items()}
        trackers[t] = TrackerScores(tuple(float(v) for v in values), kept, extra)
    return RunScores(result.job.variant.label, result.job.run, trackers)


def summary_rows(results: Sequence[RunResult | RunScores]) -> list[dict]:
    """Mean, std (of the per-run values) and 95 % interval of every metric, per variant and
    tracker (:func:`pipeline.experiment_summary.summarise`)."""
    return summarise([r if isinstance(r, RunScores) else run_scores(r) for r in results])


def write_representative_rrd(result: RunResult, out: Path) -> list[Path]:
    """One ``.rrd`` per tracker of a run kept with ``keep_tracks``, through the ``rerun`` entry
    of the table of sinks (none without rerun-sdk)."""
    from bnptrack.sinks.records import SinkOptions, SinkRecord
    from bnptrack.sinks.sink import SinkSet, make_sink

    if importlib.util.find_spec("rerun") is None:  # the sink needs rerun-sdk
        return []
    job = result.job
    exp, _, params, seed = _run_setup(job)
    tag = "" if len(exp.variants) == 1 else "-" + job.variant.label.replace(" ", "").replace("-", "m")
    paths = []
    for spec in exp.trackers:
        path = out / f"{spec.name}{tag}-run{job.run}.rrd"
        meta = {"experiment": job.experiment, "scenario": exp.scenario, "params": job.params,
                "tracker": spec.name, "preset": spec.preset, "seed": str(seed), "variant": job.variant.label}
        sinks = SinkSet([make_sink("rerun", SinkOptions(path, params=params))])
        sinks.open(meta)
        try:
            for frame, est in zip(result.frames, result.trackers[spec.label].estimates, strict=True):
                sinks.write(SinkRecord(frame, est))
        finally:
            sinks.close()
        paths.append(path)
    return paths


@dataclass(frozen=True)
class ExperimentOutput:
    out: Path
    summary_md: Path
    summary_csv: Path
    plots: tuple[Path, ...]
    recordings: tuple[Path, ...]
    rows: tuple[dict, ...]
    seconds: float


def _jobs_to_run(exp: Experiment, seed: int, params: str, runs: int, have: dict) -> list[RunJob]:
    """Runs ``0 .. runs-1`` of every variant that ``have`` (the journal's runs) lacks, plus the
    representative run 0 of each variant redone for its plots and recordings when the journal
    holds it."""
    jobs = [RunJob(exp.name, seed, i, params, v, keep_tracks=(i == 0)) for v in exp.variants for i in range(runs)
            if (v.label, i) not in have]
    return jobs + [RunJob(exp.name, seed, 0, params, v, keep_tracks=True) for v in exp.variants
                   if (v.label, 0) in have]


def _revalidate(name: str, seed: int, params: str, out: Path, code: str, k: int, workers, cluster) -> None:
    """Redo ``k`` of the journal's runs (evenly spread) with this code; adopt the journal when
    every one gives the same scores, else refuse naming the first run that differs."""
    from bnptrack.pipeline.experiment_journal import adopt, journal_runs, same_scores

    header, done = journal_runs(out)
    if header.get("code") == code or not done:
        return
    picks = [done[int(i)] for i in np.linspace(0, len(done) - 1, min(k, len(done)))]
    exp = get_experiment(name)
    variants = {v.label: v for v in exp.variants}
    jobs = [RunJob(name, seed, s.run, params, variants[s.variant]) for s in picks]
    timing = [k for k, _ in METRICS].index("ms")
    for old, new in zip(picks, run_jobs(jobs, workers=workers, cluster=cluster)):
        if not same_scores(old, run_scores(new), timing):
            raise ConfigError(f"{out}: run {old.run} ({old.variant}) redone by this code gives other scores than "
                              "the journal's: its runs cannot be carried over; use --fresh or another --out")
    adopt(out, code)


def _progress_bar(name: str, total: int, done: int):
    """A progress bar with the rate and the time left, starting at the runs already journalled."""
    from tqdm import tqdm

    return tqdm(total=total, initial=done, desc=name, unit="run", smoothing=0.05)


def run_experiment(name: str, *, runs: int = 100, seed: int = 1, params: str = DEFAULT_EXPERIMENT_PARAMS,
                   out: Path | None = None, workers: int | None = None, cluster: str | None = None,
                   quiet: bool = False, rrd: bool = True, fresh: bool = False,
                   revalidate: int = 0) -> ExperimentOutput:
    """Run experiment ``name`` end to end and write its outputs into ``out``.

    Every finished run is journalled in ``out/runs.jsonl`` (:mod:`pipeline.experiment_journal`):
    started again with the same ``out``, the experiment runs only the runs the journal lacks
    (``fresh`` starts over; ``revalidate`` K carries over a journal of other tracker code
    once K of its runs, redone, give the same scores).  The table covers runs ``0 .. runs-1`` of every variant; the
    plots, the runs executed in this invocation."""
    import time

    from bnptrack.pipeline.experiment_journal import JOURNAL_NAME, RunJournal, code_fingerprint

    exp = get_experiment(name)
    if runs < 1:
        raise ConfigError(f"--runs must be >= 1, got {runs}")
    out = Path(out) if out is not None else Path("recordings") / "experiments" / f"{name}-{params}-s{seed}"
    out.mkdir(parents=True, exist_ok=True)
    if fresh:
        (out / JOURNAL_NAME).unlink(missing_ok=True)
    setup = {"experiment": name, "seed": seed, "params": params, "trackers": [t.label for t in exp.trackers],
             "variants": [v.label for v in exp.variants], "code": code_fingerprint()}
    if revalidate and (out / JOURNAL_NAME).exists():
        _revalidate(name, seed, params, out, setup["code"], revalidate, workers, cluster)
    journal, done = RunJournal.open(out, setup)
    have = {(s.variant, s.run): s for s in done}
    jobs = _jobs_to_run(exp, seed, params, runs, have)
    bar = None if quiet else _progress_bar(name, len(exp.variants) * runs,
                                           sum((v.label, i) in have for v in exp.variants for i in range(runs)))

    def record(result: RunResult) -> None:
        key = (result.job.variant.label, result.job.run)
        if key not in have:  # not the representative run redone
            have[key] = run_scores(result)
            journal.append(have[key])
            if bar is not None:
                bar.update(1)

    t0 = time.perf_counter()
    try:
        results = run_jobs(jobs, workers=workers, cluster=cluster, progress=record)
    finally:
        journal.close()
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0
    title = f"{name} ({exp.description}; params {params}, seed {seed}, {runs} runs)"
    rows = summary_rows([have[(v.label, i)] for v in exp.variants for i in range(runs)])
    md, csv_path = write_summary(rows, out, title)
    from bnptrack.pipeline.experiment_plots import write_plots

    plots = write_plots(results, out, name)
    recs: list[Path] = []
    if rrd:
        for v in exp.variants:
            rep = next(r for r in results if r.job.variant == v and r.job.run == 0)
            recs += write_representative_rrd(rep, out)
    return ExperimentOutput(out, md, csv_path, tuple(plots), tuple(recs), tuple(rows), seconds)
