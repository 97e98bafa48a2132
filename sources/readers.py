"""Readers of robotics message types: the interface and the table of readers by schema.

A log recorded by ROS 2 (``ros2 bag record -s mcap``: CDR messages with ``ros2msg`` schemas) or
by Foxglove's SDK (protobuf or JSON with Foxglove's schemas) carries measurements in message
types of its own.  :mod:`sources.robot_log` decodes each message with the maintained library of
its encoding (``mcap-ros2-support``, ``mcap-protobuf-support``; JSON with the standard library)
and hands the decoded object to the :class:`MessageReader` of its schema, which returns one
:class:`Scan`: the rows of one bnptrack measurement kind in the sensor's own frame.  The log
reader then places the scan (the sensor's pose from ``/tf_static``) and makes a
:class:`~tracker.types.Frame` of it, so the tracker never sees where a frame came from.

:data:`READERS` is the table of readers by schema name.  Adding a message type: one module
with a class that has ``kind`` and ``scan(msg)``, plus one entry here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Protocol

from bnptrack.sources.scan import Scan

__all__ = ["Scan", "MessageReader", "ReaderEntry", "READERS", "reader_entry"]


class MessageReader(Protocol):
    """What reads one message type: ``kind`` (a bnptrack measurement kind) and
    ``scan(msg)`` (the library's decoded message -> :class:`Scan`; :class:`ValueError` for a
    message it cannot use, e.g. a point cloud without ``x``/``y`` fields)."""

    kind: str

    def scan(self, msg: Any) -> Scan: ...


@dataclass(frozen=True)
class ReaderEntry:
    """A row of :data:`READERS`: the reader class (``"module:attribute"``, imported on use),
    the bnptrack kind it gives, the message encodings it reads, and what it takes from a
    message (for ``bnptrack info`` and the docs)."""

    factory: str
    kind: str
    encodings: tuple[str, ...]
    takes: str

    def load(self) -> MessageReader:
        module, _, attr = self.factory.partition(":")
        return getattr(importlib.import_module(module), attr)()


#: The readers by schema name (ROS 2 ``pkg/msg/Type``, Foxglove ``foxglove.Type``).
READERS: dict[str, ReaderEntry] = {
    "radar_msgs/msg/RadarScan": ReaderEntry(
        "bnptrack.sources.read_radar:RadarScanReader", "bearing_range", ("cdr",),
        "returns[].azimuth and range (bearing = -azimuth)"),
    "sensor_msgs/msg/PointCloud2": ReaderEntry(
        "bnptrack.sources.read_pointcloud2:PointCloud2Reader", "xy", ("cdr",),
        "the x and y fields of every point (z and other fields dropped)"),
    "vision_msgs/msg/Detection3DArray": ReaderEntry(
        "bnptrack.sources.read_poses:Detection3DArrayReader", "xy", ("cdr",),
        "detections[].bbox.center.position x, y (box centres)"),
    "geometry_msgs/msg/PoseArray": ReaderEntry(
        "bnptrack.sources.read_poses:PoseArrayReader", "xy", ("cdr",),
        "poses[].position x, y"),
    "foxglove.PointCloud": ReaderEntry(
        "bnptrack.sources.read_foxglove:FoxglovePointCloudReader", "xy", ("protobuf", "json"),
        "the x and y fields of every point, placed by the cloud's pose"),
}


def reader_entry(schema: str, message_encoding: str) -> ReaderEntry | None:
    """The entry that reads messages of ``schema`` in ``message_encoding``, or ``None``."""
    entry = READERS.get(schema)
    if entry is None or message_encoding not in entry.encodings:
        return None
    return entry
