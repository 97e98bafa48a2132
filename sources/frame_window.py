"""Which frames of a source a run reads: a window in seconds of log time or in frame numbers,
and a frame count (``replay --start/--end``, ``track --start/--end``, ``source.KEY`` of
``--set`` in every command).

Written once here so that ``replay`` (the pipeline's source stage) and offline ``track`` cut a
log the same way: ``bnptrack track LOG --end 40f`` tracks the frames ``replay LOG --end 40f``
publishes.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from itertools import islice
from typing import Annotated

import msgspec

from bnptrack.tracker.types import Frame

__all__ = ["FrameWindow", "WINDOW_KEYS"]

_NonNeg = Annotated[float, msgspec.Meta(ge=0)]
_NonNegInt = Annotated[int, msgspec.Meta(ge=0)]


class FrameWindow(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``start_s`` / ``end_s``: keep the frames whose time stamp is that many seconds after the
    first frame's or more / or less (log time, both ends included); ``start_frame`` /
    ``end_frame``: the frame numbers in that range (seconds and frames are not mixed at one
    end); ``frames`` > 0: stop after that many frames of the window."""

    frames: _NonNegInt = 0
    start_s: _NonNeg | None = None
    end_s: _NonNeg | None = None
    start_frame: _NonNegInt | None = None
    end_frame: _NonNegInt | None = None

    @classmethod
    def of(cls, settings: object) -> FrameWindow:
        """The window of any settings object with these fields (e.g. the pipeline's
        ``SourceConfig``)."""
        return cls(**{key: getattr(settings, key) for key in WINDOW_KEYS})

    def check(self, prefix: str = "source.") -> None:
        """Raise ``ValueError`` (one line, keys named with ``prefix``) for a window that mixes
        seconds and frames at one end or ends before it starts."""
        for end in ("start", "end"):
            if getattr(self, f"{end}_s") is not None and getattr(self, f"{end}_frame") is not None:
                raise ValueError(f"{prefix}{end}_s and {prefix}{end}_frame: give the {end} in seconds or "
                                 "in frames, not both")
        if self.start_s is not None and self.end_s is not None and self.end_s < self.start_s:
            raise ValueError(f"{prefix}end_s = {self.end_s:g} is before {prefix}start_s = {self.start_s:g}")
        if self.start_frame is not None and self.end_frame is not None and self.end_frame < self.start_frame:
            raise ValueError(f"{prefix}end_frame = {self.end_frame} is before {prefix}start_frame = "
                             f"{self.start_frame}")

    def describe(self, prefix: str = "source.", typed: Mapping[str, str] | None = None) -> str:
        """The keys that are set, e.g. ``source.start_frame = 500, source.frames = 3``; a key
        in ``typed`` as the option that set it (``--start 200s``)."""
        typed = typed or {}
        return ", ".join(typed.get(key) or f"{prefix}{key} = {getattr(self, key):g}" for key in WINDOW_KEYS
                         if getattr(self, key) not in (None, 0))

    def check_not_empty(self, frames: Iterable[Frame], log: str, prefix: str = "source.",
                        typed: Mapping[str, str] | None = None) -> None:
        """Raise ``ValueError`` (one line naming ``log`` and the window) when the window holds
        none of ``frames`` (read up to the window's first frame, or to the end when it has none;
        pass a fresh iterator: what is read is consumed).  ``typed``: as in :meth:`describe`."""
        if next(self.cut(frames), None) is None:
            raise ValueError(self.no_frame(log, prefix, "; `bnptrack info LOG` lists a log's frames and times",
                                           typed))

    def no_frame(self, what: str, prefix: str = "source.", hint: str = "",
                 typed: Mapping[str, str] | None = None) -> str:
        """The one-line error of a window that holds no frame of ``what``."""
        return f"{what}: no frame in the window {self.describe(prefix, typed) or '(all frames)'}{hint}"

    def cut(self, frames: Iterable[Frame]) -> Iterator[Frame]:
        """The window's frames of ``frames``, read no further than its end (call :meth:`check`
        first)."""
        frames = iter(frames)
        if self.start_s is not None or self.end_s is not None or self.start_frame is not None \
                or self.end_frame is not None:
            frames = self._between(frames)
        return islice(frames, self.frames) if self.frames else frames

    def _between(self, frames: Iterator[Frame]) -> Iterator[Frame]:
        stamp0 = None
        for frame in frames:
            if stamp0 is None:
                stamp0 = frame.stamp_ns
            t = (frame.stamp_ns - stamp0) / 1e9
            if (self.end_s is not None and t > self.end_s) or (self.end_frame is not None and frame.frame > self.end_frame):
                return
            if (self.start_s is None or t >= self.start_s) and (self.start_frame is None or frame.frame >= self.start_frame):
                yield frame


#: The ``source.KEY`` settings of a window, in every command's ``--set``.
WINDOW_KEYS = tuple(FrameWindow.__struct_fields__)
