"""The first run of a tracker on a machine compiles its numba kernels: say so, and show it.

:func:`compile_progress` (``track``, ``launch``, ``replay``) prints one line when tracker
``NAME``'s kernels have not been compiled into this version's kernel cache folder yet
(:func:`tracker.numerics.kernel_cache_dir`; a file ``compiled-NAME`` there marks a run of
``NAME`` that finished), then, at most once a second while the count changes, how many of the
kernels not cached yet are compiled (numba writes one index file ``*.nbi`` per compiled
kernel, from whichever process compiles it: the command's own or a pipeline's tracker stage),
and at the end how many it compiled in how long.  Each tracker's first run says it (a run of
``ddp`` compiles no GLMB kernel), but a tracker whose kernels are all cached already (``dpyp``
after ``ddp``: they share them) and a warm cache print nothing.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO

__all__ = ["compile_progress", "CompileProgress", "FirstCompile"]

#: Seconds between two progress lines (at most).
INTERVAL_S = 1.0


class CompileProgress:
    """Counts the index files that appear in ``folder`` against ``total`` kernels to compile,
    printing a line to ``out`` at most every :data:`INTERVAL_S` seconds when the count changed."""

    def __init__(self, tracker: str, folder: Path, total: int, out: TextIO | None) -> None:
        self.tracker, self.folder, self.total, self.out = tracker, folder, total, out
        self.before = _index_files(folder)
        self.t0 = time.monotonic()
        self.done = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="compile-progress", daemon=True)
        self.helper: subprocess.Popen | None = None

    def start(self, helper: bool) -> None:
        self._say(f"first run of tracker {self.tracker} with this version on this machine: compiling "
                  f"its numba kernels once (up to {self.total}); later runs load them from {self.folder}")
        self._thread.start()
        self.helper = _start_helper(self.tracker) if helper else None

    def _count(self) -> int:
        return len(_index_files(self.folder) - self.before)

    def _watch(self) -> None:
        while not self._stop.wait(INTERVAL_S):
            n = self._count()
            if n != self.done:
                self.done = n
                self._say(f"compiling kernels: {n}/{self.total} done ({time.monotonic() - self.t0:.0f} s)")

    def finish(self, ok: bool) -> None:
        """Stop watching; after a run that finished (``ok``), say how many kernels compiled and
        mark the tracker's kernels as compiled."""
        self._stop.set()
        self._thread.join()
        if self.helper is not None and self.helper.poll() is None:  # the run failed early
            self.helper.terminate()
            self.helper.wait()
        if not ok:
            return
        n, took = self._count(), time.monotonic() - self.t0
        if n:
            self._say(f"compiled {n} kernels in {took:.0f} s (cached in {self.folder})")
        else:  # a run that called none of them (no frame, or none of that kind)
            self._say(f"compiled no kernel: the run called none of the {self.total} not cached yet ({took:.0f} s)")
        mark_compiled(self.folder, self.tracker)

    def _say(self, text: str) -> None:
        if self.out is not None:
            print(f"bnptrack: {text}", file=self.out, flush=True)


def mark_compiled(folder: Path, tracker: str) -> None:
    """Mark tracker ``tracker``'s kernels as compiled in ``folder`` (no message on later runs)."""
    with contextlib.suppress(OSError):
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"compiled-{tracker}").write_text("")


def _start_helper(tracker: str) -> subprocess.Popen | None:
    """Start :mod:`tracker.precompile` for ``tracker`` (it compiles the kernels from the other
    end on the other core), or None when the manifest does not list the tracker."""
    from bnptrack.tracker.precompile import MANIFEST

    if not MANIFEST.is_file():
        return None
    try:
        return subprocess.Popen([sys.executable, "-m", "bnptrack.tracker.precompile", tracker],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None


def _index_files(folder: Path) -> set[str]:
    """The numba index files under ``folder`` (one per compiled kernel)."""
    try:
        return {str(p) for p in folder.rglob("*.nbi")}
    except OSError:
        return set()


def _uncached_kernels(tracker: str, folder: Path) -> int:
    """How many of the kernels defined once tracker ``tracker``'s modules are imported have no
    index file in ``folder`` yet (an upper bound of what the run compiles)."""
    from bnptrack.tracker import numerics, registry

    with contextlib.suppress(ValueError):  # an unknown name is reported by the build
        registry.kind(tracker)
    names = {os.path.basename(p) for p in _index_files(folder)}
    return sum(1 for prefix in numerics.kernel_file_prefixes()
               if not any(n.startswith(prefix + ".py") for n in names))


class FirstCompile:
    """:class:`CompileProgress` begun when a run is past its checks (:meth:`begin`, at most
    once; ``launch`` / ``replay`` call it at the launcher's first status after them, so an
    error in the configuration prints nothing of it) and ended with the run (:meth:`end`)."""

    def __init__(self, tracker: str, quiet: bool, out: TextIO | None = None, helper: bool = True) -> None:
        self.tracker, self.quiet, self.out, self.helper = tracker, quiet, out, helper
        self.progress: CompileProgress | None = None
        self._begun = False

    def begin(self) -> None:
        from bnptrack.tracker import registry
        from bnptrack.tracker.numerics import JIT, kernel_cache_dir

        if self._begun:
            return
        self._begun = True
        folder = Path(kernel_cache_dir())
        if not JIT or self.tracker not in registry.TRACKERS or (folder / f"compiled-{self.tracker}").exists():
            return
        total = _uncached_kernels(self.tracker, folder)
        if total == 0:  # every kernel is cached already (another tracker's run compiled the ones it shares)
            mark_compiled(folder, self.tracker)
            return
        self.progress = CompileProgress(self.tracker, folder, total, None if self.quiet else self.out or sys.stderr)
        self.progress.start(self.helper)

    def end(self, ok: bool) -> None:
        if self.progress is not None:
            self.progress.finish(ok)
            self.progress = None


@contextlib.contextmanager
def compile_progress(tracker: str, quiet: bool, out: TextIO | None = None, helper: bool = True) -> Iterator[None]:
    """Show the compilation of tracker ``tracker``'s kernels while the block runs, on its
    first run on this machine (see the module's docstring; nothing printed with ``quiet``),
    with (``helper``) the second process of :mod:`tracker.precompile` compiling them from the
    other end; nothing at all without numba, for an unknown tracker or once the tracker has run
    here."""
    first = FirstCompile(tracker, quiet, out, helper)
    first.begin()
    ok = False
    try:
        yield
        ok = True
    finally:
        first.end(ok)
