"""The columnar half of :class:`sinks.rerun_sink.RerunSink`: the frames :meth:`RerunSink.log`
keeps (:class:`KeptFrame`), turned at each flush into one Arrow chunk per entity (tracks and
their trails, measurements, truth, motion clusters, the time series) and sent with
``RecordingStream.send_columns``.

:class:`ChunkSender` is a base class of :class:`~sinks.rerun_sink.RerunSink` and works on its
state: the stream ``_rec`` and schema ``_s``, the kept ``_frames`` / ``_scalars`` / ``_clears``,
the trails' ``_history`` / ``_truth_history``, the live labels ``_live``, ``_styled``,
``trail`` and the scene geometry ``_geo``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa
import rerun as rr

from bnptrack.sinks.rerun_clusters import cluster_columns, from_first_cluster
from bnptrack.sinks.rerun_columns import cluster_label_style, cluster_style, scalar_columns, send, track_colours
from bnptrack.sinks.rerun_geometry import EMPTY2, track_strips, truth_crosses, truth_trails
from bnptrack.sinks.rerun_measurements import measurement_chunks
from bnptrack.sinks.rerun_style import CLUSTER_LABEL_LIFT, CLUSTER_LABELS, CLUSTERS, R_RING, RINGS, TRUTH, TRUTH_TRAILS


__all__ = ["ChunkSender", "KeptFrame"]


class KeptFrame(NamedTuple):
    """What :meth:`RerunSink.log` keeps of one frame until the next flush."""

    k: int
    t: int
    labels: tuple[str, ...]
    pos: np.ndarray  # (n, 2) track positions
    cov: np.ndarray  # (n, 2, 2) position covariances
    tcls: np.ndarray  # (n,) class ids of the tracks
    tcol: np.ndarray  # (n,) packed colours of the tracks (their cluster's, else their label's)
    ccl: np.ndarray  # (n,) motion cluster of the tracks (-1: none)
    shown: np.ndarray  # (n,) whether the track's name shows (not beside an older track's)
    model: Any  # the frame's measurement model (its sensor's, as the tracker resolved it)
    z: np.ndarray  # (M, d) measurements
    idx: np.ndarray | None  # (M,) index of the assigned track, -1 clutter; None: no assignments
    truth_ids: tuple[str, ...] | None
    truth_pos: np.ndarray | None


class ChunkSender:
    """Send :class:`~sinks.rerun_sink.RerunSink`'s kept frames as columns (see the module docstring)."""

    def _send(self, path: str, ks: np.ndarray, ts: np.ndarray,
              comps: list[tuple[str, pa.Array, np.ndarray]]) -> None:
        send(self._rec, self._s, path, ks, ts, comps)

    def _send_kept(self) -> None:
        """Turn the kept frames into one chunk per entity and send them."""
        frames, self._frames = self._frames, []
        scalars, self._scalars = self._scalars, {}
        clears, self._clears = self._clears, []
        if frames:
            self._send_tracks(frames, clears)
            self._send_measurements(frames)
            self._send_truth(frames)
            self._send_clusters(frames)
        for entity, rows in scalars.items():
            self._send(entity, *scalar_columns(rows))
        for path, k, t in clears:
            self._send(path, np.array([k]), np.array([t]),
                       [("Clear:is_recursive", pa.array([True], type=pa.bool_()), np.array([1]))])

    def _send_tracks(self, frames: list[KeptFrame], clears: list[tuple[str, int, int]]) -> None:
        s = self._s
        # group the kept frames by label, in order
        per: dict[str, tuple[list[Any], ...]] = {}
        for r in frames:
            for i, lab in enumerate(r.labels):
                g = per.get(lab)
                if g is None:
                    g = per[lab] = ([], [], [], [], [], [])
                g[0].append(r.k)
                g[1].append(r.t)
                g[2].append(r.pos[i])
                g[3].append(r.cov[i])
                g[4].append(r.tcol[i])
                g[5].append(r.shown[i])
        # a label that ended (Clear) and came back starts a new trail after the clear
        cleared: dict[str, list[int]] = {}
        for path, k, _t in clears:
            cleared.setdefault(path, []).append(k)
        for lab, (ks, ts, ps, cs, cols, shows) in per.items():
            path = self._track_path(lab)
            P = np.array(ps)
            kk = np.asarray(ks, dtype=np.int64)
            pts, lengths, self._history[lab] = track_strips(
                self._history.get(lab, EMPTY2), P, np.array(cs), kk, cleared.get(path, ()), self.trail,
                self._geo.circle)
            W = P.shape[0]
            self._send(path, kk, np.asarray(ts), [
                ("Points2D:positions", s.positions(P), np.ones(W, dtype=np.int64)),
                ("LineStrips2D:strips", s.strip_array(pts, lengths), np.full(W, 2)),
                *track_colours(np.array(cols, dtype=np.uint32)),
                ("Points2D:show_labels", pa.array(np.array(shows, dtype=bool)), np.ones(W, dtype=np.int64)),
            ])
        for lab in [lab for lab in self._history if lab not in self._live]:
            del self._history[lab]

    def _send_clusters(self, frames: list[KeptFrame]) -> None:
        """``world/clusters`` of the kept frames from the first one with a motion cluster (however batched)."""
        if CLUSTERS not in self._styled:
            if not (frames := from_first_cluster(frames)):
                return
            self._log_arrays(CLUSTERS, cluster_style(), static=True)
            self._log_arrays(CLUSTER_LABELS, cluster_label_style(), static=True)
            self._styled.add(CLUSTERS)
        ks, ts = np.array([(r.k, r.t) for r in frames], dtype=np.int64).T
        points, strips, names = cluster_columns(self._s, frames, CLUSTER_LABEL_LIFT * self._geo.cross)
        for entity, comps in ((CLUSTERS, points), (CLUSTERS, strips), (CLUSTER_LABELS, names)):
            self._send(entity, ks, ts, comps)

    def _send_measurements(self, frames: list[KeptFrame]) -> None:
        """Measurements, measurement->track lines and (range-only) rings of all kept frames,
        per sensor model (:mod:`sinks.rerun_measurements`)."""
        for model in dict.fromkeys(r.model for r in frames):
            for entity, ks, ts, comps in measurement_chunks(self._s, [r for r in frames if r.model == model], model):
                if entity == RINGS and RINGS not in self._styled:
                    self._rec.log(RINGS, rr.LineStrips2D.from_fields(
                        radii=[R_RING], show_labels=False, draw_order=0.5), static=True)
                    self._styled.add(RINGS)
                self._send(entity, ks, ts, comps)

    def _send_truth(self, frames: list[KeptFrame]) -> None:
        """Grey crosses and trails of the true objects of the kept frames that have truth."""
        s = self._s
        rows = [r for r in frames if r.truth_ids is not None]
        if not rows:
            return
        ks = np.array([r.k for r in rows], dtype=np.int64)
        ts = np.array([r.t for r in rows], dtype=np.int64)
        counts = np.array([len(r.truth_ids) for r in rows], dtype=np.int64)
        TP = np.concatenate([r.truth_pos for r in rows])
        n = TP.shape[0]
        cross = truth_crosses(TP, self._geo.cross)
        labels = pa.array([f"truth {tid}" for r in rows for tid in r.truth_ids for _ in (0, 1)],
                          type=pa.string())
        self._send(TRUTH, ks, ts, [
            ("LineStrips2D:strips", s.strip_array(cross.reshape(-1, 2), np.full(2 * n, 2)), 2 * counts),
            ("LineStrips2D:labels", labels, 2 * counts),
        ])
        pts, lengths, self._truth_history = truth_trails(
            [(r.truth_ids, r.truth_pos) for r in rows], self._truth_history, self.trail)
        self._send(TRUTH_TRAILS, ks, ts, [("LineStrips2D:strips", s.strip_array(pts, lengths), counts)])
