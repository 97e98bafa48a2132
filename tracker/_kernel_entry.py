"""Kernels that only other kernels call, compiled without numba's Python wrapper.

numba compiles, beside each kernel's machine code, a wrapper that Python calls: it unboxes
every argument (an array is a dozen fields, each checked), calls the kernel and boxes what it
returns.  A kernel called only by other kernels never runs its wrapper, yet a first run pays
for building, optimising and emitting it: the two-level tracker has 38 such kernels, and their
wrappers were a fifth of the LLVM instructions its first compile optimises (docs/performance.md,
cold start).  :func:`tracker.numerics.jit` with ``kernels_only=True`` compiles
the kernel through numba's pipeline with its lowering told to build no Python wrapper (numba's
``no_cpython_wrapper``); the kernel's own machine code, which its callers link, is the same.

A call from Python still works, by another way: :class:`KernelsOnlyDispatcher` answers it
with a second dispatcher of the same function under the name ``<qualname>_python_entry``
(compiled with its wrapper at its first Python call and cached under that name; numba's
cache keys an entry by signature, not by options, so the two must not share a name).  The
compiled code is the same either way; only such a Python call pays a second compile, which is
why the trackers' own Python code calls none of these kernels (``tests/tracker/
test_kernel_entry.py`` checks it for the two-level and single-level trackers).
"""

from __future__ import annotations

import threading
import types
from collections.abc import Callable
from typing import Any

__all__ = ["kernels_only_dispatcher", "ENTRY_SUFFIX"]

#: The qualname suffix of a kernel's second dispatcher, for Python calls.
ENTRY_SUFFIX = "_python_entry"

_lock = threading.Lock()
_classes: tuple[type, type] | None = None


def _numba_classes() -> tuple[type, type]:
    """(:class:`KernelsOnlyDispatcher`, the compiler of its kernels), defined once numba is
    imported."""
    global _classes
    if _classes is None:
        from numba.core.compiler import Compiler, DefaultPassBuilder
        from numba.core.compiler_machinery import register_pass
        from numba.core.registry import CPUDispatcher
        from numba.core.typed_passes import NativeLowering

        @register_pass(mutates_CFG=True, analysis_only=False)
        class LoweringWithoutWrapper(NativeLowering):
            """numba's lowering with the compile's ``no_cpython_wrapper`` flag set meanwhile:
            the flags the typing saw are those of every other kernel (numba's typing keys its
            cache of overload implementations by them: other flags would compile each
            implementation a second time)."""

            _name = "bnptrack_lowering_without_python_wrapper"

            def run_pass(self, state: Any) -> bool:
                flags = state.flags
                before, flags.no_cpython_wrapper = flags.no_cpython_wrapper, True
                try:
                    return super().run_pass(state)
                finally:
                    flags.no_cpython_wrapper = before

        class KernelsOnlyCompiler(Compiler):
            """numba's nopython pipeline with :class:`LoweringWithoutWrapper`."""

            def define_pipelines(self) -> list:
                pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
                pm.passes = [(LoweringWithoutWrapper if p is NativeLowering else p, d) for p, d in pm.passes]
                pm.finalize()
                return [pm]

        class KernelsOnlyDispatcher(CPUDispatcher):
            """numba's dispatcher of a kernel compiled without its Python wrapper: kernels
            call it as any other; a Python call goes to its second dispatcher
            (:func:`python_entry`), since this one's compiled code has no entry for Python."""

            _python_entry: Any = None
            _decorate_entry: Callable[[Callable], Any]

            def __call__(self, *args: Any) -> Any:
                entry = self._python_entry
                if entry is None:
                    with _lock:
                        if self._python_entry is None:
                            self._python_entry = python_entry(self.py_func, self._decorate_entry)
                    entry = self._python_entry
                return entry(*args)

        _classes = (KernelsOnlyDispatcher, KernelsOnlyCompiler)
    return _classes


def kernels_only_dispatcher(fn: Callable, options: dict[str, Any],
                            decorate_entry: Callable[[Callable], Any]) -> Any:
    """numba's dispatcher of ``fn`` with ``options`` (njit's, ``cache`` included), compiled
    without its Python wrapper; numba's ``config.CACHE_DIR`` must be the kernel cache folder
    meanwhile.  ``decorate_entry`` makes the dispatcher of :func:`python_entry`."""
    dispatcher_class, compiler_class = _numba_classes()
    opts = dict(options)
    cache = opts.pop("cache", False)
    disp = dispatcher_class(py_func=fn, locals={}, targetoptions={**opts, "nopython": True},
                            pipeline_class=compiler_class)
    disp._decorate_entry = decorate_entry
    if cache:
        disp.enable_caching()
    return disp


def python_entry(fn: Callable, decorate: Callable[[Callable], Any]) -> Any:
    """``decorate`` (numba's ``njit`` with the kernels' options, in the kernel cache folder)
    of a copy of ``fn`` named ``<qualname>_python_entry``: compiled with its Python wrapper."""
    copy = types.FunctionType(fn.__code__, fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__qualname__ = fn.__qualname__ + ENTRY_SUFFIX
    copy.__module__, copy.__doc__ = fn.__module__, fn.__doc__
    return decorate(copy)
