"""The measurement columns of a recording: the points, the measurement -> track lines and, for
kinds whose rows fix no position (range-only), the rings, of the kept frames of one sensor.

Each row is drawn in the world frame through its sensor's measurement model -- the model the
tracker resolved for the frame (:class:`sinks.rerun_sensors.SensorBook`) -- with the model's
own ``to_cartesian`` (or ``locus`` / ``locus_point``): no second copy of the geometry here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from bnptrack.sinks.rerun_columns import Schema
from bnptrack.sinks.rerun_geometry import hits_per_row, measurement_xy
from bnptrack.sinks.rerun_style import (ASSIGNMENTS, CLUTTER_CLASS, GREY_CLUTTER, MEASUREMENTS, R_MEAS_ASSIGNED,
                                        R_MEAS_CLUTTER, RINGS, UNASSIGNED_CLASS, WHITE_UNASSIGNED, pack_rgba)

__all__ = ["measurement_chunks", "Chunk"]

#: (entity path, frames, stamps, [(component, values, rows per frame)]).
Chunk = tuple[str, np.ndarray, np.ndarray, list[tuple[str, pa.Array, np.ndarray]]]

_RING_POINTS = 49


def measurement_chunks(s: Schema, rows: Sequence[Any], model: Any) -> list[Chunk]:
    """The chunks of the kept frames ``rows`` (each with ``k``, ``t``, ``z``, ``idx``, ``pos``,
    ``tcls``, ``tcol``), all of the sensor ``model``: measurements coloured by the track they
    were assigned to (grey: clutter; white: no assignments), lines to those tracks, and the
    rings of a kind that fixes no position."""
    ks = np.array([r.k for r in rows], dtype=np.int64)
    ts = np.array([r.t for r in rows], dtype=np.int64)
    counts = np.array([r.z.shape[0] for r in rows], dtype=np.int64)
    ntr = np.array([r.pos.shape[0] for r in rows], dtype=np.int64)
    Z = np.concatenate([r.z for r in rows])
    tpos = np.concatenate([r.pos for r in rows])
    tcls = np.concatenate([r.tcls for r in rows])
    tcol = np.concatenate([r.tcol for r in rows])
    has = np.repeat(np.array([r.idx is not None for r in rows]), counts)
    idx = np.concatenate([r.idx if r.idx is not None else np.full(r.z.shape[0], -1)
                          for r in rows]).astype(np.int64)
    tr_off = np.concatenate([[0], np.cumsum(ntr)[:-1]])
    hit = idx >= 0
    gidx = np.where(hit, idx + np.repeat(tr_off, counts), 0)
    xy = measurement_xy(model, Z, tpos, gidx, hit)
    cls = np.where(hit, tcls[gidx] if tcls.size else 0,
                   np.where(has, CLUTTER_CLASS, UNASSIGNED_CLASS)).astype(np.uint16)
    col = np.where(hit, tcol[gidx] if tcol.size else 0,
                   np.where(has, pack_rgba(GREY_CLUTTER), pack_rgba(WHITE_UNASSIGNED))).astype(np.uint32)
    radii = np.where(hit, R_MEAS_ASSIGNED, R_MEAS_CLUTTER).astype(np.float32)
    out: list[Chunk] = [(MEASUREMENTS, ks, ts, [
        ("Points2D:positions", s.positions(xy), counts),
        ("Points2D:class_ids", pa.array(cls, type=pa.uint16()), counts),
        ("Points2D:colors", pa.array(col, type=pa.uint32()), counts),
        ("Points2D:radii", pa.array(radii, type=pa.float32()), counts),
    ])]
    nh = int(hit.sum())
    lines = np.empty((nh, 2, 2))
    lines[:, 0] = xy[hit]
    lines[:, 1] = tpos[gidx[hit]] if nh else lines[:, 1]
    per_row = hits_per_row(hit, counts)
    out.append((ASSIGNMENTS, ks, ts, [
        ("LineStrips2D:strips", s.strip_array(lines.reshape(-1, 2), np.full(nh, 2)), per_row),
        ("LineStrips2D:colors", pa.array((col[hit] & np.uint32(0xFFFFFF00)) | np.uint32(150),
                                         type=pa.uint32()), per_row),
        ("LineStrips2D:class_ids", pa.array(cls[hit], type=pa.uint16()), per_row),
    ]))
    if not getattr(model, "fixes_position", True):
        out.append(_rings(s, ks, ts, counts, Z, model, cls, col))
    return out


def _rings(s: Schema, ks: np.ndarray, ts: np.ndarray, counts: np.ndarray, Z: np.ndarray, model: Any,
           cls: np.ndarray, col: np.ndarray) -> Chunk:
    """Rows that fix no position: one arc of each row's locus (the range ring of a range-only
    row) over the sensor's field of view, about its heading."""
    a = model.heading + np.linspace(-model.half_fov, model.half_fov, _RING_POINTS)
    arcs = model.locus(Z, a)
    return (RINGS, ks, ts, [
        ("LineStrips2D:strips", s.strip_array(arcs.reshape(-1, 2), np.full(Z.shape[0], a.size)), counts),
        ("LineStrips2D:colors", pa.array((col & np.uint32(0xFFFFFF00)) | np.uint32(90), type=pa.uint32()), counts),
        ("LineStrips2D:class_ids", pa.array(cls, type=pa.uint16()), counts),
    ])
