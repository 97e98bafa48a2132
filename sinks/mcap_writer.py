"""The MCAP log writer: frames, truth and tracks into an MCAP file (a sink).

File layout written by :class:`McapLogWriter` (read back by :mod:`sources.mcap_log`; described
in docs/formats.md):

* one ``Metadata`` record named ``tracker.messages.METADATA_NAME`` (``"bnptrack.scenario"``) with string
  keys, e.g. ``{"scenario": "vo2017", "params": "vo2017", "seed": "1"}``;
* channels ``/measurements``, ``/truth``, ``/tracks`` (registered on first use), message
  encoding ``json``, schema encoding ``jsonschema`` (the schemas of :mod:`tracker.messages`);
* ``log_time = publish_time = stamp_ns``, ``sequence = frame index``;
* small zstd chunks (4 KiB) and a flush every few writes, so a crash loses little.
"""

from __future__ import annotations

import json
import os
from typing import Any

from mcap.writer import CompressionType, Writer

from bnptrack.tracker.messages import (
    METADATA_NAME,
    SCHEMA_VERSION,
    TOPIC_MEASUREMENTS,
    TOPIC_TRACKS,
    TOPIC_TRUTH,
    encode,
    from_truth,
    json_schema,
)
from bnptrack.tracker.types import Estimate, Frame

__all__ = ["DEFAULT_CHUNK_SIZE", "DEFAULT_FLUSH_EVERY", "McapLogWriter", "TOPIC_TRACKS_ONLINE"]

#: Chunk size used by :class:`McapLogWriter` (small, so a cut file loses little).
DEFAULT_CHUNK_SIZE = 4 * 1024
#: Writes (``write_frame``/``write_tracks`` calls) between explicit flushes.
DEFAULT_FLUSH_EVERY = 5

#: The channel of a lagged run's online estimates (``bnptrack track --lag N``), beside its
#: ``/tracks`` (the lagged ones); the same messages as ``/tracks``.
TOPIC_TRACKS_ONLINE = "/tracks_online"

_SCHEMA_NAMES = {
    TOPIC_MEASUREMENTS: "bnptrack.Measurements",
    TOPIC_TRUTH: "bnptrack.Truth",
    TOPIC_TRACKS: "bnptrack.Tracks",
}


#: The writers open in this process by file (real path): a sink that writes a channel of its
#: own beside ``/tracks`` (the ``foxglove`` sink) writes into the same file (:meth:`McapLogWriter.open_at`).
_OPEN: dict[str, "McapLogWriter"] = {}


class McapLogWriter:
    """Write frames, truth and tracks to an MCAP file (use as a context manager).

    ``metadata`` (string keys and values; other values are converted with ``str``) is
    written as the ``bnptrack.scenario`` record.  ``flush_every`` is the number of
    ``write_frame``/``write_tracks`` calls between explicit flushes (each flush closes the
    current chunk and flushes the OS file buffer; it does not fsync).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        metadata: dict[str, str] | None = None,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        *,
        flush_every: int = DEFAULT_FLUSH_EVERY,
        compression: str = "zstd",
    ) -> None:
        self.path = os.fspath(path)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in comp:
            raise ValueError(f"compression must be one of {sorted(comp)}, got {compression!r}")
        if flush_every < 1:
            raise ValueError("flush_every must be >= 1")
        self._file = open(self.path, "wb")
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp[compression])
            self._writer.start(profile="", library=f"bnptrack (schema v{SCHEMA_VERSION})")
            if metadata is not None:
                self._writer.add_metadata(
                    METADATA_NAME, {str(k): str(v) for k, v in metadata.items()}
                )
            self._file.flush()
        except BaseException:
            self._file.close()
            raise
        self._channels: dict[str, int] = {}
        _OPEN[os.path.realpath(self.path)] = self
        self._flush_every = flush_every
        self._since_flush = 0
        self._closed = False
        self.n_frames = 0
        self.n_tracks = 0

    # -- context manager -------------------------------------------------------------
    def __enter__(self) -> "McapLogWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------------
    def _channel(self, topic: str) -> int:
        ch = self._channels.get(topic)
        if ch is None:
            schema = json.dumps(json_schema(topic), separators=(",", ":")).encode()
            sid = self._writer.register_schema(_SCHEMA_NAMES[topic], "jsonschema", schema)
            ch = self._writer.register_channel(
                topic, "json", sid, metadata={"schema_version": str(SCHEMA_VERSION)}
            )
            self._channels[topic] = ch
        return ch

    def _put(self, topic: str, data: bytes, stamp_ns: int, frame: int) -> None:
        stamp = int(stamp_ns)
        self._writer.add_message(
            self._channel(topic),
            log_time=stamp,
            data=data,
            publish_time=stamp,
            sequence=int(frame) & 0xFFFFFFFF,
        )

    def _tick(self) -> None:
        self._since_flush += 1
        if self._since_flush >= self._flush_every:
            self.flush()

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")

    def write_frame(self, frame: Frame, run: str = "") -> None:
        """Write ``/measurements`` (and ``/truth`` when ``frame.truth`` is not ``None``).

        Both messages are encoded (and validated) before either is written.
        """
        self._check_open()
        meas = encode(frame, run)
        truth = (
            encode(from_truth(frame.frame, frame.stamp_ns, frame.truth, run))
            if frame.truth is not None
            else None
        )
        self.write_encoded_frame(meas, truth, frame.stamp_ns, frame.frame)

    def write_tracks(self, est: Estimate, run: str = "") -> None:
        """Write one ``/tracks`` message."""
        self._check_open()
        self.write_encoded_tracks(encode(est, run), est.stamp_ns, est.frame)

    def write_online_tracks(self, est: Estimate, run: str = "") -> None:
        """Write one ``/tracks_online`` message (:data:`TOPIC_TRACKS_ONLINE`)."""
        schema = json.dumps(json_schema(TOPIC_TRACKS), separators=(",", ":")).encode()
        self.write_message(TOPIC_TRACKS_ONLINE, (_SCHEMA_NAMES[TOPIC_TRACKS], "jsonschema", schema), "json",
                           encode(est, run), est.stamp_ns, est.frame)

    def write_encoded_frame(
        self, measurements: bytes, truth: bytes | None, stamp_ns: int, frame: int
    ) -> None:
        """Write a frame's ``/measurements`` (and ``/truth``) payloads as they are.

        For payloads that were already validated (:mod:`tracker.messages`) (e.g. received and checked
        by the pipeline's sink): the bytes go into the file without decoding or
        re-encoding them.  Same records and flushing as :meth:`write_frame`.
        """
        self._check_open()
        self._put(TOPIC_MEASUREMENTS, measurements, stamp_ns, frame)
        if truth is not None:
            self._put(TOPIC_TRUTH, truth, stamp_ns, frame)
        self.n_frames += 1
        self._tick()

    def write_encoded_tracks(self, tracks: bytes, stamp_ns: int, frame: int) -> None:
        """Write one already validated ``/tracks`` payload as it is (see
        :meth:`write_encoded_frame`)."""
        self._check_open()
        self._put(TOPIC_TRACKS, tracks, stamp_ns, frame)
        self.n_tracks += 1
        self._tick()

    @staticmethod
    def open_at(path: str | os.PathLike) -> "McapLogWriter | None":
        """The writer of this process that has ``path`` open, or ``None``."""
        return _OPEN.get(os.path.realpath(os.fspath(path)))

    def write_message(self, topic: str, schema: tuple[str, str, bytes], message_encoding: str, data: bytes,
                      stamp_ns: int, frame: int) -> None:
        """Write one message of a channel other than bnptrack's own (``schema``: name,
        encoding, data; the channel is registered on its first message), with the times and
        flushing of the frames."""
        self._check_open()
        ch = self._channels.get(topic)
        if ch is None:
            sid = self._writer.register_schema(*schema)
            ch = self._channels[topic] = self._writer.register_channel(topic, message_encoding, sid)
        stamp = int(stamp_ns)
        self._writer.add_message(ch, log_time=stamp, data=data, publish_time=stamp, sequence=int(frame) & 0xFFFFFFFF)
        self._tick()

    def flush(self) -> None:
        """Close the current chunk and flush it to the OS."""
        self._check_open()
        self._writer.flush()
        self._since_flush = 0

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if _OPEN.get(os.path.realpath(self.path)) is self:
            del _OPEN[os.path.realpath(self.path)]
        try:
            self._writer.finish()
        finally:
            self._file.close()
