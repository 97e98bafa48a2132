"""The error of a log that could not be read to its end (:class:`McapLogError`), shared by the
readers of bnptrack's own logs (:mod:`sources.mcap_log`, which re-exports it) and of ROS 2 /
Foxglove logs (:mod:`sources.robot_log`)."""

from __future__ import annotations

__all__ = ["McapLogError"]


class McapLogError(Exception):
    """A log that could not be read to its end.

    Everything readable before the problem has already been yielded when this is raised.

    Attributes
    ----------
    path: the file.
    kind: ``"truncated"`` (the file ends early), ``"corrupt"`` (unreadable bytes) or
        ``"invalid"`` (a message breaks the schema, or frame indices do not increase).
    offset: byte offset up to which the file was read successfully.
    n_messages: messages read so far (all topics; for ``"invalid"``, the 1-based number of the
        offending message).
    last_frame: last frame index delivered to the caller (``None`` if none).
    reason: what went wrong (for ``"invalid"``, the CodecError text naming topic and frame).
    topic, frame: topic and frame of the offending message, when known.
    run: set by :func:`bnptrack.track` before it raises the error: the ``TrackRun`` of the
        frames read before the problem (``None`` elsewhere).
    """

    run: object = None

    def __init__(
        self,
        path: str,
        kind: str,
        offset: int,
        n_messages: int,
        last_frame: int | None,
        reason: str,
        topic: str | None = None,
        frame: int | None = None,
    ) -> None:
        self.path = path
        self.kind = kind
        self.offset = offset
        self.n_messages = n_messages
        self.last_frame = last_frame
        self.reason = reason
        self.topic = topic
        self.frame = frame
        if kind == "not_mcap":
            super().__init__(f"{path}: not an MCAP file: {reason}")
            return
        what = {"truncated": "truncated", "corrupt": "corrupt data", "invalid": "invalid message"}[kind]
        where = (
            f"after frame {last_frame}" if last_frame is not None else "before the first complete frame"
        )
        super().__init__(
            f"{path}: {what} {where} (message {n_messages}, byte offset {offset}): {reason}"
        )

    def __reduce__(self):
        return (
            type(self),
            (self.path, self.kind, self.offset, self.n_messages, self.last_frame,
             self.reason, self.topic, self.frame),
        )
