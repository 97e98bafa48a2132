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
* :func:`gammaln` is ``scipy.special.gammaln`` (the same doubles) without importing
  ``scipy.special`` (see its docstring).
* :func:`unique_ints` is ``np.unique`` of integer keys by a sort (faster on large arrays).
* :func:`logsumexp` is :math:`\log \sum_i e^{a_i}` computed as
  :math:`t + \log \sum_i e^{a_i - t}`, :math:`t = \max_i a_i` (an all ``-inf`` input gives
  ``-inf``).
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import math
import os
import sys
import threading
from pathlib import Path
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import numpy as np

F = TypeVar("F", bound=Callable)

#: The kernels are compiled (numba present and ``BNPTRACK_NO_JIT`` is not ``1``).
JIT: bool = importlib.util.find_spec("numba") is not None and os.environ.get("BNPTRACK_NO_JIT") != "1"

_lock = threading.Lock()
_pending: list[_LazyKernel] = []
_namespaces: dict[int, dict[str, Any]] = {}  # the modules that define kernels
_defined: list[_LazyKernel] = []  # every kernel defined, in order


class _LazyKernel:
    """A kernel compiled with numba on first use.  The first call of any kernel imports numba
    and decorates every kernel defined so far (``njit`` compiles nothing until a call, and then
    loads from the cache); each name of a kernel module that held a lazy kernel is rebound to
    its numba dispatcher, so a compiled kernel that calls another one finds a dispatcher, as if
    they had been decorated at import."""

    def __init__(self, fn: Callable, inline: bool, kernels_only: bool = False) -> None:
        self.py_func, self.inline, self.kernels_only, self.dispatcher = fn, inline, kernels_only, None
        self.__wrapped__, self.__name__, self.__qualname__, self.__doc__ = fn, fn.__name__, fn.__qualname__, fn.__doc__

    def __call__(self, *args: Any) -> Any:
        dispatcher = self.dispatcher
        if dispatcher is None:
            dispatcher = _compile_pending(self)
        return dispatcher(*args)


#: numba's options of every kernel (``no_cfunc_wrapper``: no kernel is called through a C
#: function pointer).
_NJIT_OPTIONS = {"cache": True, "nogil": True, "no_cfunc_wrapper": True}


def _compile_pending(kernel: _LazyKernel) -> Any:
    """Decorate every pending kernel with numba and rebind the module names that held them."""
    import_numba()
    from numba import config, njit

    from bnptrack.tracker._kernel_entry import kernels_only_dispatcher

    with _lock:
        before, config.CACHE_DIR = config.CACHE_DIR, kernel_cache_dir()
        try:  # numba picks a kernel's cache directory when it decorates it
            for k in _pending:
                if k.dispatcher is None:
                    if k.kernels_only:
                        k.dispatcher = kernels_only_dispatcher(k.py_func, _NJIT_OPTIONS, _decorate)
                    else:
                        k.dispatcher = njit(**_NJIT_OPTIONS, **({"inline": "always"} if k.inline else {}))(k.py_func)
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


def _decorate(fn: Callable) -> Any:
    """``fn`` decorated as the kernels are (the Python call of a kernels-only kernel:
    :mod:`tracker._kernel_entry`), cached in the kernel cache folder."""
    from numba import config, njit

    with _lock:
        before, config.CACHE_DIR = config.CACHE_DIR, kernel_cache_dir()
        try:
            return njit(**_NJIT_OPTIONS)(fn)
        finally:
            config.CACHE_DIR = before


def import_numba() -> None:
    """Import numba, first loading scipy's ``cython_blas`` extension module without the
    ``scipy.linalg`` package around it (:func:`scipy_extension`).

    numba's import (``numba.np.arraymath``, at its first compile or cache load) checks that
    BLAS is there with ``import scipy.linalg.cython_blas``, which runs ``scipy.linalg``'s
    ``__init__``: 0.15-0.3 s of CPU (``scipy._lib``'s array-API layer imports ``numpy.f2py``,
    ``numpy.testing``, ...) that no kernel uses.  The module numba then finds is the very one
    that import would have loaded, so numba enables the same BLAS functions and its LAPACK
    width check still runs.  Nothing is done when numba or ``scipy.linalg`` is already
    imported."""
    if "numba" in sys.modules or "scipy.linalg" in sys.modules:
        return
    if importlib.util.find_spec("scipy") is not None:
        scipy_extension("linalg", "cython_blas")
    if not LEAN_NUMBA:
        import numba  # noqa: F401
        return
    from bnptrack.tracker import _kernel_cache

    _import_numba_lean(lambda: _kernel_cache.lean_cache_loads(kernel_cache_dir()))


#: Set by the command line (``bnptrack track``, ``launch``, ``stage``, ``replay``: processes
#: that run no code but the project's): numba's set-up leaves out its optional ``yaml`` and
#: ``cffi`` support (:func:`_import_numba_lean`), and cached kernels load without a parse of
#: their linking bitcode and without the set-up of numba's compiler registries
#: (:func:`tracker._kernel_cache.lean_cache_loads`).
LEAN_NUMBA = False


def _import_numba_lean(lean_loads: Callable[[], bool]) -> None:
    """Import numba with ``yaml``, ``cffi`` and ``colorama`` unimportable meanwhile, then apply
    ``lean_loads`` (:func:`tracker._kernel_cache.lean_cache_loads`); if that does not apply
    (a numba version it was not checked with), set numba's CPU target up as its first cache
    load would (``refresh()`` of the typing and target contexts), still without them.  numba
    imports ``yaml`` only to read a ``.numba_config.yaml`` in the working directory (then left
    importable) and ``cffi`` to compile calls of cffi functions, which no kernel makes
    (``numba.core.typing.cffi_utils`` is imported meanwhile, so numba's cffi support stays off
    in this process); they cost about 50 ms of CPU (pycparser compiles its lexer's regular
    expressions).  With ``colorama``, numba colours the text of every error it raises, and a
    first compile raises (and catches) thousands while it resolves overloads: 2-3 % of a
    compile's CPU, for messages no one reads (an uncaught one still says the same, uncoloured).
    All three are importable again afterwards."""
    blocked = [m for m in ("yaml", "cffi", "colorama") if m not in sys.modules]
    if os.path.isfile(".numba_config.yaml") and "yaml" in blocked:
        blocked.remove("yaml")
    for m in blocked:
        sys.modules[m] = None  # type: ignore[assignment]  # "import m" raises ImportError
    try:
        from numba.core.registry import cpu_target
        from numba.core.typing import cffi_utils  # noqa: F401

        if not lean_loads():
            cpu_target.typing_context.refresh()
            cpu_target.target_context.refresh()
    finally:
        for m in blocked:
            if sys.modules.get(m, 0) is None:
                del sys.modules[m]


def scipy_extension(package: str, name: str) -> Any:
    """scipy's compiled module ``scipy.<package>.<name>`` (e.g. ``optimize._lsap``, whose
    ``linear_sum_assignment`` *is* ``scipy.optimize.linear_sum_assignment``), loaded from its
    file under its full name without running the package's ``__init__`` when that package is
    not imported yet: ``scipy.optimize`` costs 0.3-1 s to import (it imports
    ``scipy.linalg``, ``scipy.spatial``, ``scipy.special``, ...) for one C function.  The
    module is registered in ``sys.modules``, so a later ``import scipy.<package>`` finds it
    (and binds it as the package's attribute, :class:`_BindExtensions`); if its file is not
    where scipy keeps it, the ordinary import is used."""
    full = f"scipy.{package}.{name}"
    with _lock:
        module = sys.modules.get(full)
        if module is not None:
            return module
        if f"scipy.{package}" not in sys.modules:
            module = _load_extension(package, name)
    return module if module is not None else importlib.import_module(full)


def _load_extension(package: str, name: str) -> Any:
    """Load ``scipy/<package>/<name>.<ext>`` as ``scipy.<package>.<name>``, or None."""
    scipy_spec = importlib.util.find_spec("scipy")
    for folder in (scipy_spec.submodule_search_locations or []) if scipy_spec else []:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = os.path.join(folder, package, name + suffix)
            if os.path.isfile(path):
                full = f"scipy.{package}.{name}"
                spec = importlib.util.spec_from_file_location(
                    full, path, loader=importlib.machinery.ExtensionFileLoader(full, path))
                module = importlib.util.module_from_spec(spec)
                sys.modules[full] = module
                try:
                    spec.loader.exec_module(module)
                except BaseException:
                    del sys.modules[full]
                    raise
                _BINDER.bind(f"scipy.{package}", name)
                return module
    return None


class _BindExtensions(importlib.abc.MetaPathFinder):
    """At the first import of a scipy package one of whose modules :func:`scipy_extension`
    loaded alone: the package's own spec, whose module gets those modules bound as attributes
    once it has run (what the import of a submodule does to its package)."""

    def __init__(self) -> None:
        self.pending: dict[str, list[str]] = {}

    def bind(self, package: str, name: str) -> None:
        self.pending.setdefault(package, []).append(name)
        if self not in sys.meta_path:
            sys.meta_path.insert(0, self)

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        names = self.pending.pop(fullname, None)
        if names is None:
            return None
        if not self.pending:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            run = spec.loader.exec_module

            def exec_module(module: Any) -> None:
                run(module)
                for name in names:
                    setattr(module, name, sys.modules[f"{fullname}.{name}"])

            spec.loader.exec_module = exec_module
        return spec


_BINDER = _BindExtensions()


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


def jit(fn: F, inline: bool = False, kernels_only: bool = False) -> F:
    """``fn`` compiled with numba (``cache=True, nogil=True``; ``inline="always"`` when
    ``inline``) if :data:`JIT`, else ``fn`` itself (the same code, interpreted).  numba is
    imported at the first call of any kernel (:class:`_LazyKernel`).  ``kernels_only``: only
    other kernels call it, so numba builds no Python wrapper for it (a Python call compiles a
    second copy: :mod:`tracker._kernel_entry`)."""
    if not JIT:
        return fn
    kernel = _LazyKernel(fn, inline, kernels_only)
    with _lock:
        _pending.append(kernel)
        _defined.append(kernel)
    return kernel  # type: ignore[return-value]


def kernel_bindings(modules: Iterable[Any]) -> list[tuple[Any, str, Callable]]:
    """Every ``(module, name, python function)`` where a module of ``modules`` binds ``name``
    to a kernel (lazy or compiled, also one imported from another module).  Rebinding each name
    to its function runs the code of those modules interpreted, e.g. to compare it with the
    compiled code; empty without :data:`JIT`."""
    return [(module, name, value.py_func) for module in modules for name, value in sorted(vars(module).items())
            if isinstance(value, _LazyKernel) or (_is_dispatcher(value) and callable(getattr(value, "py_func", None)))]


def _is_dispatcher(value: Any) -> bool:
    """Whether ``value`` is a numba dispatcher (one of :mod:`tracker._kernel_entry`'s too)."""
    return any(c.__module__.startswith("numba.") for c in type(value).__mro__[:-1])


def kernel_file_prefixes() -> list[str]:
    """The names numba gives the cache files of every kernel defined so far that compiles on
    its own (not inlined): ``<file stem>.<qualname>-<first line>`` (then ``.py311.nbi``)."""
    with _lock:
        kernels = [k for k in _defined if not k.inline]
    return [f"{Path(k.py_func.__code__.co_filename).stem}.{k.__qualname__}-{k.py_func.__code__.co_firstlineno}"
            for k in kernels]


def _preload_kernel(x: float) -> float:
    return x + 1.0


_preload_kernel = jit(_preload_kernel)


def preload() -> None:
    """Import numba and set its compiler up now, by calling one small cached kernel: what the
    first call of any kernel pays (0.3-1 s) besides loading that kernel.  The tracker stage
    runs it in a thread while it waits for the source; a no-op without :data:`JIT`."""
    _preload_kernel(1.0)


def unique_ints(x: np.ndarray) -> np.ndarray:
    """``np.unique(x)`` of a 1-d integer array, by a sort (the same values in the same order;
    numpy 2's hashing ``unique`` takes tens of times longer on arrays of 10^5-10^6 keys)."""
    s = np.sort(x)
    if s.size < 2:
        return s
    keep = np.empty(s.size, dtype=bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


#: Runs of this many keys are insertion-sorted before :func:`argsort_stable`'s merges.
SORT_RUN = 16


def argsort_stable(keys: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``np.argsort(keys, kind="stable")`` of a 1-d array of floats or integers, for the
    kernels: the same permutation (a stable sort's is unique: equal keys keep their order,
    NaNs go last), by a merge sort (runs of :data:`SORT_RUN` keys insertion-sorted, then
    merged bottom-up).  One small kernel compiled once into the kernel cache, where numba's
    own ``np.argsort`` and ``np.sort`` compile their generic sort code afresh in every process
    (about 1 s of CPU each); a kernel sorts values as ``x[argsort_stable(x)]``."""
    n = keys.shape[0]
    src = np.empty(n, dtype=np.int64)
    for i in range(n):
        src[i] = i
    for lo in range(0, n, SORT_RUN):
        hi = min(lo + SORT_RUN, n)
        for i in range(lo + 1, hi):
            v = src[i]
            key = keys[v]
            j = i
            while j > lo:  # shift while key < the previous key (NaN: greater than any number)
                prev = keys[src[j - 1]]
                if not (key < prev or (prev != prev and key == key)):
                    break
                src[j] = src[j - 1]
                j -= 1
            src[j] = v
    if n <= SORT_RUN:
        return src
    dst = np.empty(n, dtype=np.int64)
    width = SORT_RUN
    while width < n:
        for lo in range(0, n, 2 * width):
            mid, hi = min(lo + width, n), min(lo + 2 * width, n)
            i, j = lo, mid
            for k in range(lo, hi):  # the right run's key first only when strictly less
                if j < hi and (i == mid or keys[src[j]] < keys[src[i]]
                               or (keys[src[i]] != keys[src[i]] and keys[src[j]] == keys[src[j]])):
                    dst[k] = src[j]
                    j += 1
                else:
                    dst[k] = src[i]
                    i += 1
        src, dst = dst, src
        width *= 2
    return src


argsort_stable = jit(argsort_stable, kernels_only=True)


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


# --------------------------------------------------------------------------- gammaln
# scipy.special costs 0.25-0.5 s to import (its array-API layer imports numpy.f2py and
# numpy.testing; docs/performance.md, start-up), and the DDP-EMM's (alpha, d) grid
# (tracker.bnp.urn, tracker.bnp.group_hyper) is its only user on the tracking path.  scipy
# evaluates gammaln with Cephes' lgam (S. L. Moshier, Cephes Math Library 2.2; scipy's
# xsf::cephes::lgam); _lgam is that algorithm for 0 < x <= MAXLGM with the same constants and
# the same order of every floating-point operation (log is the C library's, which numba calls
# too), so its results are the same doubles (tests/tracker/test_gammaln.py compares millions).

#: log(sqrt(2 pi)), and the largest argument with a finite result (Cephes' MAXLGM).
_LS2PI = 0.91893853320467274178
_MAXLGM = 2.556348e305


def _lgam(x: float) -> float:  # pragma: no cover - compiled
    """Cephes' ``lgam`` for ``0 < x <= MAXLGM``: recurrence to ``[2, 3)`` and a rational
    approximation below 13, Stirling's series above (its short form above 1000)."""
    if x < 13.0:
        z, p, u = 1.0, 0.0, x
        while u >= 3.0:
            p -= 1.0
            u = x + p
            z *= u
        while u < 2.0:
            z /= u
            p += 1.0
            u = x + p
        if u == 2.0:
            return math.log(z)
        p -= 2.0
        x = x + p
        num = -1.37825152569120859100e3
        num = num * x - 3.88016315134637840924e4
        num = num * x - 3.31612992738871184744e5
        num = num * x - 1.16237097492762307383e6
        num = num * x - 1.72173700820839662146e6
        num = num * x - 8.53555664245765465627e5
        den = x - 3.51815701436523470549e2
        den = den * x - 1.70642106651881159223e4
        den = den * x - 2.20528590553854454839e5
        den = den * x - 1.13933444367982507207e6
        den = den * x - 2.53252307177582951285e6
        den = den * x - 2.01889141433532773231e6
        return math.log(z) + x * num / den
    q = (x - 0.5) * math.log(x) - x + _LS2PI
    if x >= 1000.0:
        if x > 1.0e8:
            return q
        p = 1.0 / (x * x)
        return q + ((7.9365079365079365079365e-4 * p - 2.7777777777777777777778e-3) * p
                    + 0.0833333333333333333333) / x
    p = 1.0 / (x * x)
    a = 8.11614167470508450300e-4
    a = a * p - 5.95061904284301438324e-4
    a = a * p + 7.93650340457716943945e-4
    a = a * p - 2.77777777730099687205e-3
    a = a * p + 8.33333333333331927722e-2
    return q + a / x


def _lgam_array(x: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[i] = _lgam(x[i])`` over two flat arrays."""
    for i in range(x.size):
        out[i] = _lgam(x[i])


_lgam = jit(_lgam, inline=True)
_lgam_array = jit(_lgam_array)


def gammaln(x: float | np.ndarray) -> np.ndarray:
    r""":math:`\log |\Gamma(x)|` elementwise, as ``scipy.special.gammaln(x)`` (the same doubles,
    the same shape; a 0-d input gives a numpy scalar) without importing ``scipy.special``:
    compiled Cephes ``lgam`` for ``0 < x <= MAXLGM``; scipy's own function for any other
    argument (``x <= 0``, NaN, infinite) and in the interpreted mode (``BNPTRACK_NO_JIT=1``)."""
    x = np.asarray(x, dtype=float)
    flat = np.ascontiguousarray(x).reshape(-1)
    if not JIT or not bool(np.all((flat > 0.0) & (flat <= _MAXLGM))):
        from scipy.special import gammaln as scipy_gammaln  # the general case: scipy's own

        return scipy_gammaln(x)
    out = np.empty_like(flat)
    _lgam_array(flat, out)
    return out.reshape(x.shape)[()]
