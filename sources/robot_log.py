"""Frames from the measurement channels of a ROS 2 or Foxglove MCAP log.

:func:`iter_robot_frames` reads the chosen channels (``--topic /radar/scan``; several topics:
several sensors) of a log whose messages are of the types of :data:`sources.readers.READERS`:
each message is decoded with a maintained library of its encoding (CDR: ``rosbags``'
deserializer, generated once per schema, or ``mcap-ros2-support``'s ``DecoderFactory`` for a
schema rosbags does not parse; protobuf: ``mcap-protobuf-support``'s ``DecoderFactory``;
JSON: ``json``) and read by its schema's reader into one
:class:`~tracker.types.Frame`:

* time: the message's own stamp (``header.stamp``, Foxglove's ``timestamp``), else the MCAP
  log time;
* sensor: ``header.frame_id`` (the topic when it is empty);
* pose: the frame's pose in the root of ``/tf_static`` (:mod:`sources.tf_static`) when the log
  has a static transform to it; ``xy`` rows are then moved from the sensor's frame to the
  world frame.  Without one, the frame has no pose (the params file's ``[sensors.NAME]``
  table gives it) and ``xy`` rows are taken as world coordinates.

The frames of all chosen channels are ordered by time (file order among equal stamps) and
numbered 1, 2, ... as a multi-sensor bnptrack log numbers its interleaved frames.  A damaged
file yields the frames read before the damage, then raises
:class:`~sources.mcap_log.McapLogError`, as :func:`~sources.mcap_log.iter_frames` does.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

from mcap.records import Channel, DataEnd, Message, Schema
from mcap.stream_reader import StreamReader

from bnptrack.sources.channels import ChannelInfo, channel_list, record_limit, trackable, trackable_listing
from bnptrack.sources.log_errors import McapLogError
from bnptrack.sources.readers import MessageReader, Scan, reader_entry
from bnptrack.sources.tf_static import StaticTransforms
from bnptrack.tracker.messages import TOPIC_MEASUREMENTS
from bnptrack.tracker.types import Frame

__all__ = ["TF_STATIC", "TF_SCHEMA", "robot_topics", "iter_robot_frames"]

TF_STATIC = "/tf_static"
TF_SCHEMA = "tf2_msgs/msg/TFMessage"


def robot_topics(path: str | os.PathLike, topic_map: Mapping[str, str],
                 channels: list[ChannelInfo] | None = None) -> list[str]:
    """The channels of ``topic_map`` read as ``/measurements`` that need a reader of
    :data:`~sources.readers.READERS` (in the order given); ``[]`` when they are bnptrack's own
    JSON channels.  :class:`ValueError` (one line listing the trackable channels) for a
    channel that is missing, of a type bnptrack cannot use, or mixed with bnptrack channels."""
    wanted = [src for src, dst in topic_map.items() if dst == TOPIC_MEASUREMENTS and src != TOPIC_MEASUREMENTS]
    if not wanted:
        return []
    channels = channel_list(path) if channels is None else channels
    by_topic = {c.topic: c for c in channels}
    spath, robot, own = os.fspath(path), [], []
    for topic in wanted:
        c = by_topic.get(topic)
        if c is None:
            problem = f"has no channel {topic}"
        elif trackable(c) is not None:
            robot.append(topic)
            continue
        elif c.message_encoding == "json" and not c.schema.startswith("foxglove."):
            own.append(topic)
            continue
        else:
            problem = f"channel {topic} carries {c.schema or 'schemaless'} ({c.message_encoding}), which bnptrack cannot track"
        raise ValueError(f"{spath} {problem}; trackable channels: {trackable_listing(channels)}")
    if robot and own:
        raise ValueError(f"{spath}: --topic {', '.join(own)} (bnptrack JSON) and {', '.join(robot)} "
                         "(ROS 2 / Foxglove types) cannot be read together")
    return robot


#: A message read but not yet a frame (its pose may come later in the file):
#: ``(stamp_ns, order, kind, scan, sensor)``.
_Pending = tuple[int, int, str, Scan, str]


class _RobotScanner:
    """Stream the records of a log, decoding the chosen channels and ``/tf_static``."""

    def __init__(self, path: str | os.PathLike, topics: Iterable[str]) -> None:
        self.path = os.fspath(path)
        self.topics = frozenset(topics)
        self.tf = StaticTransforms()
        self.pending: list[_Pending] = []
        self.in_order = True
        """Whether ``pending`` is in time order as read (no sort needed)."""
        self.max_stamp = 0  # the latest stamp read so far (kept once the order breaks)
        self.latest = (0, "", 0)  # the message stamped furthest before one read earlier: (ns, topic, its count)
        self.n_messages = 0
        self.offset = 0
        self.schemas: dict[int, Schema] = {}
        self.decoders: dict[int, tuple[Callable[[bytes], Any], MessageReader | None, str]] = {}
        self.per_topic: dict[str, int] = {}  # messages read of each topic (for the errors)

    def run(self) -> None:
        """Read the file to its end (or raise McapLogError; ``pending`` holds what was read)."""
        try:
            f = open(self.path, "rb")
        except OSError as exc:
            raise McapLogError(self.path, "corrupt", 0, 0, None, f"cannot open: {exc}") from exc
        with f:
            size = os.fstat(f.fileno()).st_size
            records = StreamReader(f, validate_crcs=True, record_size_limit=record_limit(size)).records
            while True:
                self.offset = f.tell()
                try:
                    rec = next(records)
                except StopIteration:
                    return
                except Exception as exc:  # the mcap library's errors on bad bytes
                    kind = "truncated" if f.tell() >= size else "corrupt"
                    raise self._error(kind, f"{type(exc).__name__}: {exc}") from exc
                if isinstance(rec, Message):
                    self._message(rec)
                elif isinstance(rec, Schema):
                    self.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    self._channel(rec)
                elif isinstance(rec, DataEnd):
                    return

    def _error(self, kind: str, reason: str, topic: str | None = None) -> McapLogError:
        return McapLogError(self.path, kind, self.offset, self.n_messages, len(self.pending) or None, reason, topic)

    def _channel(self, ch: Channel) -> None:
        tf = ch.topic == TF_STATIC
        if ch.topic not in self.topics and not tf:
            return
        schema = self.schemas.get(ch.schema_id)
        name = schema.name if schema is not None else ""
        if tf and name != TF_SCHEMA:
            return
        entry = None if tf else reader_entry(name, ch.message_encoding)
        if entry is None and not tf:
            raise self._error("invalid", f"channel {ch.topic} carries {name or 'schemaless'} ({ch.message_encoding}), "
                              "which bnptrack cannot track", ch.topic)
        decode = _decoder(ch.message_encoding, schema)
        self.decoders[ch.id] = (decode, entry.load() if entry is not None else None, ch.topic)

    def _message(self, rec: Message) -> None:
        self.n_messages += 1
        dec = self.decoders.get(rec.channel_id)
        if dec is None:
            return
        decode, reader, topic = dec
        self.per_topic[topic] = k = self.per_topic.get(topic, 0) + 1
        try:
            msg = decode(rec.data)
            if reader is None:
                self.tf.add(msg)
                return
            scan = reader.scan(msg)
        except ValueError as exc:  # the reader's check of a decoded message
            raise self._error("invalid", f"{topic}'s message {k}: {exc}", topic) from exc
        except Exception as exc:  # bytes the decoder cannot read
            raise self._error("invalid", f"{topic}'s message {k} cannot be decoded: {type(exc).__name__}: {exc}",
                              topic) from exc
        stamp = scan.stamp_ns if scan.stamp_ns is not None else rec.log_time
        pending = self.pending
        if pending and stamp < pending[-1][0]:
            self.in_order = False
            self.max_stamp = max(self.max_stamp, pending[-1][0])
            if self.max_stamp - stamp > self.latest[0]:
                self.latest = (self.max_stamp - stamp, topic, k)
        pending.append((stamp, len(pending), reader.kind, scan, scan.frame_id or topic))


def _rosbags_decoder(schema: Schema) -> Callable[[bytes], Any] | None:
    """``rosbags``' deserializer of a ``ros2msg`` schema (Python code generated once for the
    type, about 1.7x faster than ``mcap_ros2``'s interpreted decoder on a RadarScan of 12
    returns: docs/performance.md), or ``None`` when rosbags cannot parse the schema."""
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(schema.data.decode(), schema.name))
        store.get_msgdef(schema.name)
    except Exception:
        return None
    name = schema.name
    return lambda data: store.deserialize_cdr(data, name)


def _decoder(message_encoding: str, schema: Schema | None) -> Callable[[bytes], Any]:
    """The library decoder of a channel, made once per channel: CDR with ``rosbags`` (else
    ``mcap_ros2``'s ``DecoderFactory``), protobuf with ``mcap_protobuf``'s, JSON with ``json``."""
    if message_encoding == "json":
        return json.loads
    if message_encoding == "cdr":
        from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

        fast = _rosbags_decoder(schema) if schema is not None and schema.encoding == "ros2msg" else None
        if fast is not None:
            return fast
        factory: Any = Ros2Decoders()
    else:
        from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders

        factory = ProtobufDecoders()
    decode = factory.decoder_for(message_encoding, schema)
    if decode is None:
        raise ValueError(f"no decoder for {message_encoding} messages of schema "
                         f"{schema.name if schema else 'none'} ({schema.encoding if schema else '-'})")
    return decode


def _frames(scanner: _RobotScanner) -> Iterator[Frame]:
    """The pending messages as frames in time order (file order among equal stamps),
    numbered from 1, placed by the static transforms."""
    pending = scanner.pending if scanner.in_order else sorted(scanner.pending, key=lambda p: (p[0], p[1]))
    if not scanner.in_order:
        _warn_if_far_out_of_order(scanner, pending)
    poses: dict[str, Any] = {}
    for k, (stamp, _, kind, scan, sensor) in enumerate(pending, start=1):
        if sensor not in poses:
            pose = scanner.tf.pose(sensor)
            poses[sensor] = (pose, pose.bnptrack_pose() if pose is not None else None)
        pose, frame_pose = poses[sensor]
        z = scan.z
        if pose is not None and kind == "xy":
            z = pose.place(z)
        yield Frame.checked(k, stamp, sensor, kind, z, pose=frame_pose)


#: A message stamped more than this many median periods before one read earlier is named in a
#: warning: ordering it by its stamp moves it far (a clock jump, or a wrong stamp).
FAR_OUT_OF_ORDER_PERIODS = 10


def _warn_if_far_out_of_order(scanner: _RobotScanner, ordered: list[_Pending]) -> None:
    """Warn when the sort by stamp moved a message further than
    :data:`FAR_OUT_OF_ORDER_PERIODS` median periods of the log's messages."""
    from bnptrack.tracker.input_checks import warn

    late_ns, topic, k = scanner.latest
    stamps = [p[0] for p in ordered]
    steps = sorted(b - a for a, b in zip(stamps, stamps[1:]))
    period = steps[len(steps) // 2] if steps else 0
    if late_ns > FAR_OUT_OF_ORDER_PERIODS * max(period, 1):
        warn(f"{scanner.path}: {topic}'s message {k} is stamped {late_ns / 1e9:.6g} s before a message read "
             f"earlier ({late_ns / max(period, 1):.0f} periods of {period / 1e9:.6g} s); frames follow the stamps, "
             f"so it is tracked that much earlier than the file puts it: check the sensor's clock")


def iter_robot_frames(path: str | os.PathLike, topics: Iterable[str]) -> Iterator[Frame]:
    """The frames of the ``topics`` of a ROS 2 / Foxglove log (module docstring).  A damaged
    file or an unreadable message: the frames read before it, then :class:`McapLogError`."""
    scanner = _RobotScanner(path, topics)
    try:
        scanner.run()
    except McapLogError:
        yield from _frames(scanner)
        raise
    yield from _frames(scanner)
