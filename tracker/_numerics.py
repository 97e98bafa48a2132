r"""Numerical helpers shared by the trackers: the one JIT switch and the one log-sum-exp.

* :func:`jit` compiles a kernel with numba (``cache=True, nogil=True``) unless numba is
  missing or ``BNPTRACK_NO_JIT=1``: then the same Python function runs interpreted.
  :data:`JIT` says which.  numba itself (0.4 s to import, more on a busy machine) is imported
  at the first call of a kernel, not when a tracker module is imported: a command that only
  builds or describes a tracker (``bnptrack launch``'s checks, ``track --help``) never pays it.
  The kernels are cached in a directory named by a digest of every kernel-defining source
  file (:func:`kernel_cache_dir`): numba checks only a kernel's own file before loading it
  from its cache, so a kernel that calls (inlines) a kernel of another file that has since
  changed would otherwise load stale machine code, or crash.
* :func:`logsumexp` is :math:`\log \sum_i e^{a_i}` computed as
  :math:`t + \log \sum_i e^{a_i - t}`, :math:`t = \max_i a_i` (an all ``-inf`` input gives
  ``-inf``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import threading
from pathlib import Path
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

F = TypeVar("F", bound=Callable)

#: The kernels are compiled (numba present and ``BNPTRACK_NO_JIT`` is not ``1``).
JIT: bool = importlib.util.find_spec("numba") is not None and os.environ.get("BNPTRACK_NO_JIT") != "1"

_lock = threading.Lock()
_pending: list[_LazyKernel] = []
_namespaces: dict[int, dict[str, Any]] = {}  # the modules that define kernels


class _LazyKernel:
    """A kernel compiled with numba on first use.  The first call of any kernel imports numba
    and decorates every kernel defined so far (``njit`` compiles nothing until a call, and then
    loads from the cache); each name of a kernel module that held a lazy kernel is rebound to
    its numba dispatcher, so a compiled kernel that calls another one finds a dispatcher, as if
    they had been decorated at import."""

    def __init__(self, fn: Callable, inline: bool) -> None:
        self.py_func, self.inline, self.dispatcher = fn, inline, None
        self.__wrapped__, self.__name__, self.__qualname__, self.__doc__ = fn, fn.__name__, fn.__qualname__, fn.__doc__

    def __call__(self, *args: Any) -> Any:
        dispatcher = self.dispatcher
        if dispatcher is None:
            dispatcher = _compile_pending(self)
        return dispatcher(*args)


def _compile_pending(kernel: _LazyKernel) -> Any:
    """Decorate every pending kernel with numba and rebind the module names that held them."""
    from numba import config, njit

    with _lock:
        before, config.CACHE_DIR = config.CACHE_DIR, kernel_cache_dir()
        try:  # numba picks a kernel's cache directory when it decorates it
            for k in _pending:
                if k.dispatcher is None:
                    opts = {"inline": "always"} if k.inline else {}
                    k.dispatcher = njit(cache=True, nogil=True, **opts)(k.py_func)
                _namespaces[id(k.py_func.__globals__)] = k.py_func.__globals__
        finally:
            config.CACHE_DIR = before
        _pending.clear()
        for namespace in _namespaces.values():
            for name, value in list(namespace.items()):
                if isinstance(value, _LazyKernel) and value.dispatcher is not None:
                    namespace[name] = value.dispatcher
        assert kernel.dispatcher is not None
        return kernel.dispatcher


_KERNELS_ROOT = Path(__file__).resolve().parent  # every kernel lives in this package


def kernel_sources_digest(root: Path = _KERNELS_ROOT) -> str:
    """SHA-256 (16 hex digits) of the path and bytes of every ``.py`` file under ``root`` that
    defines a kernel (its text contains ``jit(``), in path order."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        text = path.read_bytes()
        if b"jit(" in text:
            digest.update(path.relative_to(root).as_posix().encode() + b"\0" + text + b"\0")
    return digest.hexdigest()[:16]


def kernel_cache_dir() -> str:
    """Where the compiled kernels are cached: ``$NUMBA_CACHE_DIR`` (numba's own setting) or
    ``$XDG_CACHE_HOME/bnptrack/numba`` (``~/.cache/...``), then a folder named by
    :func:`kernel_sources_digest`.  Editing any kernel file starts a fresh folder, so no
    kernel is ever loaded with a stale copy of a kernel it calls from another file.  If the
    folder cannot be written, numba falls back to its usual places."""
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "bnptrack", "numba")
    return os.path.join(base, kernel_sources_digest())


def jit(fn: F, inline: bool = False) -> F:
    """``fn`` compiled with numba (``cache=True, nogil=True``; ``inline="always"`` when
    ``inline``) if :data:`JIT`, else ``fn`` itself (the same code, interpreted).  numba is
    imported at the first call of any kernel (:class:`_LazyKernel`)."""
    if not JIT:
        return fn
    kernel = _LazyKernel(fn, inline)
    with _lock:
        _pending.append(kernel)
    return kernel  # type: ignore[return-value]


def _preload_kernel(x: float) -> float:
    return x + 1.0


_preload_kernel = jit(_preload_kernel)


def preload() -> None:
    """Import numba and set its compiler up now, by calling one small cached kernel: what the
    first call of any kernel pays (0.3-1 s) besides loading that kernel.  The tracker stage
    runs it in a thread while it waits for the source; a no-op without :data:`JIT`."""
    _preload_kernel(1.0)


def logsumexp(a: np.ndarray, axis: int | None = None):
    """:math:`\\log \\sum \\exp(a)` over ``axis`` (an array), or over every entry when
    ``axis`` is ``None`` (a float).  Plain numpy: scipy's has a large per-call overhead on
    small arrays."""
    if axis is None:
        top = float(np.max(a))
        return top + math.log(float(np.sum(np.exp(a - top)))) if math.isfinite(top) else top
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(top, axis=axis) + np.log(np.sum(np.exp(a - top), axis=axis))
