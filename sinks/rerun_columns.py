"""Rerun components as ready Arrow arrays: the sink builds its columns with numpy and sends them
without the archetype constructors' per-call Python cost (:class:`Schema`, :func:`send`,
:func:`log_arrays`), and escapes entity-path parts (:func:`entity_part`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr

from bnptrack.sinks.rerun_style import R_CLUSTER_CENTRE, R_CLUSTER_LABEL, R_CLUSTER_LINK, R_ELLIPSE, R_TRACK, R_TRAIL

__all__ = ["Batch", "Schema", "send", "log_arrays", "entity_part", "track_style", "track_colours", "cluster_style", "cluster_label_style",
           "annotation_context", "scalar_columns"]


class Batch:
    """A ready Arrow array with its component descriptor (``rerun.ComponentBatchLike``)."""

    __slots__ = ("_descr", "_array")

    def __init__(self, descr: Any, array: pa.Array) -> None:
        self._descr, self._array = descr, array

    def component_descriptor(self) -> Any:
        return self._descr

    def as_arrow_array(self) -> pa.Array:
        return self._array


class Schema:
    """Component descriptors and Arrow types of the components this module writes as arrays.

    Taken once from real archetype objects (``rr.Points2D``, ``rr.LineStrips2D``, ``rr.Scalars``,
    ``rr.Clear``, ``rr.TextLog``, ``rr.AnnotationContext``), so the arrays built here from numpy
    carry exactly the descriptors and Arrow types the SDK's constructors would give them, without
    their per-call Python cost.  The tests read every component back and compare the values.
    """

    def __init__(self) -> None:
        protos = {
        "Points2D": rr.Points2D(
                [[0.0, 0.0]], radii=[1.0], colors=[0], labels=["a"], class_ids=[1],
                show_labels=True, draw_order=1.0,
            ),
        "LineStrips2D": rr.LineStrips2D(
                [[[0.0, 0.0], [1.0, 1.0]]], radii=[1.0], colors=[0], labels=["a"],
                class_ids=[1], show_labels=True, draw_order=1.0,
            ),
            "Scalars": rr.Scalars([1.0]),
            "Clear": rr.Clear(recursive=True),
            "TextLog": rr.TextLog("a", level="INFO"),
            "AnnotationContext": rr.AnnotationContext(
                [rr.AnnotationInfo(id=1, label="a", color=(1, 2, 3, 255))]),
        }
        self.d: dict[str, Any] = {}
        self.t: dict[str, pa.DataType] = {}
        for arch, proto in protos.items():
            for batch in proto.as_component_batches():
                descr = batch.component_descriptor()
                key = f"{arch}:{str(descr).split(':', 1)[1]}"
                self.d[key] = descr
                self.t[key] = batch.as_arrow_array().type
        self.vec2 = self.t["Points2D:positions"]
        self.strip = self.t["LineStrips2D:strips"]

    def positions(self, xy: np.ndarray) -> pa.Array:
        flat = np.ascontiguousarray(xy, dtype=np.float32).reshape(-1)
        return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float32()), type=self.vec2)

    def strip_array(self, points: np.ndarray, lengths: np.ndarray) -> pa.Array:
        """LineStrip2D array: strip ``i`` is the next ``lengths[i]`` rows of ``points``."""
        offsets = np.zeros(len(lengths) + 1, dtype=np.int32)
        np.cumsum(lengths, out=offsets[1:])
        return pa.ListArray.from_arrays(pa.array(offsets, type=pa.int32()), self.positions(points),
                                        type=self.strip)


def send(rec: rr.RecordingStream, schema: Schema, path: str, ks: np.ndarray, ts: np.ndarray,
         comps: list[tuple[str, pa.Array, np.ndarray]]) -> None:
    """One chunk: rows at frames ``ks`` / stamps ``ts``; ``comps`` = (key, flat array,
    per-row instance counts)."""
    offs = []
    for _key, _arr, counts in comps:
        o = np.zeros(len(counts) + 1, dtype=np.int32)
        np.cumsum(counts, out=o[1:])
        offs.append(o)
    ks = np.asarray(ks, dtype=np.int64)
    stamps = np.asarray(ts, dtype=np.int64).astype("datetime64[ns]")
    cols = [rr.ComponentColumn(schema.d[key], Batch(schema.d[key], arr), offsets=o)
            for (key, arr, _c), o in zip(comps, offs)]
    rec.send_columns(
        path,
        indexes=[rr.TimeColumn("frame", sequence=ks), rr.TimeColumn("stamp", timestamp=stamps)],
        columns=cols,
        strict=True,
    )


def log_arrays(rec: rr.RecordingStream, schema: Schema, path: str, comps: dict[str, pa.Array],
               static: bool = False) -> None:
    """``rr.log`` of ready Arrow arrays (one row), skipping the archetype constructors."""
    d = schema.d
    rec.log(path, [Batch(d[k], arr) for k, arr in comps.items()], static=static, strict=True)


def entity_part(part: str) -> str:
    """One entity-path part (labels like ``10.3`` are fine; escape anything unusual)."""
    if part and all(ch.isalnum() or ch in "._-" for ch in part):
        return part
    return rr.escape_entity_path_part(part)


def track_style(name: str) -> dict[str, pa.Array]:
    """The static style of a track's entity: display name, sizes and draw order.  Its colours are
    temporal (:func:`track_colours`): a track of a two-level tracker takes its cluster's colour,
    which changes with the cluster (a static colour would shadow them); so is whether its name
    shows (``Points2D:show_labels``: hidden beside an older track's,
    :func:`sinks.rerun_geometry.labels_shown`)."""
    return {
        "Points2D:labels": pa.array([name], type=pa.string()),
        "Points2D:radii": pa.array([R_TRACK], type=pa.float32()),
        "Points2D:draw_order": pa.array([5.0], type=pa.float32()),
        "LineStrips2D:radii": pa.array([R_TRAIL, R_ELLIPSE], type=pa.float32()),
        "LineStrips2D:show_labels": pa.array([False], type=pa.bool_()),
        "LineStrips2D:draw_order": pa.array([4.0], type=pa.float32()),
    }


def track_colours(packed: np.ndarray) -> list[tuple[str, pa.Array, np.ndarray]]:
    """The colour columns of a track's rows (``packed`` (W,) RGBA, one per frame): the point's
    and the trail's, and the ellipse's a little transparent."""
    packed = np.asarray(packed, dtype=np.uint32)
    strips = np.stack([packed, (packed & np.uint32(0xFFFFFF00)) | np.uint32(170)], axis=1).reshape(-1)
    W = packed.size
    return [("Points2D:colors", pa.array(packed, type=pa.uint32()), np.ones(W, dtype=np.int64)),
            ("LineStrips2D:colors", pa.array(strips, type=pa.uint32()), np.full(W, 2))]


def cluster_style() -> dict[str, pa.Array]:
    """The static style of ``world/clusters``: centroid size (no label: the names are
    ``world/clusters/labels``), thin links, drawn under the tracks."""
    return {
        "Points2D:radii": pa.array([R_CLUSTER_CENTRE], type=pa.float32()),
        "Points2D:show_labels": pa.array([False], type=pa.bool_()),
        "Points2D:draw_order": pa.array([3.0], type=pa.float32()),
        "LineStrips2D:radii": pa.array([R_CLUSTER_LINK], type=pa.float32()),
        "LineStrips2D:show_labels": pa.array([False], type=pa.bool_()),
        "LineStrips2D:draw_order": pa.array([3.0], type=pa.float32()),
    }


def cluster_label_style() -> dict[str, pa.Array]:
    """The static style of ``world/clusters/labels``: a small point, its label shown."""
    return {
        "Points2D:radii": pa.array([R_CLUSTER_LABEL], type=pa.float32()),
        "Points2D:show_labels": pa.array([True], type=pa.bool_()),
        "Points2D:draw_order": pa.array([3.0], type=pa.float32()),
    }


def annotation_context(schema: Schema, classes: list[tuple[int, str, int]]) -> dict[str, pa.Array]:
    """The ``AnnotationContext`` of ``classes`` = (class id, label, packed RGBA colour)."""
    rows = [{"class_id": i, "class_description": {
                "info": {"id": i, "label": name, "color": color},
                "keypoint_annotations": [], "keypoint_connections": []}}
            for i, name, color in classes]
    return {"AnnotationContext:context": pa.array([rows], type=schema.t["AnnotationContext:context"])}


def scalar_columns(rows: list[tuple[int, int, list[float]]]) -> tuple[np.ndarray, np.ndarray, list[Any]]:
    """(frames, stamps, components) of a ``Scalars`` column from rows (frame, stamp, values)."""
    ks = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    ts = np.fromiter((r[1] for r in rows), dtype=np.int64, count=len(rows))
    vals = [r[2] for r in rows]
    flat = pa.array([v for row in vals for v in row], type=pa.float64())
    return ks, ts, [("Scalars:scalars", flat, np.array([len(v) for v in vals]))]
