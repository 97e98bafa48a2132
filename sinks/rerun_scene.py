"""The static content of a recording (written at the start): the run's metadata, the metric grid
with its axes and tick labels, the legend and the fixed styles of the measurements, assignments
and truth (grid and legend are written again when the scene grows); and the sensors, each drawn
at its pose (:func:`log_sensor`, from the frame it is first seen at, again when it moves)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import rerun as rr

from bnptrack.sinks.rerun_columns import entity_part
from bnptrack.sinks.rerun_geometry import SceneGeometry, nice_step
from bnptrack.sinks.rerun_sensors import fov_outline, sensor_title
from bnptrack.sinks.rerun_style import (ASSIGNMENTS, AXES, ELLIPSE_SIGMA, GREY_CLUTTER, GREY_TRUTH, GREY_TRUTH_TRAIL, GRID,
                               GRID_TICKS, LEGEND, MEASUREMENTS, METADATA, PALETTE, R_ASSIGN_LINE, R_ELLIPSE,
                               R_MEAS_ASSIGNED, R_MEAS_CLUTTER, R_TRACK, R_TRAIL, R_TRUTH_CROSS, R_TRUTH_TRAIL,
                               SENSORS, TRUTH, TRUTH_TRAILS, WHITE_UNASSIGNED, WORLD)
from bnptrack.tracker.models.sensors import Sensor

__all__ = ["write_static", "log_grid", "log_legend", "log_sensor", "view_bounds"]


def write_static(rec: rr.RecordingStream, scene: SceneGeometry, metadata: dict[str, str], trail: int) -> None:
    """The static content of a recording: run metadata (document and recording property), the
    y-up transform, the grid, the legend and the styles of the measurements, assignments and
    truth."""
    meta = {str(k): str(v) for k, v in metadata.items()}
    meta.setdefault("bnptrack_version", _version("bnptrack"))
    meta.setdefault("rerun_version", rr.__version__)
    name = " ".join(meta[k] for k in ("scenario", "tracker") if k in meta)
    if "seed" in meta:
        name += f" seed {meta['seed']}"
    rec.send_recording_name(name.strip() or "bnptrack run")
    rec.send_property("bnptrack", rr.AnyValues(**{_ident(k): v for k, v in meta.items()}))
    rows = "\n".join(f"| {k} | {_md(v)} |" for k, v in meta.items())
    rec.log(METADATA, rr.TextDocument(
        "# bnptrack run\n\n| key | value |\n| --- | --- |\n" + rows + "\n\n"
        "Scene: x east, y north (m), each sensor at its pose with its field of view, grid lines every "
        f"{nice_step((scene.bounds[1] - scene.bounds[0]) / 8):g} m; the legend is above the scene. "
        "Tracks: dot + name (T<birth frame>.<index>, as in the summary and the export; a name "
        "beside an older track's is hidden), trail of the "
        f"last {trail} positions, {ELLIPSE_SIGMA:g}-sigma position ellipse. Measurements "
        "take the colour of the track they were assigned to; grey dots are clutter; thin lines "
        "join a measurement to its track. Grey crosses and thin trails: ground truth.",
        media_type=rr.MediaType.MARKDOWN), static=True)
    rec.log(WORLD, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)  # draw +y up
    log_grid(rec, scene.bounds)
    log_legend(rec, scene, ())
    # styles that do not change from frame to frame
    rec.log(MEASUREMENTS, rr.Points2D.from_fields(show_labels=False, draw_order=3.0), static=True)
    rec.log(ASSIGNMENTS, rr.LineStrips2D.from_fields(radii=[R_ASSIGN_LINE], show_labels=False,
                                                     draw_order=2.0), static=True)
    rec.log(TRUTH, rr.LineStrips2D.from_fields(radii=[R_TRUTH_CROSS], colors=[GREY_TRUTH],
                                               show_labels=False, draw_order=1.0), static=True)
    rec.log(TRUTH_TRAILS, rr.LineStrips2D.from_fields(
        radii=[R_TRUTH_TRAIL], colors=[GREY_TRUTH_TRAIL], show_labels=False, draw_order=0.9),
        static=True)


def log_grid(rec: rr.RecordingStream, bounds: tuple[float, float, float, float]) -> None:
    """Static metric grid (round steps, about 8 across the field of view), the x and y axes
    through the sensor, and tick labels in metres along the bottom and left edges."""
    x0, x1, y0, y1 = bounds
    step = nice_step((x1 - x0) / 8)
    xs = np.arange(math.ceil(x0 / step), math.floor(x1 / step) + 1) * step
    ys = np.arange(math.ceil(y0 / step), math.floor(y1 / step) + 1) * step
    lines = [[[x, y0], [x, y1]] for x in xs] + [[[x0, y], [x1, y]] for y in ys]
    rec.log(GRID, rr.LineStrips2D(lines, radii=-0.5, colors=[(70, 70, 70, 110)], draw_order=0.0),
            static=True)
    rec.log(AXES, rr.LineStrips2D([[[x0, 0.0], [x1, 0.0]], [[0.0, y0], [0.0, y1]]], radii=-0.8,
                                  colors=[(135, 135, 135, 200)], show_labels=False, draw_order=0.05),
            rr.Points2D([[x1 - 0.07 * (x1 - x0), y0 - 0.1 * (y1 - y0)], [0.0, y1 + 0.02 * (y1 - y0)]],
                        radii=-1.0,
                        colors=[(135, 135, 135, 255)], labels=["x east (m)", "y north (m)"],
                        show_labels=True, draw_order=0.05), static=True)
    inset = 0.025 * (x1 - x0)  # tick labels are centred on their point: keep them in view
    ticks = [[x, y0] for x in xs] + [[x0 + inset, y] for y in ys if y > y0 + 0.5 * step]
    labels = [f"{x:g}" for x in xs] + [f"{y:g}" for y in ys if y > y0 + 0.5 * step]
    rec.log(GRID_TICKS, rr.Points2D(ticks, radii=-1.0, colors=[(135, 135, 135, 255)], labels=labels,
                                    show_labels=True, draw_order=0.05), static=True)


def log_sensor(rec: rr.RecordingStream, sensor: Sensor, colour: tuple[int, int, int, int]) -> None:
    """The sensor at its pose (at the stream's present time): ``world/sensors/<name>``, a dot
    labelled with its name and the outline of its field of view, in its own colour."""
    rec.log(f"{SENSORS}/{entity_part(sensor_title(sensor))}",
            rr.Points2D([[sensor.x, sensor.y]], radii=-6.0, colors=[colour], labels=[sensor_title(sensor)],
                        show_labels=True),
            rr.LineStrips2D([fov_outline(sensor)], radii=-0.75, colors=[(*colour[:3], 150)], draw_order=0.1))


_LEGEND_ROWS = 3
_ROW = 0.07  # legend row height, a fraction of the scene's height


def view_bounds(bounds: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """The box the view opens on: the scene ``bounds`` and, above them, the legend's band."""
    x0, x1, y0, y1 = bounds
    return x0, x1, y0, y1 + (_LEGEND_ROWS + 0.5) * _ROW * (y1 - y0)


def log_legend(rec: rr.RecordingStream, scene: SceneGeometry,
               sensors: Sequence[tuple[Sensor, tuple[int, int, int, int]]],
               track: tuple[tuple[int, int, int], str] | None = None) -> None:
    """Static legend in a band above the scene (:func:`view_bounds`), one entity per symbol:
    ``world/legend/<what>``, the symbol drawn as in the scene with its meaning as label; in
    the middle column ``world/legend/sensors``, one dot per sensor in its colour.  ``track``:
    the colour and name of the first track, drawn as the track symbols' example (before it, a
    palette colour and no name)."""
    x0, x1, y0, y1 = scene.bounds
    w, h = x1 - x0, y1 - y0
    dy = _ROW * h
    left, mid, right = x0 + 0.15 * w, x0 + 0.5 * w, x1 - 0.15 * w
    top = y1 + _LEGEND_ROWS * dy
    track_rgb, name = track if track is not None else (PALETTE[2], "")

    def at(col: float, row: float) -> np.ndarray:
        return np.array([col, top - row * dy])

    rec.log(f"{LEGEND}/measurement", rr.Points2D([at(left, 0)], radii=R_MEAS_ASSIGNED, colors=[WHITE_UNASSIGNED],
                                                 labels=["measurement"], show_labels=True), static=True)
    rec.log(f"{LEGEND}/clutter", rr.Points2D([at(left, 1)], radii=R_MEAS_CLUTTER, colors=[GREY_CLUTTER],
                                             labels=["clutter (no track)"], show_labels=True), static=True)
    p, q = at(left, 2), at(left, 2) + (0.04 * w, 0.0)
    rec.log(f"{LEGEND}/assigned", rr.Points2D([p], radii=R_MEAS_ASSIGNED, colors=[track_rgb],
                                              labels=["assigned measurement (track colour)"], show_labels=True),
            rr.LineStrips2D([[p, q]], radii=R_ASSIGN_LINE, colors=[(*track_rgb, 150)]), static=True)
    c, hx = at(right, 0), scene.cross
    rec.log(f"{LEGEND}/truth", rr.LineStrips2D(
        [[c - (hx, hx), c + (hx, hx)], [c + (-hx, hx), c + (hx, -hx)]], radii=R_TRUTH_CROSS,
        colors=[GREY_TRUTH], labels=["truth", ""], show_labels=True), static=True)
    c = at(right, 1)
    trail = c + np.stack([np.linspace(-0.06 * w, 0.0, 6), 0.01 * w * np.sin(np.linspace(0, 3, 6))], -1)
    rec.log(f"{LEGEND}/track", rr.Points2D([c], radii=R_TRACK, colors=[track_rgb],
                                           labels=[f"track {name} + trail".replace("  ", " ")], show_labels=True),
            rr.LineStrips2D([trail], radii=R_TRAIL, colors=[track_rgb]), static=True)
    c = at(right, 2)
    ell = c + scene.circle * (0.03 * w, 0.012 * h)
    rec.log(f"{LEGEND}/ellipse", rr.LineStrips2D([ell], radii=R_ELLIPSE, colors=[(*track_rgb, 170)],
                                                 labels=[f"{ELLIPSE_SIGMA:g}-sigma ellipse"], show_labels=True),
            static=True)
    if sensors:
        step = min(1.0, (_LEGEND_ROWS - 1) / max(len(sensors) - 1, 1))
        rec.log(f"{LEGEND}/sensors", rr.Points2D(
            [at(mid, i * step) for i in range(len(sensors))], radii=-6.0, colors=[c for _s, c in sensors],
            labels=[f"sensor {sensor_title(s)} ({s.kind})" for s, _c in sensors], show_labels=True), static=True)


def _ident(key: str) -> str:
    out = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in key)
    return out if out and not out[0].isdigit() else f"k_{out}"


def _md(value: str) -> str:
    return value.replace("|", "\\|").replace("\n", " ")


def _version(dist: str) -> str:
    try:
        from importlib.metadata import version

        return version(dist)
    except Exception:  # pragma: no cover - not installed
        return "unknown"
