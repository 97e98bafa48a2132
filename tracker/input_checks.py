"""Checks of a user's inputs that would give a wrong result without a word.

Each check sits at an edge where the input arrives and is run once there:

* :func:`check_sensor_spec` (when a parameter set is built,
  :class:`~tracker.models.params.ModelParams`): a ``heading_deg`` that looks like radians;
* :func:`check_frames` (on the first frames of a log, before tracking: ``bnptrack track``,
  the launcher's checks of ``launch`` / ``replay``, :func:`bnptrack.track`): a frame's sensor
  with neither a ``[sensors.NAME]`` table nor a pose while the parameters declare other
  sensors (an error: a misspelt name), time stamps whose spacing implies another unit, a pose
  heading outside :math:`[-2\\pi, 2\\pi]` (degrees where radians are expected).

A warning is raised with :func:`warn` (``warnings.warn`` with :class:`InputWarning`): Python
callers see it as any warning, and the command line prints it on one line
(``warning: ...``).
"""

from __future__ import annotations

import math
import statistics
import warnings
from collections.abc import Iterable, Mapping
from typing import Any

from bnptrack.tracker.config import ConfigError, did_you_mean

__all__ = ["InputWarning", "warn", "check_sensor_spec", "check_frames", "SCAN_FRAMES",
           "MIN_SPACING_NS", "MAX_SPACING_NS"]

#: How many of a log's first frames :func:`check_frames` is given before tracking.
SCAN_FRAMES = 200
#: Median spacing between a sensor's scans below 1 ms or above 1 h: the stamps are probably
#: not nanoseconds.
MIN_SPACING_NS = 1_000_000
MAX_SPACING_NS = 3600 * 10**9

#: Stamps too close together: written in these units (factor to nanoseconds); too far apart:
#: converted to nanoseconds as if they were seconds.
_SMALL = (("seconds", 1e9), ("milliseconds", 1e6), ("microseconds", 1e3))
_LARGE = (("milliseconds converted as seconds", 1e-3), ("microseconds converted as seconds", 1e-6),
          ("nanoseconds converted as seconds", 1e-9))


class InputWarning(UserWarning):
    """An input that is accepted but probably gives a wrong result (the message names the fix)."""


def warn(message: str) -> None:
    """Raise ``message`` as an :class:`InputWarning` (``warnings.warn``)."""
    warnings.warn(message, InputWarning, stacklevel=3)


def check_sensor_spec(name: str, heading_deg: float) -> None:
    """Warn when a ``[sensors.NAME]`` ``heading_deg`` looks like radians: a value that is not a
    whole number of degrees within :math:`[-2\\pi, 2\\pi]` (e.g. ``0.698`` for 40 degrees)."""
    h = float(heading_deg)
    if 0.0 < abs(h) <= 2 * math.pi and h != round(h):
        warn(f"[sensors.{name}] heading_deg = {h:g} looks like radians ({math.degrees(h):.4g} deg); "
             f"heading_deg is in degrees: write heading_deg = {math.degrees(h):.4g} if that is meant")


def check_frames(params: Any, frames: Iterable[Any]) -> None:
    """Check the first frames of a run against ``params`` (a
    :class:`~tracker.models.params.ModelParams`, or None: only the stamps and poses are
    checked): raise :class:`ConfigError` for a misspelt sensor name, warn (:func:`warn`) for
    stamps in another unit and for pose headings in degrees."""
    declared: Mapping[str, Any] = getattr(params, "sensors", None) or {}
    stamps: dict[str, list[int]] = {}
    degrees_seen = False
    for f in frames:
        if declared and f.sensor not in declared and f.pose is None:
            raise ConfigError(
                f"frame {f.frame}: sensor {f.sensor!r} has no [sensors.{f.sensor}] table in the parameters "
                f"and no pose in its frames, while the parameters declare "
                f"{', '.join(repr(n) for n in declared)}{did_you_mean(f.sensor, list(declared))}; "
                f"fix the name, or add a [sensors.{f.sensor}] table with its pose")
        stamps.setdefault(f.sensor, []).append(int(f.stamp_ns))
        if not degrees_seen and f.pose is not None and abs(float(f.pose[2])) > 2 * math.pi:
            degrees_seen, h = True, float(f.pose[2])
            warn(f"sensor {f.sensor!r}: frame {f.frame} has pose heading {h:g}, outside [-2pi, 2pi]: "
                 f"a pose heading is in radians (from +y towards +x); if {h:g} is degrees, send "
                 f"{math.radians(h):.6g}")
    for sensor, times in stamps.items():
        _check_spacing(sensor, times)


def _check_spacing(sensor: str, stamps: list[int]) -> None:
    """Warn when the median spacing of a sensor's scans is under 1 ms or over 1 h, naming the
    unit that gives the spacing closest to a second."""
    gaps = [b - a for a, b in zip(stamps, stamps[1:]) if b > a]
    if len(gaps) < 2:
        return
    gap = statistics.median(gaps)
    if MIN_SPACING_NS <= gap <= MAX_SPACING_NS:
        return
    small = gap < MIN_SPACING_NS
    factors = _SMALL if small else _LARGE
    unit, factor = min(factors, key=lambda uf: abs(math.log10(gap * uf[1] / 1e9)))
    fix = (f"they look like {unit} (the spacing would be {gap * factor / 1e9:g} s): "
           + (f"multiply them by {factor:g}" if small else f"divide them by {1 / factor:g}"))
    warn(f"sensor {sensor!r}: the median spacing of its time stamps is {_duration(gap)} between scans; "
         f"stamp_ns must be nanoseconds -- {fix}")


def _duration(ns: float) -> str:
    """``ns`` as a short duration (``500 ns``, ``2.5 h``)."""
    for unit, scale in (("h", 3600e9), ("s", 1e9), ("ms", 1e6), ("us", 1e3)):
        if ns >= scale:
            return f"{ns / scale:.3g} {unit}"
    return f"{ns:g} ns"
