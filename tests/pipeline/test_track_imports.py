"""What ``bnptrack track`` imports of scipy: none of ``scipy.linalg``,
``scipy.special``, ``scipy.optimize`` or ``scipy.spatial`` (0.6-1 s of imports between them)
with the kernels compiled; numba still finds BLAS (``tracker.numerics.import_numba`` loads
scipy's ``cython_blas`` alone), and a later ``import scipy.linalg`` is whole.  Checks of
``sys.modules`` in a fresh interpreter; docs/performance.md has the timings."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from testkit import REPO_ROOT

_SCIPY_PACKAGES = {"scipy.linalg", "scipy.special", "scipy.optimize", "scipy.spatial", "scipy.sparse", "scipy.stats"}

_TRACK_PROBE = """
import atexit, json, sys
from bnptrack.pipeline.cli import main
atexit.register(lambda: print(json.dumps(sorted(sys.modules)), file=sys.stderr))
sys.argv = ["bnptrack", *{argv!r}]
main(prog_name="bnptrack")  # as the command line runs it: ends with os._exit after the atexit handlers
"""


def _run(code: str, tmp: Path) -> str:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    env.pop("BNPTRACK_NO_JIT", None)
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stderr.strip().splitlines()[-1]


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_track_imports_no_scipy_package(tmp_path: Path) -> None:
    """Neither scipy's packages nor numba's optional yaml and cffi (``LEAN_NUMBA``)."""
    argv = ["track", "recordings/vo2017-s1.mcap", "--out", str(tmp_path / "t.mcap"), "-q"]
    modules = set(json.loads(_run(_TRACK_PROBE.format(argv=argv), tmp_path)))
    assert "numba" in modules and "scipy.linalg.cython_blas" in modules
    assert sorted(modules & _SCIPY_PACKAGES) == []
    assert sorted(modules & {"yaml", "cffi", "pycparser"}) == []
    assert "numpy.ma" not in modules  # numba's typeof of an ndarray, the summary's median
    assert (tmp_path / "t.mcap").stat().st_size > 0


def test_track_summary_median_is_numpys() -> None:
    """``TrackResult.ms_median`` (``statistics.median``, no ``numpy.ma``) is ``np.median``'s
    double for odd and even counts; NaN and infinite times are left out."""
    import numpy as np

    from bnptrack.pipeline.offline import FrameMetrics, TrackResult

    for times in ([3.0, 1.0, 2.0], [0.1, 0.7, 0.2, 0.3000000000000001], [5.25], [1.0, float("nan"), 4.0, float("inf")]):
        result = TrackResult("ddp", tuple(FrameMetrics(k, 0, 0, t) for k, t in enumerate(times)), 0)
        finite = [t for t in times if np.isfinite(t)]
        assert result.ms_median == float(np.median(finite))
    assert TrackResult("ddp", (), 0).ms_median is None
    assert TrackResult("ddp", (FrameMetrics(0, 0, 0, 4.0), FrameMetrics(1, 0, 0, 1.0)), 0).ms_median == 2.5


_LEAN_PROBE = """
import json, sys
from bnptrack.tracker import numerics
numerics.LEAN_NUMBA = True
numerics.preload()
from numba.core.typing import cffi_utils
from numba.core import config
left_out = [m in sys.modules for m in ("yaml", "cffi")]
import yaml, cffi
print(json.dumps([left_out, cffi_utils.SUPPORTED, config._HAVE_YAML, numerics._preload_kernel(1.5),
                  yaml.safe_load("a: 1")]), file=sys.stderr)
"""


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_lean_numba_leaves_yaml_and_cffi_importable(tmp_path: Path) -> None:
    left_out, cffi_supported, have_yaml, kernel, parsed = json.loads(_run(_LEAN_PROBE, tmp_path))
    assert left_out == [False, False] and not cffi_supported and not have_yaml
    assert kernel == 2.5 and parsed == {"a": 1}


_BLAS_PROBE = """
import json, sys
import numpy as np
from bnptrack.tracker.numerics import import_numba
import_numba()
import numba
from numba.np import arraymath
linalg_before = "scipy.linalg" in sys.modules

@numba.njit
def dot(a, b):
    return np.dot(a, b)

a = np.arange(6.0).reshape(2, 3)
product = dot(a, a.T).tolist()
import scipy.linalg
import scipy.linalg.cython_blas as blas
print(json.dumps([linalg_before, arraymath._HAVE_BLAS, product, scipy.linalg.cython_blas is blas,
                  blas is sys.modules["scipy.linalg.cython_blas"], hasattr(scipy.linalg, "solve")]), file=sys.stderr)
"""


@pytest.mark.slow
def test_numba_finds_blas_without_scipy_linalg(tmp_path: Path) -> None:
    """[[0,1,2],[3,4,5]] times its transpose is [[5, 14], [14, 50]], through numba's BLAS."""
    linalg_before, have_blas, product, bound, same, whole = json.loads(_run(_BLAS_PROBE, tmp_path))
    assert (linalg_before, have_blas, product) == (False, True, [[5.0, 14.0], [14.0, 50.0]])
    assert bound and same and whole
