"""Checks of a user's inputs that would give a wrong result without a word.

Each check sits at an edge where the input arrives and is run once there:

* :func:`check_sensor_spec` (when a parameter set is built,
  :class:`~tracker.models.params.ModelParams`): a ``heading_deg`` that looks like radians;
* :func:`check_frames` (on the first frames of a log, before tracking: ``bnptrack track``,
  the launcher's checks of ``launch`` / ``replay``, :func:`bnptrack.track`): a frame's sensor
  with neither a ``[sensors.NAME]`` table nor a pose while the parameters declare other
  sensors (an error: a misspelt name, naming the side to fix), a frame's sensor with no pose
  anywhere and a name other than the default sensor's (a warning), time stamps whose spacing implies another unit, a pose
  heading outside :math:`[-2\\pi, 2\\pi]` (degrees where radians are expected).

A warning is raised with :func:`warn` (``warnings.warn`` with :class:`InputWarning`): Python
callers see it as any warning, and the command line prints it on one line
(``warning: ...``).
"""

from __future__ import annotations

import math
import os
import statistics
import sys
import warnings
from difflib import get_close_matches
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from bnptrack.tracker.config import ConfigError

__all__ = ["InputWarning", "warn", "check_sensor_spec", "check_frames", "check_spacing", "SCAN_FRAMES",
           "MIN_SPACING_NS", "MAX_SPACING_NS", "DEFAULT_SENSOR_NAMES", "SIM_SENSOR"]

#: The sensor name of simulated frames (``bnptrack simulate``, the synthetic source).
SIM_SENSOR = "sim0"
#: Sensor names that mean the parameter set's default sensor: frames so named need no pose.
DEFAULT_SENSOR_NAMES = ("", SIM_SENSOR)

#: How many of a log's first frames :func:`check_frames` is given before tracking.
SCAN_FRAMES = 200
#: Median spacing between a sensor's scans below 2 ms (over 500 scans a second) or above 1 h:
#: the stamps are probably not nanoseconds (microsecond stamps of a 1 Hz sensor are 1 ms apart).
MIN_SPACING_NS = 2_000_000
MAX_SPACING_NS = 3600 * 10**9

#: Stamps too close together: written in these units (factor to nanoseconds); too far apart:
#: converted to nanoseconds as if they were seconds.
_SMALL = (("seconds", 1e9), ("milliseconds", 1e6), ("microseconds", 1e3))
_LARGE = (("milliseconds converted as seconds", 1e-3), ("microseconds converted as seconds", 1e-6),
          ("nanoseconds converted as seconds", 1e-9))


class InputWarning(UserWarning):
    """An input that is accepted but probably gives a wrong result (the message names the fix)."""


#: The folders of bnptrack's own code: a warning is attributed to the first caller outside them.
_OWN_CODE = tuple(str(Path(__file__).resolve().parents[1] / pkg) + os.sep
                  for pkg in ("tracker", "sources", "sinks", "pipeline", "bnptrack"))


def warn(message: str) -> str:
    """Raise ``message`` as an :class:`InputWarning` (``warnings.warn``), attributed to the
    caller's own line outside bnptrack (so Python's default filter shows it once per line of
    the caller's code and message, not once per bnptrack line); returns it."""
    level, frame = 2, sys._getframe(1)  # stacklevel 2: the caller of warn
    while frame is not None and frame.f_code.co_filename.startswith(_OWN_CODE):
        level, frame = level + 1, frame.f_back
    warnings.warn(message, InputWarning, stacklevel=level)
    return message


def check_sensor_spec(name: str, heading_deg: float) -> None:
    """Warn when a ``[sensors.NAME]`` ``heading_deg`` looks like radians: a value that is not a
    whole number of degrees within :math:`[-2\\pi, 2\\pi]` (e.g. ``0.698`` for 40 degrees)."""
    h = float(heading_deg)
    if 0.0 < abs(h) <= 2 * math.pi and h != round(h):
        warn(f"[sensors.{name}] heading_deg = {h:g} looks like radians ({math.degrees(h):.4g} deg); "
             f"heading_deg is in degrees: write heading_deg = {math.degrees(h):.4g} if that is meant")


def check_frames(params: Any, frames: Iterable[Any], source: str | None = None,
                 set_sensors: Mapping[str, str] | None = None, set_name: str = "--set") -> tuple[str, ...]:
    """Check the first frames of a run against ``params`` (a
    :class:`~tracker.models.params.ModelParams`, or None: only the stamps and poses are
    checked), read from ``source`` (the params file or set, named in messages) and the
    ``--set`` items ``set_sensors`` (sensor name -> the item that declares its table, when
    only an item does; ``set_name`` names such an item, e.g. ``--set``): raise :class:`ConfigError` for a misspelt sensor name, warn
    (:func:`warn`) for a sensor with no pose anywhere, stamps in another unit and pose
    headings in degrees.  Returns the messages of the warnings raised."""
    frames = list(frames)
    declared: Mapping[str, Any] = getattr(params, "sensors", None) or {}
    stamps: dict[str, list[int]] = {}
    raised: list[str] = []
    for f in frames:
        if declared and f.sensor not in declared and f.pose is None:
            raise ConfigError(_misspelt(f.sensor, f.frame, declared, source, set_sensors or {}, set_name))
        stamps.setdefault(f.sensor, []).append(int(f.stamp_ns))
    degrees = next((f for f in frames if f.pose is not None and abs(float(f.pose[2])) > 2 * math.pi), None)
    if degrees is not None:
        h = float(degrees.pose[2])
        raised.append(f"sensor {degrees.sensor!r}: frame {degrees.frame} has pose heading {h:g}, outside "
                      f"[-2pi, 2pi]: a pose heading is in radians (from +y towards +x); if {h:g} is "
                      f"degrees, send {math.radians(h):.6g}")
    if params is not None:
        raised += _unposed(frames, declared)
    raised += [note for note in (check_spacing(s, t) for s, t in stamps.items()) if note]
    for note in raised:
        warn(note)
    return tuple(raised)


def _unposed(frames: list[Any], declared: Mapping[str, Any]) -> list[str]:
    """A warning for each sensor with neither a ``[sensors.NAME]`` table nor a pose in any of
    ``frames`` whose name is not the default sensor's: it is tracked at the default pose."""
    from bnptrack.tracker.models.measurement import KINDS

    posed = {f.sensor for f in frames if f.pose is not None}
    kinds = {f.sensor: f.kind for f in frames}
    fix = ("add a [sensors.{s}] table with x, y, heading_deg to your params file (docs/models.md, 'Sensors'), "
           "or send a per-frame 'pose'")
    out = []
    for s, kind in kinds.items():
        if s in declared or s in posed or s in DEFAULT_SENSOR_NAMES:
            continue
        entry = KINDS.get(kind)
        if entry is not None and entry.world_frame:
            what = (f"its detections are world positions, but its field of view and clutter region are the "
                    f"default sensor's (at (0, 0) facing +y)")
        else:
            what = "tracked as if at (0, 0) facing +y (the default sensor)"
        out.append(f"sensor {s!r} has no pose: {what}; {fix.format(s=s)}")
    return out


def _misspelt(sensor: str, frame: int, declared: Mapping[str, Any], source: str | None,
              set_sensors: Mapping[str, str], set_name: str = "--set") -> str:
    """The error for a log's sensor with neither a ``[sensors.NAME]`` table nor a pose while
    the parameters (from ``source``, and the ``--set`` items of ``set_sensors``) declare other
    sensors: which side to fix."""
    where = source or "the parameters"
    tables = ", ".join(f"[sensors.{n}]" + (f" (from {set_name} {set_sensors[n]!r})" if n in set_sensors else "")
                       for n in declared)
    close = get_close_matches(sensor, list(declared), n=1, cutoff=0.6)
    if close and close[0] in set_sensors:
        item = set_sensors[close[0]]
        fixed = item.replace(f"sensors.{close[0]}", f"sensors.{sensor}", 1)
        return (f"{set_name} {item!r} declares sensor {close[0]!r}, which the log does not have: the log's sensor "
                f"{sensor!r} (frame {frame}) has no [sensors.{sensor}] table and no pose in its frames "
                f"(did you mean {set_name} {fixed!r}?)")
    if close:
        fix = (f"rename that table to [sensors.{sensor}] if it is this sensor, or, if the log misspells "
               f"{close[0]!r}, fix the name in the log")
    else:
        fix = f"add a [sensors.{sensor}] table with x, y, heading_deg to {where}, or send a per-frame 'pose'"
    return (f"the log's sensor {sensor!r} (frame {frame}) has no [sensors.{sensor}] table in {where}, "
            f"which declares {tables}, and no pose in its frames: {fix}")


def check_spacing(sensor: str, stamps: list[int]) -> str | None:
    """The warning when the median spacing of a sensor's scans is under 2 ms or over 1 h,
    naming the unit that gives the spacing closest to a second (None when it is plausible)."""
    gaps = [b - a for a, b in zip(stamps, stamps[1:]) if b > a]
    if len(gaps) < 2:
        return None
    gap = statistics.median(gaps)
    if MIN_SPACING_NS <= gap <= MAX_SPACING_NS:
        return None
    small = gap < MIN_SPACING_NS
    factors = _SMALL if small else _LARGE
    unit, factor = min(factors, key=lambda uf: abs(math.log10(gap * uf[1] / 1e9)))
    fix = (f"they look like {unit} (the spacing would be {gap * factor / 1e9:g} s): "
           + (f"multiply them by {factor:g}" if small else f"divide them by {1 / factor:g}"))
    return (f"sensor {sensor!r}: the median spacing of its time stamps is {_duration(gap)} between scans; "
            f"stamp_ns must be nanoseconds -- {fix}")


def _duration(ns: float) -> str:
    """``ns`` as a short duration (``500 ns``, ``2.5 h``)."""
    for unit, scale in (("h", 3600e9), ("s", 1e9), ("ms", 1e6), ("us", 1e3)):
        if ns >= scale:
            return f"{ns / scale:.3g} {unit}"
    return f"{ns:g} ns"
