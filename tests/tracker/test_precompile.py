"""The second compiling process of a first run (tracker/precompile.py) and its manifest."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

import pytest

from bnptrack.tracker.numerics import JIT
from testkit import REPO_ROOT, bnptrack_env

pytestmark = pytest.mark.skipif(not JIT, reason="nothing compiles without numba")


@pytest.mark.slow
def test_precompile_caches_from_the_end_and_skips_what_was_cached(tmp_path):
    import numba
    from numba import types

    manifest = tmp_path / "manifest.pkl"
    rows = [("bnptrack.tracker.numerics", "_preload_kernel", (types.float64,)),
            ("bnptrack.tracker.numerics", "_lgam_array", (types.float64[::1], types.float64[::1]))]
    manifest.write_bytes(pickle.dumps({"numba": numba.__version__, "trackers": {"ddp": rows}}))
    code = ("import sys; from pathlib import Path; from bnptrack.tracker.precompile import precompile; "
            "print(precompile('ddp', Path(sys.argv[1])))")
    env = bnptrack_env({"NUMBA_CACHE_DIR": str(tmp_path / "cache")})
    runs = [subprocess.run([sys.executable, "-c", code, str(manifest)], cwd=REPO_ROOT, env=env,
                           capture_output=True, text=True, timeout=300) for _ in range(2)]
    assert [r.stdout.strip() for r in runs] == ["2", "0"], [r.stderr for r in runs]
    names = sorted(os.path.basename(p) for p in (tmp_path / "cache").rglob("*.nbi"))
    assert [n.split("-")[0] for n in names] == ["numerics._lgam_array", "numerics._preload_kernel"]


def test_every_manifest_entry_is_a_current_kernel_with_its_argument_count():
    """A kernel moved to another module or renamed, or given other arguments, leaves the
    manifest stale: rerun ``python3 benchmarks/kernel_manifest.py``.  Each tracker is resolved
    as ``python -m bnptrack.tracker.precompile NAME`` resolves it: its kind, then the modules
    its entries name; an entry must name a kernel defined there with as many arguments."""
    import importlib

    from bnptrack.tracker import numerics, registry
    from bnptrack.tracker.precompile import MANIFEST, load_manifest

    trackers = load_manifest()
    assert trackers, f"{MANIFEST}: unreadable or written by another numba version"
    for name, entries in trackers.items():
        registry.kind(name)
        for module, _, _ in entries:
            importlib.import_module(module)
        defined = {(k.py_func.__module__, k.py_func.__qualname__): k.py_func.__code__.co_argcount
                   for k in numerics._defined}
        stale = [f"{m}.{q} ({len(sig)} arguments; found: {defined.get((m, q))})" for m, q, sig in entries
                 if defined.get((m, q)) != len(sig)]
        assert not stale, f"{MANIFEST}, tracker {name}: stale entries {stale}; rerun benchmarks/kernel_manifest.py"
