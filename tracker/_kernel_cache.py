"""Cheaper loads of the kernels numba has cached (start-up; docs/performance.md).

A warm ``bnptrack track`` with the two-level tracker loads 27 compiled kernels from numba's
cache.  :func:`lean_cache_loads` (applied for the command line by
:func:`tracker.numerics.import_numba`, ``LEAN_NUMBA``, when numba is a version it was checked
with, :data:`LEAN_LOADS_VERSIONS`) leaves out three costs of numba's own load that a process
which only runs cached kernels does not need, and one cost of every compile:

* **The parse of each kernel's linking bitcode**.  numba keeps, beside each
  kernel's object code, the LLVM bitcode of its module, to link it into a kernel compiled
  later; at every load it parsed that bitcode and walked its functions and globals through
  llvmlite only to learn which symbols the library defines.  Those names are read from a small
  file beside the cache instead (``links/<sha1 of the bitcode>``, written from the parsed
  module the first time that bitcode is loaded); the bitcode is parsed only if a fresh compile
  links the kernel.
* **The set-up of the compiler's registries**.  numba's ``Cache.load_overload``
  first calls ``target_context.refresh()``, which imports and installs every typing and
  lowering registry (numba's ``cpython``, ``np``, ``typed``, ``experimental`` modules,
  0.3-0.6 s of CPU on this machine) although loading machine code types and lowers nothing.
  The lean load runs only the part a loaded kernel links against, numba's runtime (NRT,
  ``rtsys.initialize``), and checks that every external symbol the kernel's module declares
  (same file) resolves before its object code is linked; if one does not (a symbol that
  numba registers while it sets a registry up), it runs the whole refresh first, as numba
  would have.  A kernel that is compiled (a cache miss) gets the whole set-up from numba's
  compiler, which refreshes the contexts itself.
* **The options of every compile, hashed and compared afresh**: numba's typing keys its cache
  of overload implementations by the compile's ``Flags`` (a ``TargetConfig``), whose hash and
  equality build a dict of all its options each time (:func:`_fast_target_configs`: the same
  results without the dict; this one speeds up a compile, not a load).
* **``numpy.ma``**: numba's ``typeof`` of an ndarray asks
  ``isinstance(val, np.ma.MaskedArray)``, and numpy 2 imports ``numpy.ma`` (0.05-0.12 s) at
  that first attribute access.  An array whose type is exactly ``np.ndarray`` is no masked
  array, so :func:`typeof_ndarray` types it without asking (the rest of numba's function, the
  same types); any subclass goes to numba's own function.

The object code that runs is the cached one, unchanged.
"""

from __future__ import annotations

import hashlib
import os
import sys
import threading
from typing import Any

__all__ = ["lean_cache_loads", "defined_symbols", "external_symbols", "typeof_ndarray", "LEAN_LOADS_VERSIONS"]

#: numba versions whose cache loading :func:`lean_cache_loads` replaces (it mirrors
#: ``CPUCodeLibrary._unserialize``, ``Cache.load_overload`` and ``typeof``'s ndarray case of
#: these versions); any other version is left alone.
LEAN_LOADS_VERSIONS = ("0.68.",)


def lean_cache_loads(cache_dir: str, versions: tuple[str, ...] | None = None) -> bool:
    """Make numba's cache loads lean (see the module's docstring); the link files go to
    ``cache_dir/links``.  Returns whether it applies (set once per process; False for a numba
    version not in ``versions``, by default :data:`LEAN_LOADS_VERSIONS`)."""
    import numba
    from numba.core import caching, codegen

    library = codegen.JITCodeLibrary
    if getattr(library, "_bnptrack_lean", False):
        return True
    if not numba.__version__.startswith(LEAN_LOADS_VERSIONS if versions is None else versions):
        return False
    _lean_unserialize(library, os.path.join(cache_dir, "links"))
    _load_without_refresh(caching.Cache)
    _typeof_without_numpy_ma()
    _fast_target_configs()
    library._bnptrack_lean = True
    return True


def _lean_unserialize(library: type, folder: str) -> None:
    """Replace ``library._unserialize`` (an object-code cache entry) and
    ``_get_module_for_linking`` (parse the bitcode when a compile first links the library)."""
    from numba.core import codegen

    unserialize = library._unserialize.__func__
    for_linking = library._get_module_for_linking

    def _unserialize(cls: type, cg: Any, state: tuple) -> Any:
        """numba's ``CPUCodeLibrary._unserialize`` for an object-code cache entry, less the
        parse and walk of the bitcode when its link file exists, after a check that the
        symbols the module declares resolve (else the registries are set up first)."""
        name, kind, data = state
        if kind != "object":
            _refresh_cpu_target(cg)
            return unserialize(cls, cg, state)
        object_code, shared_bitcode = data
        path = os.path.join(folder, hashlib.sha1(shared_bitcode).hexdigest())
        links, module = _read_links(path), None
        if links is None:
            module = codegen.ll.parse_bitcode(shared_bitcode)
            links = defined_symbols(module), external_symbols(module)
            _write_links(path, *links)
        defined, external = links
        if not _all_resolve(cg, external):
            _refresh_cpu_target(cg)
        lib = cg.create_library(name)
        lib.enable_object_caching()
        lib._set_compiled_object(object_code)
        if module is None:
            lib._bnptrack_bitcode = shared_bitcode  # parsed by _get_module_for_linking if needed
        else:
            lib._shared_module = module
        lib._finalize_final_module()
        cg._engine._defined_symbols.update(defined)
        return lib

    def _get_module_for_linking(self: Any) -> Any:
        bitcode = self.__dict__.pop("_bnptrack_bitcode", None)
        if bitcode is not None:
            self._shared_module = codegen.ll.parse_bitcode(bitcode)
        return for_linking(self)

    library._unserialize = classmethod(_unserialize)
    library._get_module_for_linking = _get_module_for_linking


def _load_without_refresh(cache: type) -> None:
    """Replace ``cache.load_overload``: for the CPU target, numba's runtime is initialised
    (what a loaded kernel links against) instead of the whole ``target_context.refresh()``."""
    from numba.core.registry import cpu_target
    from numba.core.runtime import rtsys

    load_overload = cache.load_overload

    def _load_overload(self: Any, sig: Any, target_context: Any) -> Any:
        if target_context is not cpu_target.target_context:
            return load_overload(self, sig, target_context)
        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)
        return None  # the ``with`` block swallowed an exception (as numba's)

    cache.load_overload = _load_overload


def _refresh_cpu_target(cg: Any) -> None:
    """``refresh()`` of the CPU target context whose codegen is ``cg`` (numba's own set-up of
    every registry: what its load would have run first); nothing for another codegen."""
    from numba.core.registry import cpu_target

    context = cpu_target.target_context
    if context.codegen() is cg:
        context.refresh()


def _all_resolve(cg: Any, names: list[str]) -> bool:
    """Whether the engine of ``cg`` or the process's symbol table (llvmlite's
    ``address_of_symbol``: C libraries, ``add_symbol`` entries) defines every name."""
    from numba.core import codegen

    defined = cg._engine._defined_symbols
    return all(n in defined or codegen.ll.address_of_symbol(n) for n in names)


def defined_symbols(module: Any) -> list[str]:
    """The names numba's ``JitEngine._load_defined_symbols`` takes from an LLVM module: its
    functions and global variables that are not declarations."""
    return [g.name for gs in (module.functions, module.global_variables) for g in gs if not g.is_declaration]


def external_symbols(module: Any) -> list[str]:
    """The symbols an LLVM module declares and another library must define (its function and
    global variable declarations, LLVM's intrinsics ``llvm.*`` left out): what the linking of
    its object code resolves."""
    return [g.name for gs in (module.functions, module.global_variables) for g in gs
            if g.is_declaration and not g.name.startswith("llvm.")]


def _read_links(path: str) -> tuple[list[str], list[str]] | None:
    """The defined and the external names of a link file (``d NAME`` and ``x NAME`` lines,
    ``end`` last), or None if it is missing, incomplete or not of that form."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().split("\n")
    except OSError:
        return None
    if not lines or lines[-1] != "end":
        return None
    defined, external = [], []
    for line in lines[:-1]:
        kind, _, name = line.partition(" ")
        if kind not in ("d", "x") or not name:
            return None
        (defined if kind == "d" else external).append(name)
    return defined, external


def _write_links(path: str, defined: list[str], external: list[str]) -> None:
    """Write a link file atomically (another process may read it meanwhile); a cache folder
    that cannot be written is no error (the next load parses the module again)."""
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = f"{path}.{os.getpid()}.{threading.get_ident()}"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write("\n".join([*(f"d {n}" for n in defined), *(f"x {n}" for n in external), "end"]))
        os.replace(tmp, path)
    except OSError:
        pass


def _fast_target_configs() -> None:
    """numba's ``TargetConfig`` (a compile's ``Flags``) hashed and compared without building the
    dict of its 20-odd options each time: numba's typing keys its cache of overload
    implementations by them and hashes and compares them for every call it types (3-4 % of a
    first compile's CPU).  The same results: numba's hash is that of the sorted option names (the
    class's, whatever the values), its equality that of every option's value, defaults included,
    and two configs of one class whose set values are equal are equal."""
    from numba.core.targetconfig import TargetConfig

    values = TargetConfig.values
    hashes: dict[type, int] = {}

    def __hash__(self: Any) -> int:
        cls = type(self)
        h = hashes.get(cls)
        if h is None:
            h = hashes[cls] = hash(tuple(sorted(cls.options)))
        return h

    def __eq__(self: Any, other: Any) -> Any:
        if not isinstance(other, TargetConfig):
            return NotImplemented
        if type(self) is type(other) and self._values == other._values:
            return True
        return values(self) == values(other)

    TargetConfig.__hash__ = __hash__
    TargetConfig.__eq__ = __eq__


def _typeof_without_numpy_ma() -> None:
    """Register :func:`typeof_ndarray` as numba's ``typeof`` of ``np.ndarray``."""
    import numpy as np
    from numba.core.typing.typeof import typeof_impl

    if typeof_impl.dispatch(np.ndarray) is not typeof_ndarray:
        typeof_impl.register(np.ndarray, typeof_ndarray)


def typeof_ndarray(val: Any, c: Any) -> Any:
    """numba's ``typeof`` of an array (``numba.core.typing.typeof._typeof_ndarray``) without
    its ``isinstance(val, np.ma.MaskedArray)`` test for an array of type exactly ``np.ndarray``
    (no masked array; the test would import ``numpy.ma``); a subclass goes to numba's."""
    from numba.core import errors, types
    from numba.core.typing import typeof as numba_typeof
    from numba.np import numpy_support

    if type(val) is not sys.modules["numpy"].ndarray:
        return numba_typeof._typeof_ndarray(val, c)
    try:
        dtype = numpy_support.from_dtype(val.dtype)
    except errors.NumbaNotImplementedError:
        raise errors.NumbaValueError(f"Unsupported array dtype: {val.dtype}")  # noqa: B904  (as numba)
    layout = numpy_support.map_layout(val)
    return types.Array(dtype, val.ndim, layout, readonly=not val.flags.writeable)
