"""Finish a file when the process is told to stop: :class:`CloseOnSignal` runs a writer's
``close`` at SIGTERM / SIGINT (footer written), then the signal's previous disposition."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

__all__ = ["CloseOnSignal"]


class CloseOnSignal:
    """SIGTERM / SIGINT handlers (main thread only; elsewhere nothing happens) that call
    ``close`` and then what was installed before: a Python handler is called (SIGINT ->
    KeyboardInterrupt, another writer's handler), the default disposition kills the process by
    the same signal, an ignored signal stays ignored."""

    def __init__(self, close: Callable[[], None]) -> None:
        self._close = close
        self._old_handlers: dict[int, Any] = {}

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                self._old_handlers[sig] = signal.signal(sig, self._on_signal)
            except (ValueError, OSError):  # pragma: no cover - not allowed here
                pass

    def restore(self) -> None:
        """Put the previous handlers back (where ours are still installed)."""
        if threading.current_thread() is not threading.main_thread():
            return
        for sig, old in self._old_handlers.items():
            try:
                if signal.getsignal(sig) == self._on_signal:
                    signal.signal(sig, old)
            except (ValueError, OSError, TypeError):  # pragma: no cover
                pass

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        old = self._old_handlers.get(signum, signal.SIG_DFL)
        try:
            self._close()  # also puts the previous handler back
        finally:
            if callable(old):
                old(signum, frame)  # e.g. SIGINT -> KeyboardInterrupt, or another sink's handler
            elif old == signal.SIG_DFL:
                signal.signal(signum, signal.SIG_DFL)
                os.kill(os.getpid(), signum)  # die by the signal, as without the sink
            # SIG_IGN: stays ignored (the sink is closed all the same)
