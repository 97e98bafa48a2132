"""The second compiling process of a first run (tracker/precompile.py) and its manifest."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

import pytest

from bnptrack.tracker._numerics import JIT
from testkit import REPO_ROOT, bnptrack_env

pytestmark = pytest.mark.skipif(not JIT, reason="nothing compiles without numba")


def test_the_manifest_names_kernels_that_exist_for_this_numba():
    from bnptrack.tracker.precompile import _dispatcher, load_manifest

    trackers = load_manifest()
    assert trackers.get("ddp"), "tracker/params/kernel_manifest.pkl: no ddp entry for this numba version"
    for module, qualname, sig in trackers["ddp"]:
        assert hasattr(_dispatcher(module, qualname), "_cache"), f"{module}.{qualname} is no cached kernel"
        assert isinstance(sig, tuple)


@pytest.mark.slow
def test_precompile_caches_from_the_end_and_skips_what_was_cached(tmp_path):
    import numba
    from numba import types

    manifest = tmp_path / "manifest.pkl"
    rows = [("bnptrack.tracker._numerics", "_preload_kernel", (types.float64,)),
            ("bnptrack.tracker._numerics", "_lgam_array", (types.float64[::1], types.float64[::1]))]
    manifest.write_bytes(pickle.dumps({"numba": numba.__version__, "trackers": {"ddp": rows}}))
    code = ("import sys; from pathlib import Path; from bnptrack.tracker.precompile import precompile; "
            "print(precompile('ddp', Path(sys.argv[1])))")
    env = bnptrack_env({"NUMBA_CACHE_DIR": str(tmp_path / "cache")})
    runs = [subprocess.run([sys.executable, "-c", code, str(manifest)], cwd=REPO_ROOT, env=env,
                           capture_output=True, text=True, timeout=300) for _ in range(2)]
    assert [r.stdout.strip() for r in runs] == ["2", "0"], [r.stderr for r in runs]
    names = sorted(os.path.basename(p) for p in (tmp_path / "cache").rglob("*.nbi"))
    assert [n.split("-")[0] for n in names] == ["_numerics._lgam_array", "_numerics._preload_kernel"]
