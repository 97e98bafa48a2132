"""Compile a tracker's kernels from the other end, in a second process, on a first run.

A first run compiles every kernel in the process that first calls it, one after the other: one
core busy, the other idle (a pipeline's other stages wait for the tracker).  While it does,
``python -m bnptrack.tracker.precompile NAME`` (started by the command line,
:mod:`pipeline.compile_notice`) compiles the same kernels with the same options into the same
cache folder, from the last one the run will need to the first, as listed with their argument
types in :data:`MANIFEST` (written by ``benchmarks/kernel_manifest.py`` from a run of each
tracker's warm-up).  A kernel it has cached is loaded, not compiled, by the run when it gets
there; it stops at the first kernel it finds already cached (the run has got there), so the
two processes meet in the middle.  The machine code is what the run would have compiled itself
(numba's cache, keyed by signature and options); a manifest that no longer matches the kernels
(another numba version, a changed kernel) only costs the second process's work: the run compiles what
it needs.
"""

from __future__ import annotations

import importlib
import pickle
import sys
from pathlib import Path
from typing import Any

__all__ = ["MANIFEST", "load_manifest", "precompile"]

#: ``{"numba": version, "trackers": {NAME: [(module, qualname, signature), ...]}}`` in the
#: order the tracker's warm-up first compiles them.
MANIFEST = Path(__file__).resolve().parent / "params" / "kernel_manifest.pkl"


def load_manifest(path: Path = MANIFEST) -> dict[str, list[tuple[str, str, Any]]]:
    """The manifest's kernels per tracker, or ``{}`` when it is missing, unreadable or from
    another numba version."""
    import numba

    try:
        with open(path, "rb") as f:
            data = pickle.load(f)
    except Exception:  # noqa: BLE001 - any unreadable manifest only means no help
        return {}
    if not isinstance(data, dict) or data.get("numba") != numba.__version__:
        return {}
    return data.get("trackers", {})


def _dispatcher(module: str, qualname: str) -> Any:
    """The numba dispatcher of the kernel whose Python function is ``module.qualname`` (it may
    be bound under another name: ``_sweeps = jit(_sweep_kernel)``), or None."""
    from bnptrack.tracker import numerics

    importlib.import_module(module)
    for kernel in list(numerics._defined):
        fn = kernel.py_func
        if fn.__module__ == module and fn.__qualname__ == qualname:
            return kernel.dispatcher or numerics._compile_pending(kernel)
    return None


def precompile(tracker: str, manifest: Path = MANIFEST) -> int:
    """Compile tracker ``tracker``'s kernels of the manifest from the last to the first,
    stopping at the first one the run has cached meanwhile (one cached before, or by this
    process as the callee of another, is skipped); return how many it compiled."""
    from bnptrack.tracker import numerics, registry

    entries = load_manifest(manifest).get(tracker, [])
    if not entries:
        return 0
    registry.kind(tracker)
    mine = {str(p) for p in Path(numerics.kernel_cache_dir()).rglob("*.nbi")}  # cached before
    _note_compiles(mine)
    done = 0
    for module, qualname, sig in reversed(entries):
        dispatcher = _dispatcher(module, qualname)
        cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
        if cache_file is None:  # not a cached numba kernel (any more): nothing to do
            continue
        index = str(cache_file._index_path)
        if Path(index).exists() and dispatcher._cache.load_overload(sig, dispatcher.targetctx) is not None:
            if index in mine:
                continue
            break  # the run has got here
        dispatcher.compile(sig)
        done += 1
    return done


def _note_compiles(paths: set[str]) -> None:
    """Add to ``paths`` the index file of every kernel this process compiles from now on
    (its callees included: numba's ``numba:compile`` events)."""
    from numba.core import event

    class _Listener(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            pass

        def on_end(self, ev: event.Event) -> None:
            cache = getattr((ev.data or {}).get("dispatcher"), "_cache", None)
            cache_file = getattr(cache, "_cache_file", None)
            if cache_file is not None:
                paths.add(str(cache_file._index_path))

    event.register("numba:compile", _Listener())


if __name__ == "__main__":  # pragma: no cover - run as a process by pipeline.compile_notice
    numerics_mod = importlib.import_module("bnptrack.tracker.numerics")
    numerics_mod.LEAN_NUMBA = True  # a process that runs the project's kernels only, as the command line
    numerics_mod.import_numba()
    precompile(sys.argv[1])
