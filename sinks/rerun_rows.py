"""The row-by-row half of :class:`sinks.rerun_sink.RerunSink`: what is logged at once, not
kept for the next flush -- births and ends of labels and of true objects (events, styles,
clears), the annotation context, the styles of the time series -- and the per-frame rows of
the time series kept for the flush.

:class:`RowLogger` is a base class of :class:`~sinks.rerun_sink.RerunSink` and works on its
state: the stream ``_rec``, the label state (``_live``, ``_class``, ``_next_class``,
``_colors``, ``_paths``, ``_styled``, ``_truth_live``), the kept ``_scalars``, ``_frames`` and
``_clears``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import pyarrow as pa
import rerun as rr

from bnptrack.sinks.rerun_clusters import structure_rows
from bnptrack.sinks.rerun_columns import annotation_context, entity_part, track_style
from bnptrack.sinks.rerun_style import (CARDINALITY, CLUTTER_CLASS, DIAGNOSTICS, EVENTS, FIRST_LABEL_CLASS, GREY_CLUTTER,
                                        HEALTH, MAX_CLASS, OSPA, OSPA2, UNASSIGNED_CLASS, WHITE_UNASSIGNED, WORLD,
                                        label_color, pack_rgba, unpack_rgba)
from bnptrack.tracker.types import Estimate, Frame, display_name

if TYPE_CHECKING:
    from bnptrack.sinks.metrics import OspaResult

__all__ = ["RowLogger"]


class RowLogger:
    """Log :class:`~sinks.rerun_sink.RerunSink`'s rare rows at once (see the module docstring)."""

    def _series_style(self, entity: str, names: list[str], colors: list[tuple[int, int, int]]) -> None:
        self._rec.log(entity, rr.SeriesLines(names=names, colors=colors, widths=[1.5] * len(names)),
                      static=True)
        self._styled.add(entity)

    def _log_context(self) -> None:
        """Annotation context of ``world``: clutter, unassigned, and one class per live label
        (its name and colour), so hovering a measurement names the track it went to."""
        classes = [(CLUTTER_CLASS, "clutter", pack_rgba(GREY_CLUTTER)),
                   (UNASSIGNED_CLASS, "measurement", pack_rgba(WHITE_UNASSIGNED))]
        classes += [(self._class[lab], display_name(lab), self._colors[lab])
                    for lab in sorted(self._live, key=self._class.__getitem__)]
        self._log_arrays(WORLD, annotation_context(self._s, classes))
        self._context_logged = True

    def _event(self, text: str, level: str = "INFO") -> None:
        self._log_arrays(EVENTS, {"TextLog:text": pa.array([text], type=pa.string()),
                                  "TextLog:level": pa.array([level], type=pa.string())})

    def _labels_changed(self, k: int, t: int, labels: tuple[str, ...]) -> None:
        """Births and ends of labels: styles, clears, events, annotation context."""
        now = set(labels)
        born = [lab for lab in labels if lab not in self._live]
        ended = sorted(self._live - now, key=self._class.__getitem__)
        self._at(k, t)
        for lab in ended:
            self._clears.append((self._track_path(lab), k, t))
            self._event(f"track {display_name(lab)} ended (last seen at frame {self._prev_frame})")
        taken = [unpack_rgba(self._colors[o]) for o in labels if o in self._live]
        for lab in born:
            name = display_name(lab)
            self._class[lab] = self._next_class
            self._next_class = (FIRST_LABEL_CLASS if self._next_class >= MAX_CLASS
                                else self._next_class + 1)
            rgba = label_color(lab, taken)
            taken.append(rgba)
            packed = pack_rgba(rgba)
            if self._colors.get(lab) != packed:  # static style: fixed for the label's life
                self._colors[lab] = packed
                self._log_arrays(self._track_path(lab), track_style(name), static=True)
            self._event(f"track {name} born")
        self._live = now
        if born:  # new classes: re-log the context, with the live labels only
            self._class = {lab: self._class[lab] for lab in labels}
            self._colors = {lab: self._colors[lab] for lab in labels}
            self._log_context()

    def _truth_changed(self, k: int, t: int, ids: tuple[str, ...]) -> None:
        now = set(ids)
        self._at(k, t)
        for gone in sorted(self._truth_live - now):
            self._event(f"truth {gone} ended (last seen at frame {self._prev_frame})", level="DEBUG")
        for new in ids:
            if new not in self._truth_live:
                self._event(f"truth {new} born", level="DEBUG")
        self._truth_live = now

    def _log_scalars(self, k: int, t: int, frame: Frame, estimate: Estimate,
                     ospa: OspaResult | None, ospa2: float | None,
                     health: Mapping[str, float] | None) -> None:
        keep = self._scalars
        n_est = float(len(estimate.tracks))
        card = [n_est, float(len(frame.truth.ids))] if frame.truth is not None else [n_est]
        keep.setdefault(CARDINALITY, []).append((k, t, card))
        if ospa is not None:
            keep.setdefault(OSPA, []).append(
                (k, t, [float(ospa.total), float(ospa.localisation), float(ospa.cardinality)]))
        if ospa2 is not None:
            keep.setdefault(OSPA2, []).append((k, t, [float(ospa2)]))
        for entity, values in structure_rows(estimate, self._frames[-1].ccl, self._cc.seen):
            keep.setdefault(entity, []).append((k, t, values))
        paths = self._paths
        for key, value in estimate.diagnostics.items():
            entity = paths.get(("diag", key))
            if entity is None:
                entity = paths[("diag", key)] = f"{DIAGNOSTICS}/{entity_part(str(key))}"
                if entity not in self._styled:
                    self._series_style(entity, [str(key)], [(120, 190, 255)])
            keep.setdefault(entity, []).append((k, t, [float(value)]))
        if health:
            for key, value in health.items():
                entity = paths.get(("health", key))
                if entity is None:
                    entity = paths[("health", key)] = f"{HEALTH}/{entity_part(str(key))}"
                    self._series_style(entity, [str(key)], [label_color(str(key))[:3]])
                keep.setdefault(entity, []).append((k, t, [float(value)]))
