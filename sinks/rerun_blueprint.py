"""The default blueprint of a recording: the layout the Rerun viewer opens it with."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import rerun.blueprint as rrb

from bnptrack.sinks.rerun_style import (CARDINALITY, DIAG_NAMES, DIAGNOSTICS, EVENTS, HEALTH, METADATA, OSPA, OSPA2, STRUCTURE,
                               WORLD)

__all__ = ["default_blueprint"]


def default_blueprint(*, diagnostics: Iterable[str] = tuple(DIAG_NAMES), health: bool = True,
                      scene_bounds: tuple[float, float, float, float] | None = None,
                      truth: bool = True) -> rrb.Blueprint:
    """The layout a recording opens with: the 2-D scene (3/5 of the width) and, beside it,
    cardinality, the structure (motion clusters of the reported tracks and the posterior
    cardinality's mean and MAP), OSPA /
    OSPA(2) and a tab group (tracker diagnostics, pipeline health, events,
    run metadata).  ``scene_bounds`` = ``(x_min, x_max, y_min, y_max)`` in metres.  Without
    ``truth`` (a log without ground truth) there is no OSPA panel (it would stay empty) and the
    cardinality panel shows the number of tracks alone.
    """
    scene_kw: dict[str, Any] = {}
    if scene_bounds is not None:
        x0, x1, y0, y1 = scene_bounds
        # the scene is drawn under a y-flip (see sinks.rerun_sink.RerunSink): view y = -world y
        scene_kw["visual_bounds"] = rrb.VisualBounds2D(x_range=[x0, x1], y_range=[-y1, -y0])
    diag_views: list[Any] = [
        rrb.TimeSeriesView(origin=f"{DIAGNOSTICS}/{k}", name=DIAG_NAMES.get(k, k)) for k in diagnostics
    ]
    tabs: list[Any] = [*diag_views]
    if health:
        tabs.append(rrb.TimeSeriesView(origin=HEALTH, name="pipeline health"))
    tabs += [rrb.TextLogView(origin=EVENTS, name="births / ends"),
             rrb.TextDocumentView(origin=METADATA, name="run")]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="/", contents=f"{WORLD}/**", name="scene (x east, y north, m)",
                              **scene_kw),
            rrb.Vertical(*_metric_views(truth), rrb.Tabs(*tabs, active_tab=0),
                         row_shares=[1.0, 1.0, 1.0, 1.1] if truth else [1.0, 1.0, 2.1]),
            column_shares=[3.0, 2.0],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline="frame"),
    )


def _metric_views(truth: bool) -> list[Any]:
    """The metric panels, each legend in the corner its curves leave free: the counts start
    low (top left), OSPA starts at its cut-off until the first tracks are confirmed and falls
    (top right), so that no legend hides the first frames."""
    low_start = rrb.PlotLegend(rrb.Corner2D.LeftTop)
    structure = rrb.TimeSeriesView(origin=STRUCTURE, name="motion clusters of the tracks; posterior cardinality mean and MAP",
                                   plot_legend=low_start)
    if not truth:
        return [rrb.TimeSeriesView(origin=CARDINALITY, name="tracks (the log has no truth: no OSPA)",
                                   plot_legend=low_start), structure]
    return [rrb.TimeSeriesView(origin=CARDINALITY, name="cardinality: estimated vs true", plot_legend=low_start),
            structure,
            rrb.TimeSeriesView(origin="metrics", contents=[OSPA, OSPA2], name="OSPA (c=100 m, p=1) and OSPA(2)",
                               plot_legend=rrb.PlotLegend(rrb.Corner2D.RightTop))]
