"""The figures of a Monte Carlo experiment (:mod:`pipeline.experiments`), mirroring the
paper's: cardinality, OSPA and its parts over the runs, and the positions of one run.
matplotlib is imported when a figure is drawn."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bnptrack.pipeline.experiment_summary import ci_halfwidth

__all__ = ["write_plots"]


def write_plots(results: Sequence[Any], out: Path, title: str) -> list[Path]:
    """PNG figures mirroring the paper's: x/y vs time, cardinality, OSPA and its parts, of
    ``results`` (:class:`pipeline.experiments.RunResult`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    variants = list(dict.fromkeys(r.job.variant.label for r in results))
    for v in variants:
        runs = [r for r in results if r.job.variant.label == v]
        suffix = "" if len(variants) == 1 else "-" + v.replace(" ", "").replace("-", "m")
        K = runs[0].n_true.size
        k = np.arange(1, K + 1)
        trackers = list(runs[0].trackers)
        # cardinality
        fig, ax = plt.subplots(figsize=(8, 4))
        same = all(np.array_equal(r.n_true, runs[0].n_true) for r in runs)
        n_true = runs[0].n_true if same else np.mean([r.n_true for r in runs], axis=0)
        ax.step(k, n_true, where="mid", color="k", lw=2, label="true" if same else "true (mean)")
        for t in trackers:
            n = np.array([r.trackers[t].n_est for r in runs])
            ax.plot(k, n.mean(0), label=f"{t} (mean)")
            ax.fill_between(k, n.mean(0) - n.std(0), n.mean(0) + n.std(0), alpha=0.2)
        ax.set(xlabel="scan k", ylabel="cardinality", title=f"{title} {v}: estimated vs true cardinality ({len(runs)} runs, ±1 std)")
        ax.legend()
        paths.append(_save(fig, out / f"cardinality{suffix}.png"))
        # OSPA and its parts
        fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
        for ax, (key, name) in zip(axes, (("ospa", "OSPA"), ("ospa_loc", "localisation"), ("ospa_card", "cardinality"))):
            for t in trackers:
                a = np.array([getattr(r.trackers[t], key) for r in runs])
                line, = ax.plot(k, a.mean(0), label=t)
                ax.fill_between(k, np.percentile(a, 10, 0), np.percentile(a, 90, 0), alpha=0.12, color=line.get_color())
                half = np.array([ci_halfwidth(col) for col in a.T])
                ax.fill_between(k, a.mean(0) - half, a.mean(0) + half, alpha=0.4, color=line.get_color(), lw=0)
            ax.set(ylabel=f"{name} (m)")
        axes[0].set_title(f"{title} {v}: OSPA (c=100, p=1): mean, its 95% interval (dark) and the 10-90% band (light) over {len(runs)} runs")
        axes[0].legend()
        axes[-1].set_xlabel("scan k")
        paths.append(_save(fig, out / f"ospa{suffix}.png"))
        # x / y of the representative run
        rep = next((r for r in runs if r.frames is not None), None)
        if rep is not None:
            fig, axes = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
            for ax, dim, name in ((axes[0], 0, "x"), (axes[1], 1, "y")):
                tk = [f.frame for f in rep.frames for _ in f.truth.ids]
                tv = [p[dim] for f in rep.frames for p in f.truth.positions]
                ax.plot(tk, tv, "k.", ms=2, label="true")
                for t, marker in zip(trackers, "o^sv"):
                    ek = [e.frame for e in rep.trackers[t].estimates for _ in e.tracks]
                    ev = [p[dim] for e in rep.trackers[t].estimates for p in e.positions]
                    ax.plot(ek, ev, marker, ms=3, mfc="none", label=t)
                ax.set(ylabel=f"{name} (m)")
            axes[0].set_title(f"{title} {v}: true and estimated positions (run {rep.job.run})")
            axes[0].legend(markerscale=2)
            axes[1].set_xlabel("scan k")
            paths.append(_save(fig, out / f"xy{suffix}.png"))
    return paths


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path
