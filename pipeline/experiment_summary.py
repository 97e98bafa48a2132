"""An experiment's per-run scores and their summary over runs: means, spreads and 95 %
confidence intervals, as a markdown table and a CSV.

A run is summarised by :class:`RunScores`, a few numbers per tracker (the run's mean OSPA and
its parts, OSPA(2), GOSPA, cardinality error, median ms per frame, the crossing pairs it kept
and the sums of each extra metric).  Those numbers are all the table needs, so a resumable
experiment journals them (:mod:`pipeline.experiment_journal`) and summarises any number of runs
without holding their per-frame series.

The interval of a mean over ``n`` runs is ``mean ± t(0.975, n-1) * std / sqrt(n)`` (Student's
t over independent runs: each run draws its own scene, noise and tracker streams).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The table's metrics: key, column header.
METRICS = (("ospa", "OSPA"), ("ospa_loc", "OSPA loc"), ("ospa_card", "OSPA card"), ("ospa2", "OSPA(2)"),
           ("gospa", "GOSPA"), ("card_err", "card. error"), ("ms", "ms/frame"))

#: Extra metrics an experiment may carry (:class:`pipeline.experiments.FrameMetric`): key, header.
EXTRA_LABELS = {"within100": "within 100 m", "range_ospa": "range OSPA"}


@dataclass(frozen=True)
class TrackerScores:
    """One tracker's scores on one run: ``values`` holds the run's value of each of
    :data:`METRICS` in that order; ``crossings_kept`` one flag per crossing pair (empty when the
    scene has none); ``extra`` each extra metric's ``(sum of num, sum of den)`` over frames."""

    values: tuple[float, ...]
    crossings_kept: tuple[bool, ...] = ()
    extra: dict[str, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class RunScores:
    """The scores of one run of an experiment: its variant's label, its index, and one
    :class:`TrackerScores` per tracker label."""

    variant: str
    run: int
    trackers: dict[str, TrackerScores]


def ci_halfwidth(a: np.ndarray) -> float:
    """Half-width of the 95 % confidence interval of the mean of ``a`` (Student's t); nan (no
    interval) for fewer than two values."""
    from scipy.stats import t

    n = a.size
    return float(t.ppf(0.975, n - 1) * a.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")


def _spread(key: str, a: np.ndarray) -> dict:
    return {key: float(a.mean()), key + "_std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
            key + "_ci": ci_halfwidth(a)}


def summarise(scores: Sequence[RunScores]) -> list[dict]:
    """One row per variant and tracker: ``runs``, and for every metric its mean over runs,
    ``_std`` (of the per-run values) and ``_ci`` (95 % half-width of the mean)."""
    rows = []
    variants = list(dict.fromkeys(s.variant for s in scores))
    trackers = list(dict.fromkeys(t for s in scores for t in s.trackers))
    for v in variants:
        runs = [s for s in scores if s.variant == v]
        for t in trackers:
            per_run = np.array([s.trackers[t].values for s in runs], dtype=float).reshape(len(runs), len(METRICS))
            row: dict = {"variant": v, "tracker": t, "runs": len(runs)}
            for i, (k, _) in enumerate(METRICS):
                row.update(_spread(k, per_run[:, i]))
            row.update(_crossing_summary([s.trackers[t].crossings_kept for s in runs]))
            row.update(_extra_summary([s.trackers[t].extra for s in runs]))
            rows.append(row)
    return rows


def _crossing_summary(per_run: Sequence[Sequence[bool]]) -> dict:
    """``crossings_kept``: the fraction of all crossing pairs of all runs that kept both
    labels (std and interval: of the per-run fractions); ``crossing_pairs``: their number.
    Empty when the scenario has no crossing pairs."""
    kept = [np.asarray(k, bool) for k in per_run if len(k)]
    if not kept:
        return {}
    frac = np.array([k.mean() for k in kept])
    allk = np.concatenate(kept)
    return {"crossings_kept": float(allk.mean()),
            "crossings_kept_std": float(frac.std(ddof=1)) if frac.size > 1 else 0.0,
            "crossings_kept_ci": ci_halfwidth(frac), "crossing_pairs": int(allk.size)}


def _extra_summary(per_run: Sequence[dict[str, tuple[float, float]]]) -> dict:
    """Each extra metric's per-run ``sum(num) / sum(den)``: mean, std and interval over runs."""
    out: dict = {}
    for key in per_run[0] if per_run else ():
        a = np.array([x[key][0] / max(x[key][1], 1e-12) for x in per_run])
        out.update(_spread(key, a))
    return out


def _columns(rows: list[dict]) -> list[tuple[str, str]]:
    cols = list(METRICS) + ([("crossings_kept", "crossings kept")] if "crossings_kept" in rows[0] else [])
    return cols + [(k, label) for k, label in EXTRA_LABELS.items() if k in rows[0]]


def _legend(rows: list[dict]) -> str:
    text = ("Mean over runs ± the half-width of its 95 % confidence interval (Student's t over runs; "
            "the CSV also gives the std of the per-run values). OSPA/OSPA(2)/GOSPA: c = 100 m, p = 1, on "
            "position; OSPA(2) window 10 scans; ms/frame: per-run median.")
    if "crossings_kept" in rows[0]:
        text += (" Crossings kept: fraction of all crossing pairs whose two objects keep their track label "
                 "from scan c-5 to c+5 (Hungarian, gate 100 m; interval over the per-run fractions).")
    if "within100" in rows[0]:
        text += (" Within 100 m: fraction of object-frames with an estimate within 100 m (one-to-one); range "
                 "OSPA: 1-D OSPA on range from the sensor (c = 100 m, p = 1), what a range-only sensor "
                 "observes (sinks/range_scores.py).")
    return text


def _half(ci: float) -> str:
    """An interval's half-width in the table: ``n/a`` when there is none (a single run)."""
    return "n/a" if np.isnan(ci) else f"{ci:.2f}"


def write_summary(rows: list[dict], out: Path, title: str) -> tuple[Path, Path]:
    """``summary.md`` (the table) and ``summary.csv`` (every column) in ``out``."""
    md, csv_path = out / "summary.md", out / "summary.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    metrics = _columns(rows)
    lines = [f"# {title}", "", _legend(rows), "",
             "| variant | tracker | runs | " + " | ".join(h for _, h in metrics) + " |",
             "|---|---|---|" + "---|" * len(metrics)]
    for r in rows:
        cells = " | ".join(f"{r[k]:.2f} ± {_half(r[k + '_ci'])}" for k, _ in metrics)
        lines.append(f"| {r['variant']} | {r['tracker']} | {r['runs']} | {cells} |")
    md.write_text("\n".join(lines) + "\n")
    return md, csv_path
