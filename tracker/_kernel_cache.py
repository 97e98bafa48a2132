"""Cheaper loads of the kernels numba has cached (issue 15, start-up; docs/performance.md).

A warm ``bnptrack track`` with the two-level tracker loads 27 compiled kernels from numba's
cache.  numba keeps, beside each kernel's object code, the LLVM bitcode of its module, to link
it into a kernel compiled later; at every load it parses that bitcode and walks all its
functions and globals through llvmlite (hundreds of ctypes calls under the GIL) only to learn
which symbols the library defines.  That was about 40 % of the loads' time.

:func:`lean_cache_loads` reads the symbol names from a small file beside the cache instead
(``symbols/<sha1 of the bitcode>``, written from numba's own walk the first time that bitcode
is loaded) and parses the bitcode only if a fresh compile links the kernel.  The object code
that runs is the cached one, unchanged.  :func:`tracker._numerics.import_numba` applies it for
the command line (``LEAN_NUMBA``) when numba is a version it was checked with
(:data:`LEAN_LOADS_VERSIONS`).
"""

from __future__ import annotations

import hashlib
import os
import threading
from typing import Any

__all__ = ["lean_cache_loads", "defined_symbols", "LEAN_LOADS_VERSIONS"]

#: numba versions whose cache loading :func:`lean_cache_loads` replaces (it mirrors
#: ``CPUCodeLibrary._unserialize`` of these versions); any other version is left alone.
LEAN_LOADS_VERSIONS = ("0.68.",)


def lean_cache_loads(cache_dir: str) -> bool:
    """Make numba's cache loads skip the parse of each kernel's linking bitcode (see the
    module's docstring); the symbol files go to ``cache_dir/symbols``.  Returns whether it
    applies (set once per process; False for a numba version not in :data:`LEAN_LOADS_VERSIONS`)."""
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
        """numba's ``CPUCodeLibrary._unserialize`` for an object-code cache entry, less the
        parse and walk of the bitcode when its symbol file exists."""
        name, kind, data = state
        if kind != "object":
            return unserialize(cls, cg, state)
        object_code, shared_bitcode = data
        path = os.path.join(folder, hashlib.sha1(shared_bitcode).hexdigest())
        names = _read_symbols(path)
        if names is None:  # numba's own load; its parsed module gives the names
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
