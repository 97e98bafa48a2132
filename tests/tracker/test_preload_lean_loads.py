"""``tracker._kernel_cache`` (the command line's lean loads): kernels loaded from numba's
cache without parsing their linking bitcode and without the set-up of numba's registries
(``refresh``) give the symbols and results numba's own load gives, a kernel compiled later
still links them, a kernel whose module declares a symbol that does not resolve gets the set-up
first, a numba version the lean loads were not checked with gets numba's own path, and
``bnptrack track`` writes the same /tracks either way.  Each load runs in a fresh interpreter
with its own numba cache folder."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from testkit import REPO_ROOT

#: subprocess probes of the kernel loading machinery (docs/testing.md, markers)
pytestmark = pytest.mark.slow

_KERNELS = '''
import math
import numpy as np
from numba import njit

@njit(cache=True)
def lgam_sum(x):
    s = 0.0
    for v in x:
        s += math.lgamma(v)
    return s

@njit(cache=True)
def roots(n):  # allocates (numba's runtime) and hashes a string (numba's hash secret)
    out = np.empty(n)
    for i in range(n):
        out[i] = math.sqrt(i + 0.5)
    return out, hash("ab" * n)
'''

_LOAD_PROBE = """
import json, sys
sys.path.insert(0, {folder!r})
import numpy as np
from bnptrack.tracker import _kernel_cache
import numba
from numba.core import base
from numba.core.registry import cpu_target
lean = {lean!r} and _kernel_cache.lean_cache_loads({cache!r})
refreshes = []
refresh = base.BaseContext.refresh
base.BaseContext.refresh = lambda self: refreshes.append(1) or refresh(self)
import kernels_mod
from numba import njit
total = kernels_mod.lgam_sum(np.arange(1.0, 6.0))
out, h = kernels_mod.roots(3)
hits = sum(kernels_mod.lgam_sum.stats.cache_hits.values()) + sum(kernels_mod.roots.stats.cache_hits.values())
engine = cpu_target.target_context.codegen()._engine
names = sorted(engine._defined_symbols)
before_compile = [len(refreshes), "numpy.ma" in sys.modules]

@njit
def twice(x):  # compiled here, not cached: links the loaded kernel's module
    return 2.0 * kernels_mod.lgam_sum(x)

print(json.dumps([lean, total, hits, names, twice(np.arange(1.0, 6.0)), out.tolist(), h, before_compile]))
"""


def _python(code: str, env: dict[str, str] | None = None, cwd: Path = REPO_ROOT) -> subprocess.CompletedProcess:
    base = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    base.pop("BNPTRACK_NO_JIT", None)
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, env={**base, **(env or {})},
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def _load_runs(tmp_path: Path, leans: tuple[bool, ...], cache: Path | None = None) -> list[list]:
    """One fresh interpreter per entry of ``leans`` running :data:`_LOAD_PROBE` (hash seed 0)."""
    (tmp_path / "kernels_mod.py").write_text(_KERNELS)
    cache = cache or tmp_path / "cache"
    env = {"NUMBA_CACHE_DIR": str(cache), "PYTHONHASHSEED": "0"}
    runs = []
    for lean in leans:
        code = _LOAD_PROBE.format(folder=str(tmp_path), lean=lean, cache=str(cache))
        runs.append(json.loads(_python(code, env).stdout.strip().splitlines()[-1]))
    return runs


def test_lean_loads_give_numbas_symbols_and_results(tmp_path: Path) -> None:
    """Cached kernels loaded the lean way define exactly the symbols numba's own load defines
    and compute the same values (the sum of log 0! .. log 4!; three square roots in a new
    array and a string hash) as the compiling run (the cache miss), without a ``refresh`` of
    numba's registries and without ``numpy.ma``; a kernel compiled afterwards that calls one
    links and runs; the link files are written by the first load."""
    runs = _load_runs(tmp_path, (False, False, True, True))  # compile, numba's load, lean loads
    assert [r[0] for r in runs] == [False, False, True, True]
    assert [r[2] for r in runs] == [0, 2, 2, 2]  # compiled once, then loaded from the cache
    assert abs(runs[0][1] - math.log(288.0)) < 1e-12  # log(0! 1! 2! 3! 4!)
    assert runs[0][5] == [math.sqrt(0.5), math.sqrt(1.5), math.sqrt(2.5)]
    for _lean, total, _hits, _names, twice, out, h, _before in runs:  # bit for bit the compiling run's
        assert total == runs[0][1] and twice == 2.0 * runs[0][1] and out == runs[0][5] and h == runs[0][6]
    assert runs[3][3] == runs[1][3]  # the lean load's symbols are numba's
    assert runs[0][7][0] > 0 and runs[1][7][0] > 0  # numba's compile and numba's load set the registries up
    assert runs[2][7] == [0, False] and runs[3][7] == [0, False]  # the lean loads did not
    link_files = sorted((cache_file.read_text() for cache_file in (tmp_path / "cache" / "links").iterdir()))
    assert len(link_files) == 2 and all(text.endswith("\nend") for text in link_files)
    assert any("\nx _numba_hashsecret_siphash_k0\n" in text for text in link_files)


def test_a_symbol_that_does_not_resolve_gets_numbas_set_up_first(tmp_path: Path) -> None:
    """A link file naming an external symbol nothing defines (as a symbol numba registers only
    while it sets its registries up would be): the lean load runs ``refresh`` before it links,
    and the results are the same."""
    runs = _load_runs(tmp_path, (False, True))
    for path in (tmp_path / "cache" / "links").iterdir():
        path.write_text(path.read_text().replace("\nend", "\nx bnptrack_not_a_symbol\nend"))
    runs += _load_runs(tmp_path, (True,))
    assert runs[1][7][0] == 0 and runs[2][7][0] > 0
    assert runs[2][1] == runs[0][1] and runs[2][2] == 2 and runs[2][5:7] == runs[0][5:7]


def test_other_numba_versions_get_numbas_own_loads(tmp_path: Path) -> None:
    """``lean_cache_loads`` applies to the numba versions it mirrors only: for any other it
    changes nothing and says so, and :func:`tracker.numerics.import_numba` then sets numba's
    CPU target up itself (``refresh``) before the kernels load the ordinary way."""
    code = """
import json, sys
from bnptrack.tracker import _kernel_cache, numerics
_kernel_cache.LEAN_LOADS_VERSIONS = ("0.0.",)
numerics.LEAN_NUMBA = True
numerics.preload()
from numba.core import codegen, typing
from numba.core.registry import cpu_target
lean = getattr(codegen.JITCodeLibrary, "_bnptrack_lean", False)
print(json.dumps([lean, numerics._preload_kernel(2.5), "numba.np.linalg" in sys.modules,
                  "cffi" in sys.modules, _kernel_cache.lean_cache_loads("unused", ("0.0.",))]))
"""
    lean, value, registries, cffi, applies = json.loads(_python(code).stdout.strip().splitlines()[-1])
    assert (lean, value, registries, cffi, applies) == (False, 3.5, True, False, False)


def test_link_files_incomplete_or_malformed_are_ignored(tmp_path: Path) -> None:
    from bnptrack.tracker import _kernel_cache

    path = tmp_path / "s"
    path.write_text("d a\nx b")  # no "end": a write cut short
    assert _kernel_cache._read_links(str(path)) is None
    path.write_text("a\nb\nend")  # the older symbol file form, without the link list
    assert _kernel_cache._read_links(str(path)) is None
    _kernel_cache._write_links(str(path), ["a", "b"], ["c"])
    assert _kernel_cache._read_links(str(path)) == (["a", "b"], ["c"])
    assert _kernel_cache._read_links(str(tmp_path / "missing")) is None


def test_typeof_ndarray_is_numbas_without_numpy_ma() -> None:
    """:func:`tracker._kernel_cache.typeof_ndarray` gives numba's type (dtype, ndim, layout,
    read-only) for plain arrays of every kind, numba's errors for an unsupported dtype and a
    masked array, and imports no ``numpy.ma`` (checked in a fresh interpreter)."""
    code = """
import json, sys
import numpy as np
from bnptrack.tracker._kernel_cache import typeof_ndarray
from numba.core.typing import typeof as nt
from numba.core.typing.typeof import Purpose, _TypeofContext
c = _TypeofContext(Purpose.argument)
base = np.arange(24.0).reshape(2, 3, 4)
ro = np.zeros(3)
ro.flags.writeable = False
arrays = [base, base[:, ::2], np.asfortranarray(base), base.transpose(1, 0, 2), np.ones(()),
          ro, np.zeros(2, np.int32), np.zeros(2, bool), np.zeros(2, np.complex64), np.zeros(2, "M8[s]"),
          np.zeros(2, [("a", "f8"), ("b", "i4")]), np.zeros((0, 3), np.uint8), np.zeros(2, object),
          np.zeros(2, "U3"), np.zeros(2, "m8[s]"), np.zeros(2, np.float16)]
ours = [str(typeof_ndarray(a, c)) for a in arrays]
no_ma = "numpy.ma" not in sys.modules
numbas = [str(nt._typeof_ndarray(a, c)) for a in arrays]
errors = []
for bad in (np.zeros(2, "V8"), np.ma.masked_array([1.0, 2.0])):
    for fn in (typeof_ndarray, nt._typeof_ndarray):
        try:
            fn(bad, c)
        except Exception as exc:
            errors.append([type(exc).__name__, str(exc)])
print(json.dumps([no_ma, ours == numbas, ours[:3], errors]))
"""
    no_ma, same, first, errors = json.loads(_python(code).stdout.strip().splitlines()[-1])
    assert no_ma and same
    assert first == ["array(float64, 3d, C)", "array(float64, 3d, A)", "array(float64, 3d, F)"]
    assert errors[0] == errors[1] and errors[0][0] == "NumbaValueError"
    assert errors[2] == errors[3] and errors[2][0] == "NumbaTypeError" and "numpy.ma.MaskedArray" in errors[2][1]




def test_target_configs_hash_and_compare_as_numbas() -> None:
    """With the lean loads applied, numba's compile options (``Flags``) hash and compare as
    numba's own ``TargetConfig`` methods do: equal for equal values set or left at their
    default, unequal when one value differs (checked in a fresh interpreter)."""
    code = """
import json, os, tempfile
from numba.core.compiler import Flags
from numba.core.targetconfig import TargetConfig
h, eq = TargetConfig.__hash__, TargetConfig.__eq__
from bnptrack.tracker._kernel_cache import lean_cache_loads
assert lean_cache_loads(tempfile.mkdtemp())
a, b, c, d = Flags(), Flags(), Flags(), Flags()
a.nrt = True; b.nrt = True; c.nrt = False; d.nrt = True
d.no_cfunc_wrapper = True
b.boundscheck = Flags.options["boundscheck"].default  # set to its default: still equal to a
pairs = [(x, y) for x in (a, b, c, d) for y in (a, b, c, d)]
same = [(hash(x) == h(x), (x == y) == eq(x, y)) for x, y in pairs]
replaced = TargetConfig.__hash__ is not h and TargetConfig.__eq__ is not eq
print(json.dumps([replaced, all(s for pair in same for s in pair), a == b, a == c, a == d, hash(a) == hash(d)]))
"""
    assert json.loads(_python(code).stdout.strip().splitlines()[-1]) == [True, True, True, False, False, True]


_TRACK_PROBE = """
import atexit, json, sys
from bnptrack.pipeline.cli import main
lean = lambda: getattr(sys.modules["numba.core.codegen"].JITCodeLibrary, "_bnptrack_lean", False)
atexit.register(lambda: print(json.dumps(lean()), file=sys.stderr))
argv = ["track", "recordings/vo2017-s1.mcap", "--out", {out!r}, "-q"]
if {command_line!r}:  # as the command line runs it: LEAN_NUMBA, os._exit after the atexit handlers
    sys.argv = ["bnptrack", *argv]
    main(prog_name="bnptrack")
else:  # as a test's CliRunner does: numba as it is
    main(args=argv, prog_name="bnptrack", standalone_mode=False)
"""


def test_track_loads_the_lean_way_with_the_same_tracks(tmp_path: Path) -> None:
    """``bnptrack track`` run as the command line (``LEAN_NUMBA``) applies the lean loads and
    writes the same /tracks messages as a run without them (but the ``ms`` timing)."""
    runs = {}
    for command_line in (True, False):
        out = tmp_path / f"{command_line}.mcap"
        proc = _python(_TRACK_PROBE.format(out=str(out), command_line=command_line))
        runs[command_line] = (proc.stderr.strip().splitlines()[-1], _tracks(out))
    assert runs[True][0] == "true" and runs[False][0] == "false"
    assert len(runs[True][1]) == 100 and runs[True][1] == runs[False][1]


def _tracks(path: Path) -> list[dict]:
    """The /tracks messages of an MCAP file as JSON objects, without the ``ms`` timing."""
    from mcap.reader import make_reader

    out = []
    with open(path, "rb") as f:
        for _schema, _channel, message in make_reader(f).iter_messages(topics=["/tracks"]):
            msg = json.loads(message.data)
            msg["diagnostics"].pop("ms")
            out.append(msg)
    return out
