"""The cluster structure in a Rerun recording: track colours by motion cluster, the
``world/clusters`` links (their names in ``world/clusters/labels``) and the ``metrics/structure`` series (clusters, posterior cardinality).

Automatic, not an option: a track whose estimate carries a ``cluster`` (the two-level trackers
``ddp`` / ``dpyp``) is drawn, from that frame on, in its cluster's colour (its
measurements and assignment lines too); a track without one keeps its label's colour.  Cluster
colours come from the track palette (:func:`sinks.rerun_style.cluster_color`: never the
truth, sensor, clutter or measurement colours), and clusters alive together differ from each
other and from the unclustered tracks of the frame.  A cluster keeps its colour while it has
reported members.  Does not import rerun (the sink sends what is built here).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from bnptrack.sinks.rerun_style import CARD_POSTERIOR, CLUSTER_COUNT, cluster_color, pack_rgba, unpack_rgba
from bnptrack.tracker.cardinality import pmf_map, pmf_mean

__all__ = ["ClusterColours", "track_clusters", "cluster_columns", "from_first_cluster", "structure_rows"]


def track_clusters(tracks: Sequence[Any]) -> np.ndarray:
    """``(n,)`` int64 cluster id of each track (``-1``: none)."""
    return np.fromiter((-1 if t.cluster is None else int(t.cluster) for t in tracks), dtype=np.int64,
                       count=len(tracks))


class ClusterColours:
    """The colour of each cluster alive (packed RGBA), kept while the cluster has members."""

    def __init__(self) -> None:
        self._of: dict[int, int] = {}
        self.seen = False
        """Whether any frame so far had a track with a cluster."""

    def frame_colours(self, clusters: np.ndarray, label_cols: np.ndarray) -> np.ndarray:
        """``(n,)`` packed colours of a frame's tracks: the cluster's colour where ``clusters``
        (``(n,)``, -1: none) names one, else ``label_cols``."""
        has = clusters >= 0
        if not has.any():
            self._of = {}
            return label_cols
        self.seen = True
        live = set(clusters[has].tolist())
        of = {c: v for c, v in self._of.items() if c in live}
        taken = [unpack_rgba(v) for v in of.values()] + [unpack_rgba(int(v)) for v in label_cols[~has]]
        for c in sorted(live - of.keys()):
            rgba = cluster_color(c, taken)
            taken.append(rgba)
            of[c] = pack_rgba(rgba)
        self._of = of
        cols = np.fromiter((of.get(c, 0) for c in clusters.tolist()), dtype=np.uint32, count=clusters.size)
        return np.where(has, cols, label_cols).astype(np.uint32)


def _frame_links(pos: np.ndarray, cl: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, ...]:
    """One frame's clusters with two or more members: centroids ``(c, 2)``, their ids, sizes and
    colours, the links ``(l, 2, 2)`` centroid -> member with their colours, and the highest
    member's y of each cluster."""
    m = cl >= 0
    ids, inv, cnt = np.unique(cl[m], return_inverse=True, return_counts=True)
    cent = np.zeros((ids.size, 2))
    np.add.at(cent, inv, pos[m])
    cent /= np.maximum(cnt, 1)[:, None]
    top = np.full(ids.size, -np.inf)
    np.maximum.at(top, inv, pos[m][:, 1])
    ccol = np.zeros(ids.size, dtype=np.uint32)
    ccol[inv] = col[m]
    big = cnt >= 2
    keep = big[inv]
    links = np.stack([cent[inv[keep]], pos[m][keep]], axis=1) if keep.any() else np.zeros((0, 2, 2))
    return cent[big], ids[big], cnt[big], ccol[big], links, col[m][keep], top[big]


def from_first_cluster(rows: Sequence[Any]) -> list:
    """``rows`` (each with ``ccl``, its tracks' cluster ids, -1: none) from the first one with a
    cluster on; empty if none has one."""
    first = next((i for i, r in enumerate(rows) if (np.asarray(r.ccl) >= 0).any()), len(rows))
    return list(rows[first:])


def cluster_columns(schema: Any, rows: Sequence[Any], lift: float) -> tuple[list, list, list]:
    """The ``world/clusters`` columns of the kept frames ``rows`` (each with ``pos``, ``ccl``
    and ``tcol``): Points2D (centroid, colour) and LineStrips2D (links); and the
    ``world/clusters/labels`` Points2D: each cluster's name ``C<id> (n)`` on a point ``lift``
    metres above its highest member, over the centroid (a label is drawn under its point, so
    it sits above the members, clear of their own names, which are drawn under them).  A frame
    without such a cluster gets empty rows (the previous frame's do not linger)."""
    parts = [_frame_links(r.pos, r.ccl, r.tcol) for r in rows]
    n_c = np.array([p[0].shape[0] for p in parts], dtype=np.int64)
    n_l = np.array([p[4].shape[0] for p in parts], dtype=np.int64)
    cent = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 2))
    top = np.concatenate([p[6] for p in parts]) if parts else np.zeros(0)
    labels = [f"C{i} ({n})" for p in parts for i, n in zip(p[1].tolist(), p[2].tolist())]
    links = np.concatenate([p[4] for p in parts]).reshape(-1, 2)
    lcol = np.concatenate([p[5] for p in parts]).astype(np.uint32)
    ccol = pa.array(np.concatenate([p[3] for p in parts]) if parts else np.zeros(0, np.uint32), type=pa.uint32())
    points = [("Points2D:positions", schema.positions(cent), n_c), ("Points2D:colors", ccol, n_c)]
    strips = [("LineStrips2D:strips", schema.strip_array(links, np.full(int(n_l.sum()), 2)), n_l),
              ("LineStrips2D:colors", pa.array((lcol & np.uint32(0xFFFFFF00)) | np.uint32(200), type=pa.uint32()),
               n_l)]
    names = [("Points2D:positions", schema.positions(np.stack([cent[:, 0], top + lift], axis=-1)), n_c),
             ("Points2D:labels", pa.array(labels, type=pa.string()), n_c), ("Points2D:colors", ccol, n_c)]
    return points, strips, names


def structure_rows(estimate: Any, clusters: np.ndarray, seen: bool) -> list[tuple[str, list[float]]]:
    """The frame's ``metrics/structure`` scalars: ``[mean, MAP]`` of its ``cardinality_pmf``
    (when it has one) and, once a cluster has been seen, the number of distinct clusters of the
    reported tracks."""
    out: list[tuple[str, list[float]]] = []
    pmf = getattr(estimate, "cardinality_pmf", None)
    if pmf is not None:
        out.append((CARD_POSTERIOR, [pmf_mean(pmf), float(pmf_map(pmf))]))
    if seen:
        out.append((CLUSTER_COUNT, [float(np.unique(clusters[clusters >= 0]).size)]))
    return out
