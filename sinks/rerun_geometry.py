"""The geometry a Rerun recording draws, in numpy over many frames at once (no per-point Python
loops): the field of view and grid steps, the ``k``-sigma ellipses, trails gathered from
position histories, truth crosses, range rings and the measurement points of range-only
sensors.  Does not import rerun.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bnptrack.sinks.rerun_style import ELLIPSE_POINTS, ELLIPSE_SIGMA

__all__ = ["SceneGeometry", "ellipses", "gather", "nice_step", "truth_crosses",
           "measurement_xy", "labels_shown", "hits_per_row", "assignment_index", "track_strips",
           "truth_trails", "EMPTY2", "EMPTY22", "EMPTY_U16", "EMPTY_U32"]

EMPTY2 = np.zeros((0, 2))
EMPTY22 = np.zeros((0, 2, 2))
EMPTY_U16 = np.zeros(0, dtype=np.uint16)
EMPTY_U32 = np.zeros(0, dtype=np.uint32)


@dataclass(frozen=True)
class SceneGeometry:
    """The scene drawn: the ``(x0, x1, y0, y1)`` box (m), the half-size of a truth cross (m)
    and the unit circle of the ellipses (``(ELLIPSE_POINTS + 1, 2)``)."""

    bounds: tuple[float, float, float, float]
    cross: float
    circle: np.ndarray

    @classmethod
    def of(cls, bounds: tuple[float, float, float, float]) -> SceneGeometry:
        """The scene of the box ``bounds`` (the sensors' fields of view,
        :func:`sinks.rerun_sensors.scene_extent`)."""
        circle = np.linspace(0.0, 2.0 * np.pi, ELLIPSE_POINTS + 1)
        span = max(bounds[1] - bounds[0], bounds[3] - bounds[2], 1.0)
        return cls(tuple(float(b) for b in bounds), 0.0075 * span,  # type: ignore[arg-type]
                   np.stack([np.cos(circle), np.sin(circle)], axis=-1))

    def with_bounds(self, bounds: tuple[float, float, float, float]) -> SceneGeometry:
        """The same scene over a larger box (the cross keeps its size)."""
        return SceneGeometry(tuple(float(b) for b in bounds), self.cross, self.circle)  # type: ignore[arg-type]


def ellipses(center: np.ndarray, cov: np.ndarray, circle: np.ndarray, k: float) -> np.ndarray:
    """``(n, K, 2)`` polygons of the ``k``-sigma ellipses ``{c + k L u : |u| = 1}``, ``L L^T = P``.

    ``L`` is the closed-form Cholesky factor of each ``2 x 2`` covariance (any square root
    traces the same ellipse); a non-positive-definite input is clipped to semidefinite.
    """
    a = np.maximum(cov[:, 0, 0], 0.0)
    b = 0.5 * (cov[:, 0, 1] + cov[:, 1, 0])
    c = np.maximum(cov[:, 1, 1], 0.0)
    l11 = np.sqrt(a)
    l21 = np.divide(b, l11, out=np.zeros_like(b), where=l11 > 0)
    l22 = np.sqrt(np.maximum(c - l21 * l21, 0.0))
    u, v = k * circle[:, 0], k * circle[:, 1]  # (K,)
    out = np.empty((cov.shape[0], circle.shape[0], 2))
    out[:, :, 0] = center[:, 0, None] + l11[:, None] * u[None]
    out[:, :, 1] = center[:, 1, None] + l21[:, None] * u[None] + l22[:, None] * v[None]
    return out


def gather(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Concatenation of ``points[starts[i]:ends[i]]`` for all ``i`` and the segment lengths."""
    lengths = (ends - starts).astype(np.int64)
    offsets = np.zeros(lengths.size + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    idx = np.arange(offsets[-1]) - np.repeat(offsets[:-1] - starts, lengths)
    return points[idx], lengths


def nice_step(span: float) -> float:
    """The largest round grid step (1, 2 or 5 x 10^n metres) not above ``span``."""
    base = 10.0 ** math.floor(math.log10(max(span, 1e-9)))
    return max(m * base for m in (1.0, 2.0, 5.0) if m * base <= span * (1 + 1e-9))


def truth_crosses(TP: np.ndarray, h: float) -> np.ndarray:
    """``(n, 2, 2, 2)``: two strokes (each two points) of an x-shaped cross of half-size ``h``
    at each of the ``(n, 2)`` positions."""
    cross = np.empty((TP.shape[0], 2, 2, 2))
    cross[:, 0, 0] = TP + (-h, -h)
    cross[:, 0, 1] = TP + (h, h)
    cross[:, 1, 0] = TP + (-h, h)
    cross[:, 1, 1] = TP + (h, -h)
    return cross


def measurement_xy(model: Any, Z: np.ndarray, tpos: np.ndarray, gidx: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """``(M, 2)`` points drawn for the measurements ``Z`` of ``model``: the measured position
    when a row fixes one (``model.fixes_position``), else the point of the row's locus (a
    range ring, say) nearest the assigned track (``hit``: assigned, ``tpos[gidx]`` its
    track's position), the model's default point for an unassigned row."""
    if getattr(model, "fixes_position", True):
        return model.to_cartesian(Z)[0] if Z.shape[0] else EMPTY2
    toward = np.full((Z.shape[0], 2), np.nan)
    if hit.any():
        toward[hit] = tpos[gidx[hit]]
    return model.locus_point(Z, toward)


def labels_shown(pos: np.ndarray, order: np.ndarray, box: tuple[float, float]) -> np.ndarray:
    """``(n,)`` which of the ``(n, 2)`` track positions show their name: taken in ``order``
    (oldest track first), a name is shown unless a shown one lies within ``box`` = (dx, dy)
    (m; a name is wider than high), so that the names of nearby tracks do not overprint.

    The shown names are kept in a grid of ``box``-sized cells, so each test looks at the few
    shown names of the 3 x 3 cells around (linear in ``n``)."""
    n = pos.shape[0]
    shown = np.zeros(n, dtype=bool)
    bx, by = float(box[0]), float(box[1])
    if n == 0 or not (bx > 0.0 and by > 0.0):
        return shown
    xy = pos.tolist()
    cells: dict[tuple[int, int], list[int]] = {}
    for i in np.asarray(order).tolist():
        x, y = xy[i]
        cx, cy = math.floor(x / bx), math.floor(y / by)
        near = any(abs(x - xy[j][0]) < bx and abs(y - xy[j][1]) < by
                   for ax in (cx - 1, cx, cx + 1) for ay in (cy - 1, cy, cy + 1) for j in cells.get((ax, ay), ()))
        if not near:
            shown[i] = True
            cells.setdefault((cx, cy), []).append(i)
    return shown


def hits_per_row(hit: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Number of ``hit`` entries in each row, the rows being the next ``counts[i]`` entries."""
    if hit.shape[0]:
        per = np.add.reduceat(hit, np.concatenate([[0], np.cumsum(counts)[:-1]]))
    else:
        per = np.zeros(len(counts), dtype=np.int64)
    return np.where(counts > 0, per, 0)


def track_strips(hist: np.ndarray, P: np.ndarray, cov: np.ndarray, ks: np.ndarray, clears: Iterable[int],
                 trail: int, circle: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two line strips per row of one track, [trail, ellipse]: its ``(W, 2)`` positions ``P``
    and ``(W, 2, 2)`` covariances at frames ``ks``, after the positions ``hist`` logged before.

    The trail of row ``i`` is its last ``trail`` positions, none from before a clear (a label
    that ended at frame ``c`` in ``clears`` and came back starts a new trail); the ellipse is
    the ``ELLIPSE_SIGMA``-sigma ellipse.  Returns the strips' points, their lengths and the
    history to keep for the next rows (the last ``trail - 1`` positions since the last clear).
    """
    H, W = hist.shape[0], P.shape[0]
    full = np.concatenate([hist, P]) if H else P
    ends = H + np.arange(W) + 1
    starts = np.maximum(ends - trail, 0)
    lo = 0
    for c in sorted(clears):
        first = int(np.searchsorted(ks, c))  # first row at or after the clear
        lo = H + first
        starts[first:] = np.maximum(starts[first:], lo)
    ell = ellipses(P, cov, circle, ELLIPSE_SIGMA).reshape(-1, 2)
    # two strips per row, [trail, ellipse], gathered from concat(full, ell)
    Le = circle.shape[0]
    base = full.shape[0]
    st = np.empty(2 * W, dtype=np.int64)
    en = np.empty(2 * W, dtype=np.int64)
    st[0::2], en[0::2] = starts, ends
    st[1::2] = base + np.arange(W) * Le
    en[1::2] = st[1::2] + Le
    pts, lengths = gather(np.concatenate([full, ell]), st, en)
    keep = trail - 1
    return pts, lengths, (full[max(base - keep, lo):] if keep else EMPTY2)


def truth_trails(rows: Sequence[tuple[Sequence[str], np.ndarray]], history: Mapping[str, np.ndarray],
                 trail: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """One trail strip per true object per row: ``rows`` = (ids, ``(n, 2)`` positions) per
    frame, ``history`` the positions of each object logged before.  Returns the strips' points,
    their lengths and the history to keep (the last ``trail - 1`` positions of the objects of
    the last row)."""
    per: dict[str, list[np.ndarray]] = {}
    for ids, positions in rows:
        for tid, p in zip(ids, positions):
            per.setdefault(tid, []).append(p)
    full: dict[str, np.ndarray] = {}
    seen: dict[str, int] = {}
    base: dict[str, int] = {}
    blocks, off = [], 0
    for tid, ps in per.items():
        hist = history.get(tid, EMPTY2)
        f = np.concatenate([hist, np.array(ps)]) if hist.shape[0] else np.array(ps)
        full[tid], seen[tid], base[tid] = f, hist.shape[0], off
        blocks.append(f)
        off += f.shape[0]
    st, en = [], []
    for ids, _ in rows:
        for tid in ids:
            e = seen[tid] + 1
            seen[tid] = e
            st.append(base[tid] + max(e - trail, 0))
            en.append(base[tid] + e)
    if not blocks:  # frames with truth but no object (a scene that starts empty)
        return EMPTY2, np.zeros(0, dtype=np.int64), {}
    pts, lengths = gather(np.concatenate(blocks), np.array(st, dtype=np.int64), np.array(en, dtype=np.int64))
    keep = trail - 1
    live = set(rows[-1][0])
    kept = {tid: f[max(f.shape[0] - keep, 0):] for tid, f in full.items() if tid in live and keep} if keep else {}
    return pts, lengths, kept


def assignment_index(M: int, assigned: Any, labels: tuple[str, ...]) -> np.ndarray | None:
    """``(M,)`` index into ``labels`` of the track each measurement was assigned to (-1:
    clutter), or ``None`` when the estimate has no assignments for the ``M`` measurements."""
    if not (len(assigned) == M and M):
        return None
    if not labels:
        return np.full(M, -1, dtype=np.int64)
    index = {lab: i for i, lab in enumerate(labels)}
    return np.fromiter((-1 if a is None else index.get(a, -1) for a in assigned), dtype=np.int64, count=M)
