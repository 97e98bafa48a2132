"""``tracker._kernel_cache`` (the command line's lean loads): kernels loaded from numba's
cache without parsing their linking bitcode give the symbols and results numba's own load
gives, a kernel compiled later still links them, and ``bnptrack track`` writes the same
/tracks with them.  Each load runs in a fresh interpreter with its own numba cache folder."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

from testkit import REPO_ROOT

_KERNELS = '''
import math
from numba import njit

@njit(cache=True)
def lgam_sum(x):
    s = 0.0
    for v in x:
        s += math.lgamma(v)
    return s
'''

_LOAD_PROBE = """
import json, sys
sys.path.insert(0, {folder!r})
import numpy as np
from bnptrack.tracker import _kernel_cache
import numba
from numba.core.registry import cpu_target
lean = {lean!r} and _kernel_cache.lean_cache_loads({cache!r})
import kernels_mod
from numba import njit
total = kernels_mod.lgam_sum(np.arange(1.0, 6.0))
hits = sum(kernels_mod.lgam_sum.stats.cache_hits.values())
engine = cpu_target.target_context.codegen()._engine
names = sorted(engine._defined_symbols)

@njit
def twice(x):  # compiled here, not cached: links the loaded kernel's module
    return 2.0 * kernels_mod.lgam_sum(x)

print(json.dumps([lean, total, hits, names, twice(np.arange(1.0, 6.0))]))
"""


def _python(code: str, env: dict[str, str] | None = None, cwd: Path = REPO_ROOT) -> subprocess.CompletedProcess:
    base = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    base.pop("BNPTRACK_NO_JIT", None)
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, env={**base, **(env or {})},
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def test_lean_loads_give_numbas_symbols_and_results(tmp_path: Path) -> None:
    """A cached kernel loaded the lean way defines exactly the symbols numba's own load
    defines, computes the same value (the sum of log 0! .. log 4!), and a kernel compiled afterwards that
    calls it links and runs; the symbol file is written by the first load."""
    (tmp_path / "kernels_mod.py").write_text(_KERNELS)
    cache = tmp_path / "cache"
    env = {"NUMBA_CACHE_DIR": str(cache)}
    runs = []
    for lean in (False, False, True, True):  # compile, numba's load, first lean load, lean load
        code = _LOAD_PROBE.format(folder=str(tmp_path), lean=lean, cache=str(cache))
        runs.append(json.loads(_python(code, env).stdout.strip().splitlines()[-1]))
    assert [r[0] for r in runs] == [False, False, True, True]
    assert [r[2] for r in runs] == [0, 1, 1, 1]  # compiled once, then loaded from the cache
    assert abs(runs[0][1] - math.log(288.0)) < 1e-12  # log(0! 1! 2! 3! 4!)
    for _lean, total, _hits, _names, twice in runs:  # bit for bit the compiling run's value
        assert total == runs[0][1] and twice == 2.0 * runs[0][1]
    assert runs[3][3] == runs[1][3]  # the lean load's symbols are numba's
    symbol_files = list((cache / "symbols").iterdir())
    assert len(symbol_files) == 1 and symbol_files[0].read_text().endswith("\nend")


def test_symbol_files_incomplete_are_ignored(tmp_path: Path) -> None:
    from bnptrack.tracker import _kernel_cache

    path = tmp_path / "s"
    path.write_text("a\nb")  # no "end": a write cut short
    assert _kernel_cache._read_symbols(str(path)) is None
    _kernel_cache._write_symbols(str(path), ["a", "b"])
    assert _kernel_cache._read_symbols(str(path)) == ["a", "b"]
    assert _kernel_cache._read_symbols(str(tmp_path / "missing")) is None




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
