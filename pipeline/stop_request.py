"""A stop asked for by a signal during an offline run: :class:`StopOnSignal` turns the first
SIGINT (Ctrl-C) or SIGTERM into the end of the run's input, so the run finishes as if its log
ended at that frame (a lagged run publishes its window, every output gets its footer, the
summary is printed); a second signal interrupts at once (:class:`KeyboardInterrupt`)."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterable, Iterator
from types import FrameType, TracebackType
from typing import Any, TypeVar

__all__ = ["StopOnSignal"]

T = TypeVar("T")


class StopOnSignal:
    """A context that holds SIGINT and SIGTERM (main thread only; elsewhere it holds nothing)
    and puts the previous handlers back on exit.  :attr:`signal_name` is the first signal's
    name (``"SIGINT"``), ``None`` while none came."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signal_name: str | None = None
        self.cut_short = False
        """Whether the signal ended the input early (not merely came after its end)."""
        self._old: dict[int, Any] = {}

    def __enter__(self) -> StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._old[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        if self.signal_name is not None:
            raise KeyboardInterrupt  # a second signal: stop now
        self.signal_name = signal.Signals(signum).name

    @property
    def requested(self) -> bool:
        return self.signal_name is not None

    def until_stopped(self, items: Iterable[T]) -> Iterator[T]:
        """``items`` up to the first signal: nothing more is read after it."""
        for item in items:
            if self.signal_name is not None:
                self.cut_short = True
                return
            yield item
