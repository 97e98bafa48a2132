"""The static content of a recording (written at the start): the run's metadata, the metric grid
with its axes and tick labels, the legend and the fixed styles of the measurements, assignments
and truth (grid and legend are written again when the scene grows); and the sensors, each drawn
at its pose (:func:`log_sensor`, from the frame it is first seen at, again when it moves)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

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

__all__ = ["write_static", "log_grid", "log_legend", "log_sensor", "view_bounds", "SceneLayout"]


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
    """Static metric grid over the :class:`SceneLayout` of ``bounds`` (round steps, about 8
    across), the x and y axes through the origin where it lies on the grid, and in the margins
    of the view the tick labels in metres (along the bottom and left edges) and the axis titles
    ("x east (m)" bottom right, "y north (m)" top left)."""
    lay = SceneLayout.of(bounds)
    x0, x1, y0, y1 = lay.grid
    step = nice_step((x1 - x0) / 8)
    xs = np.arange(math.ceil(x0 / step), math.floor(x1 / step) + 1) * step
    ys = np.arange(math.ceil(y0 / step), math.floor(y1 / step) + 1) * step
    lines = [[[x, y0], [x, y1]] for x in xs] + [[[x0, y], [x1, y]] for y in ys]
    rec.log(GRID, rr.LineStrips2D(lines, radii=-0.5, colors=[(70, 70, 70, 110)], draw_order=0.0),
            static=True)
    axes = ([[[x0, 0.0], [x1, 0.0]]] if y0 <= 0.0 <= y1 else []) + ([[[0.0, y0], [0.0, y1]]] if x0 <= 0.0 <= x1 else [])
    rec.log(AXES, rr.LineStrips2D(axes, radii=-0.8, colors=[(135, 135, 135, 200)], show_labels=False,
                                  draw_order=0.05),
            rr.Points2D(lay.titles(), radii=-1.0, colors=[(135, 135, 135, 255)], labels=["x east (m)", "y north (m)"],
                        show_labels=True, draw_order=0.05), static=True)
    ticks, labels = lay.ticks(xs, ys)
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


@dataclass(frozen=True)
class SceneLayout:
    """Where the scene's parts go in its view: ``view``, the box the view opens on, is about
    as wide for its height as the scene panel of the default layout (:data:`ASPECT`), so that
    its edges are the panel's whatever the scene's own shape; ``grid``, the scene's box widened
    or heightened about its centre to fill the view but for the margins: at the left the y tick
    labels, at the bottom the x tick labels and the x title, at the top the legend's band (the
    y title at its left).  A panel of another shape shows the whole box, margins included."""

    view: tuple[float, float, float, float]
    grid: tuple[float, float, float, float]

    #: width / height of the scene panel in the default layout (3/5 of a 16:9 window)
    ASPECT = 1.2
    LEFT, RIGHT, BOTTOM, TOP = 0.085, 0.025, 0.1, 0.2  # fractions of the view's width / height

    @classmethod
    def of(cls, bounds: tuple[float, float, float, float]) -> SceneLayout:
        x0, x1, y0, y1 = (float(b) for b in bounds)
        w, h = max(x1 - x0, 1e-9), max(y1 - y0, 1e-9)
        ratio = cls.ASPECT * (1 - cls.LEFT - cls.RIGHT) / (1 - cls.BOTTOM - cls.TOP)  # the grid's w / h
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        w, h = max(w, ratio * h), max(h, w / ratio)
        gx0, gx1, gy0, gy1 = cx - 0.5 * w, cx + 0.5 * w, cy - 0.5 * h, cy + 0.5 * h
        vw, vh = w / (1 - cls.LEFT - cls.RIGHT), h / (1 - cls.BOTTOM - cls.TOP)
        return cls((gx0 - cls.LEFT * vw, gx1 + cls.RIGHT * vw, gy0 - cls.BOTTOM * vh, gy1 + cls.TOP * vh),
                   (gx0, gx1, gy0, gy1))

    @property
    def row(self) -> float:
        """The height of a legend row (m): the band holds :data:`_LEGEND_ROWS` and a half."""
        return (self.view[3] - self.grid[3]) / (_LEGEND_ROWS + 0.5)

    def titles(self) -> np.ndarray:
        """Where the axis titles go (a label is drawn under its point): "x east (m)" in the
        bottom margin, under the x tick labels at the grid's right end; "y north (m)" at the
        top of the left margin, above the y tick labels."""
        (_vx0, _vx1, vy0, _vy1), (gx0, gx1, gy0, gy1) = self.view, self.grid
        return np.array([[gx1 - 0.06 * (gx1 - gx0), gy0 - 0.5 * (gy0 - vy0)], [gx0, gy1 + 0.35 * self.row]])

    def ticks(self, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, list[str]]:
        """The tick labels' points and texts: the x ticks in the bottom margin just under the
        grid, the y ticks centred in the left margin, each label's middle on its line."""
        (vx0, _vx1, vy0, _vy1), (gx0, _gx1, gy0, gy1) = self.view, self.grid
        bottom = gy0 - 0.12 * (gy0 - vy0)
        left = 0.5 * (vx0 + gx0)
        lift = 0.012 * (gy1 - gy0)  # a label is drawn under its point
        pts = [[x, bottom] for x in xs] + [[left, y + lift] for y in ys]
        return np.array(pts, dtype=float).reshape(-1, 2), [f"{x:g}" for x in xs] + [f"{y:g}" for y in ys]


def view_bounds(bounds: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """The box the view opens on (:attr:`SceneLayout.view`): the scene, its margins and the legend's band."""
    return SceneLayout.of(bounds).view


def log_legend(rec: rr.RecordingStream, scene: SceneGeometry,
               sensors: Sequence[tuple[Sensor, tuple[int, int, int, int]]],
               track: tuple[tuple[int, int, int], str] | None = None, truth: bool = True) -> None:
    """Static legend in the band above the grid (:class:`SceneLayout`), one entity per symbol:
    ``world/legend/<what>``, the symbol drawn as in the scene with its meaning as label; in
    the middle column ``world/legend/sensors``, one dot per sensor in its colour.  ``track``:
    the colour of the first track drawn, as the track symbols' example, and what a track's
    colour stands for (``"its motion cluster"``, ``"its label"``; before the first track, a
    palette colour and no meaning).  ``truth``: whether the run has truth (else the truth entry
    is empty)."""
    lay = SceneLayout.of(scene.bounds)
    x0, x1, y0, y1 = lay.grid
    w, dy = x1 - x0, lay.row
    left, mid, right = x0 + 0.17 * w, x0 + 0.5 * w, x1 - 0.15 * w
    top = y1 + _LEGEND_ROWS * dy
    track_rgb, meaning = track if track is not None else (PALETTE[2], "")

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
    cross = [[c - (hx, hx), c + (hx, hx)], [c + (-hx, hx), c + (hx, -hx)]] if truth else []
    rec.log(f"{LEGEND}/truth", rr.LineStrips2D(cross, radii=R_TRUTH_CROSS, colors=[GREY_TRUTH],
                                               labels=["truth", ""] if truth else [], show_labels=True), static=True)
    c = at(right, 1)
    trail = c + np.stack([np.linspace(-0.06 * w, 0.0, 6), 0.01 * w * np.sin(np.linspace(0, 3, 6))], -1)
    rec.log(f"{LEGEND}/track", rr.Points2D([c], radii=R_TRACK, colors=[track_rgb],
                                           labels=["track + trail" + (f" (colour: {meaning})" if meaning else "")], show_labels=True),
            rr.LineStrips2D([trail], radii=R_TRAIL, colors=[track_rgb]), static=True)
    c = at(right, 2)
    ell = c + scene.circle * (0.03 * w, 0.17 * dy)
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
