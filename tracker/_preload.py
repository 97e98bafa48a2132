"""Cheaper loads of the cached numba kernels, and loading them in a thread (issue 15, start-up).

A warm ``bnptrack track`` with the two-level tracker loads about 27 compiled kernels from
numba's cache, about 10 ms each, besides numba's import and set-up (0.3-0.5 s).  Two things
make that cheaper, neither changing a bit of the machine code that runs:

* :func:`lean_cache_loads`: numba keeps, beside each kernel's object code, the LLVM bitcode of
  its module for linking it into a kernel compiled later; at every load it parses that bitcode
  and walks all its functions and globals through llvmlite (hundreds of ctypes calls under the
  GIL) only to learn which symbols the library defines.  Here the symbol names are read from a
  small file beside the cache (``symbols/<sha1 of the bitcode>``, written by numba's own walk
  the first time that bitcode is seen), and the bitcode is parsed only if a fresh compile links
  the kernel.  Applied by :func:`tracker._numerics.import_numba` for the command line
  (``LEAN_NUMBA``) when numba is a version it was checked with.
* :func:`start`: a thread that imports numba, sets its CPU target up and loads the kernels the
  previous run of the same command used (a list kept beside the cache,
  ``preload/<key>.json``), while the main thread imports, opens the log and builds the tracker.
  The first kernel call waits until numba is set up and the kernels known to the thread are
  decorated (``_numerics._setup_wait``); a kernel not yet loaded then is loaded by whichever
  thread calls it first (numba's compiler lock).  :meth:`Preload.finish` joins the thread and
  writes the list for the next run.  A failure in the thread is reported on one line of
  stderr and the run goes on as without it.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from bnptrack.tracker import _numerics

__all__ = ["Preload", "start", "preloading", "lean_cache_loads", "loaded_kernels", "LEAN_LOADS_VERSIONS"]

#: numba versions whose cache loading :func:`lean_cache_loads` replaces (it mirrors
#: ``CPUCodeLibrary._unserialize`` of these versions); any other version is left alone.
LEAN_LOADS_VERSIONS = ("0.68.",)


# --------------------------------------------------------------------------- symbols


def lean_cache_loads(cache_dir: str) -> bool:
    """Make numba's cache loads skip the parse of each kernel's linking bitcode (see the
    module's docstring); the symbol files go to ``cache_dir/symbols``.  Returns whether it
    applied (once per process; False for a numba version not in :data:`LEAN_LOADS_VERSIONS`)."""
    import numba
    from numba.core import codegen

    library = codegen.JITCodeLibrary
    if getattr(library, "_bnptrack_lean", False):
        return True
    if not numba.__version__.startswith(LEAN_LOADS_VERSIONS):
        return False
    unserialize = library._unserialize.__func__
    for_linking = library._get_module_for_linking
    folder = os.path.join(cache_dir, "symbols")

    def _unserialize(cls: type, cg: Any, state: tuple) -> Any:
        name, kind, data = state
        if kind != "object":
            return unserialize(cls, cg, state)
        object_code, shared_bitcode = data
        path = os.path.join(folder, hashlib.sha1(shared_bitcode).hexdigest())
        names = _read_symbols(path)
        if names is None:  # numba's own load, whose walk of the module gives the names
            lib = unserialize(cls, cg, state)
            _write_symbols(path, defined_symbols(lib._shared_module))
            return lib
        lib = cg.create_library(name)
        lib.enable_object_caching()
        lib._set_compiled_object(object_code)
        lib._bnptrack_bitcode = shared_bitcode  # parsed by _get_module_for_linking if needed
        lib._finalize_final_module()
        cg._engine._defined_symbols.update(names)
        return lib

    def _get_module_for_linking(self: Any) -> Any:
        bitcode = self.__dict__.pop("_bnptrack_bitcode", None)
        if bitcode is not None:
            self._shared_module = codegen.ll.parse_bitcode(bitcode)
        return for_linking(self)

    library._unserialize = classmethod(_unserialize)
    library._get_module_for_linking = _get_module_for_linking
    library._bnptrack_lean = True
    return True


def defined_symbols(module: Any) -> list[str]:
    """The names numba's ``JitEngine._load_defined_symbols`` takes from an LLVM module: its
    functions and global variables that are not declarations."""
    return [g.name for gs in (module.functions, module.global_variables) for g in gs if not g.is_declaration]


def _read_symbols(path: str) -> list[str] | None:
    """The names in a symbol file (one a line, ``end`` last), or None if it is missing or
    incomplete."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().split("\n")
    except OSError:
        return None
    return lines[:-1] if lines and lines[-1] == "end" else None


def _write_symbols(path: str, names: list[str]) -> None:
    """Write a symbol file atomically (another process may read it meanwhile); a cache folder
    that cannot be written is no error (the next load walks the module again)."""
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = f"{path}.{os.getpid()}.{threading.get_ident()}"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write("\n".join([*names, "end"]))
        os.replace(tmp, path)
    except OSError:
        pass


# --------------------------------------------------------------------------- preloading


def _dispatchers() -> list[tuple[str, str, Any]]:
    """(module, name, dispatcher) of every kernel decorated so far, in definition order; a
    kernel inlined into its callers (``inline="always"``) is never loaded by itself."""
    from numba.core.dispatcher import Dispatcher

    out = []
    for namespace in list(_numerics._namespaces.values()):
        module = namespace.get("__name__", "")
        for name, value in list(namespace.items()):
            if (isinstance(value, Dispatcher) and value.py_func.__name__ == name
                    and value.py_func.__module__ == module and value.targetoptions.get("inline") != "always"):
                out.append((module, name, value))
    return out


def loaded_kernels() -> list[list[str]]:
    """[module, kernel, signature] of every kernel signature loaded or compiled so far."""
    if "numba" not in sys.modules:
        return []
    return [[module, name, str(tuple(sig))] for module, name, d in _dispatchers() for sig in d.signatures]


def _imported(name: str) -> bool:
    """Whether module ``name`` is imported and done initialising."""
    module = sys.modules.get(name)
    return module is not None and not getattr(getattr(module, "__spec__", None), "_initializing", False)


def _load_listed(entries: list[list[str]]) -> int:
    """Load each listed kernel signature from numba's cache (those the cache index holds);
    returns how many."""
    n = 0
    for module, name, sig in entries:
        dispatcher = getattr(sys.modules[module], name)
        index = dispatcher._cache._cache_file._load_index()
        magic = dispatcher.targetctx.codegen().magic_tuple()
        for key in index:
            if key[1] == magic and str(key[0]) == sig:
                dispatcher.compile(key[0])
                n += 1
    return n


class Preload:
    """The loading thread of :func:`start` and the list of kernels of its ``key``.

    The thread imports numba and sets it up at once (no module of the project is imported
    there), then waits for :meth:`go` (the main thread has imported the tracker: two threads
    importing the same modules could each see the other's half-initialised ones), decorates the
    kernels and loads the listed ones of the modules imported by then."""

    def __init__(self, key: str, folder: Path) -> None:
        self.path = folder / "preload" / f"{key}.json"
        self.listed: list[list[str]] = []
        self.error: BaseException | None = None
        self.loaded = 0
        self._go, self._ready = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"kernel-preload-{key}", daemon=True)

    def _run(self) -> None:
        try:
            try:
                self.listed = json.loads(self.path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                self.listed = []
            _numerics.import_numba()
            self._go.wait()
            _numerics.decorate_pending()
            self._ready.set()
            self.loaded = _load_listed([e for e in self.listed if _imported(e[0])])
        except BaseException as exc:  # reported by wait_setup / finish, in the main thread
            self.error = exc
        finally:
            self._ready.set()

    def go(self) -> None:
        """The main thread has imported the tracker's modules: decorate and load the kernels."""
        self._go.set()

    def wait_setup(self) -> None:
        """Block until numba is set up and the listed kernels are decorated (the first kernel
        call runs this); a failure of the thread is reported on one line and forgotten."""
        if threading.current_thread() is self._thread:
            return
        self._go.set()
        self._ready.wait()
        if _numerics._setup_wait == self.wait_setup:
            _numerics._setup_wait = None
        self._report()

    def _report(self) -> None:
        if self.error is not None:
            exc, self.error = self.error, None
            msg = str(exc).splitlines()[0] if str(exc) else ""
            print(f"bnptrack: loading the compiled kernels ahead failed, they load on first use: "
                  f"{type(exc).__name__}: {msg}", file=sys.stderr)

    def finish(self, record: bool = True) -> None:
        """Join the thread and, with ``record``, keep the list of the kernels this process
        loaded for the next run of the same key (if it changed)."""
        self._go.set()
        self._thread.join()
        if _numerics._setup_wait == self.wait_setup:
            _numerics._setup_wait = None
        self._report()
        if record:
            used = loaded_kernels()
            if used and used != self.listed:
                _write_json(self.path, used)


def _write_json(path: Path, value: Any) -> None:
    """Write ``value`` as JSON atomically; a folder that cannot be written is no error."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}")
        tmp.write_text(json.dumps(value), encoding="utf-8")
        os.replace(tmp, path)
    except OSError:
        pass


def start(key: str, folder: Callable[[], str] = _numerics.kernel_cache_dir) -> Preload | None:
    """Start loading, in a thread, numba and the kernels the last run of ``key`` (e.g.
    ``track-ddp``) used; None without :data:`tracker._numerics.JIT` or once numba is imported
    (nothing left to overlap).  Call :meth:`Preload.finish` when the work is done."""
    if not _numerics.JIT or "numba" in sys.modules or _numerics._setup_wait is not None:
        return None
    preload = Preload(key, Path(folder()))
    _numerics._setup_wait = preload.wait_setup
    preload._thread.start()
    return preload


@contextmanager
def preloading(key: str) -> Iterator[Preload | None]:
    """:func:`start` for the ``with`` block, then :meth:`Preload.finish` (the list of kernels is
    kept only if the block ends normally)."""
    preload = start(key)
    ok = False
    try:
        yield preload
        ok = True
    finally:
        if preload is not None:
            preload.finish(record=ok)
