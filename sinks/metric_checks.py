"""Input checks of the metrics (:mod:`sinks.metrics`, :mod:`sinks.crossings`) and their optimal
assignment.  Each check returns the value as the metric uses it or raises :class:`ValueError`
naming the argument."""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["LabelledScan", "check_positive", "check_order", "check_alpha", "check_points", "check_same_dim",
           "check_tracks", "check_labelled_run", "as_scans", "optimal_assignment"]

LabelledScan = Mapping[Hashable, ArrayLike]


def check_positive(value: object, name: str) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def check_order(value: object, name: str) -> float:
    v = check_positive(value, name)
    if v < 1.0:
        raise ValueError(f"{name} must be >= 1 (the metric needs order >= 1), got {value!r}")
    return v


def check_alpha(value: object) -> float:
    v = check_positive(value, "alpha")
    if v > 2.0:
        raise ValueError(f"alpha must be in (0, 2] (GOSPA is a metric only there), got {value!r}")
    return v


def check_points(A: ArrayLike, name: str) -> np.ndarray:
    """``(m, d)`` finite float array; ``[]`` becomes ``(0, 0)`` (empty, dimension unknown)."""
    arr = np.asarray(A, dtype=float)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 0)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be an (m, d) point array, got shape {arr.shape}")
    if arr.shape[0] > 0 and arr.shape[1] == 0:
        raise ValueError(f"{name} has points with no coordinates (shape {arr.shape})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def check_same_dim(X: np.ndarray, Y: np.ndarray, nx: str, ny: str) -> None:
    """Trailing dimensions must agree unless one side is an empty set given without one."""
    if X.shape[-1] == 0 and X.shape[0] == 0 or Y.shape[-1] == 0 and Y.shape[0] == 0:
        return
    if X.shape[1:] != Y.shape[1:]:
        raise ValueError(
            f"{nx} and {ny} have mismatched dimensions: {X.shape[1:]} vs {Y.shape[1:]}"
        )


def check_tracks(A: ArrayLike, name: str) -> np.ndarray:
    """``(n, W, d)`` float array with whole-position NaNs only; never-existing tracks dropped."""
    arr = np.asarray(A, dtype=float)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 0, 0)
    if arr.ndim != 3:
        raise ValueError(f"{name} must be an (n_tracks, W, d) array, got shape {arr.shape}")
    if arr.shape[0] > 0 and arr.shape[1] > 0 and arr.shape[2] == 0:
        raise ValueError(f"{name} has positions with no coordinates (shape {arr.shape})")
    if np.any(np.isinf(arr)):
        raise ValueError(f"{name} contains infinite values")
    nan = np.isnan(arr)
    if np.any(nan.any(axis=-1) != nan.all(axis=-1)):
        raise ValueError(f"{name} has partially-NaN positions (a position is all NaN or finite)")
    exists = ~nan.all(axis=-1)  # (n, W); all False when d == 0
    return arr[exists.any(axis=1)]


def check_labelled_run(run: Sequence[LabelledScan], name: str) -> tuple[list[dict], int | None]:
    """Per-scan ``{label: (d,) position}`` dicts -> (list of dicts of arrays, d or None)."""
    if isinstance(run, (str, bytes, Mapping)) or not isinstance(run, Sequence):
        raise ValueError(
            f"{name} must be a sequence (one entry per scan) of label -> position dicts"
        )
    out: list[dict] = []
    dim: int | None = None
    for k, scan in enumerate(run):
        if not isinstance(scan, Mapping):
            raise ValueError(f"{name}[{k}] must be a mapping label -> position, got {type(scan)}")
        conv = {}
        for label, pos in scan.items():
            x = np.asarray(pos, dtype=float)
            if x.ndim != 1 or x.size == 0:
                raise ValueError(f"{name}[{k}][{label!r}] must be a (d,) position, got {x.shape}")
            if not np.all(np.isfinite(x)):
                raise ValueError(f"{name}[{k}][{label!r}] contains NaN or infinite values")
            if dim is not None and x.size != dim:
                raise ValueError(f"{name}[{k}][{label!r}] has dimension {x.size}, expected {dim}")
            dim = x.size
            conv[label] = x
        out.append(conv)
    return out, dim


def as_scans(run: list[dict], dim: int) -> list[tuple[tuple[Hashable, ...], np.ndarray]]:
    """Checked ``{label: position}`` scans as (labels, ``(n, dim)`` positions)."""
    return [(tuple(scan), np.array(list(scan.values()), dtype=float).reshape(len(scan), dim)) for scan in run]


def optimal_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Optimal assignment (:func:`scipy.optimize.linear_sum_assignment`).

    scipy is imported here, at the first score: importing ``scipy.optimize`` is slow
    (docs/performance.md, measured), which a process that only unpickles :class:`sinks.metrics.OspaResult` (the Rerun recording process, see
    ``sinks.rerun_process``) should not pay.
    """
    from bnptrack.tracker.numerics import scipy_extension  # scipy's solver without scipy.optimize's import

    return scipy_extension("optimize", "_lsap").linear_sum_assignment(cost)
