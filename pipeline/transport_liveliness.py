"""Liveliness tokens of a stage's :class:`~pipeline.transport.Bus`:
``bnptrack/<run>/alive/<stage>`` (the stage runs) and ``bnptrack/<run>/ready/<stage>`` (it
can process its first frame), declared, watched and waited for.

:class:`Liveliness` is a base class of :class:`~pipeline.transport.Bus` and works on its
state: ``session``, ``prefix``, ``stage``, ``_tokens``, ``_present``, ``_alive_lock``,
``_alive_changed``.  With :mod:`pipeline.transport` and :mod:`pipeline.transport_session`,
the only modules that import zenoh.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

import zenoh

__all__ = ["Liveliness"]


class Liveliness:
    """Declare and watch the run's liveliness tokens (see the module docstring)."""

    def declare_alive(self, kind: str = "alive") -> None:
        """Declare the liveliness token ``bnptrack/<run>/<kind>/<stage>``: ``alive`` once the
        subscriptions exist, ``ready`` once the stage can process its first frame."""
        if kind not in self._tokens:
            self._tokens[kind] = self.session.liveliness().declare_token(f"{self.prefix}{kind}/{self.stage}")

    def _on_token(self, sample: Any) -> None:
        kind, _, name = str(sample.key_expr)[len(self.prefix):].partition("/")
        with self._alive_changed:
            names = self._present.setdefault(kind, set())
            if sample.kind == zenoh.SampleKind.PUT:
                names.add(name)
            else:
                names.discard(name)
            self._alive_changed.notify_all()

    def alive(self, kind: str = "alive") -> set[str]:
        """Stages whose ``alive`` (or ``ready``) token is currently visible."""
        with self._alive_lock:
            return set(self._present.get(kind, ()))

    def wait_alive(self, names: Iterable[str], timeout: float, kind: str = "alive") -> set[str]:
        """Wait until every stage in ``names`` has its ``kind`` token (or ``timeout``); return
        the missing ones."""
        want = set(names)
        deadline = time.monotonic() + timeout
        with self._alive_changed:
            while True:
                missing = want - self._present.get(kind, set())
                left = deadline - time.monotonic()
                if not missing or left <= 0:
                    return missing
                self._alive_changed.wait(min(left, 0.2))
