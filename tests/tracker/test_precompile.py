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


_RESOLVE = """
import importlib, json, sys
from bnptrack.tracker import numerics, registry
registry.kind(sys.argv[1])
rows = json.loads(sys.argv[2])
for module, _, _ in rows:
    importlib.import_module(module)
defined = {(k.py_func.__module__, k.py_func.__qualname__): k.py_func.__code__.co_argcount for k in numerics._defined}
print(json.dumps([defined.get((m, q)) for m, q, _ in rows]))
"""


def test_every_manifest_entry_is_a_current_kernel_with_its_argument_count():
    """A kernel moved to another module or renamed, or given other arguments, leaves the
    manifest stale: rerun ``python3 benchmarks/kernel_manifest.py``.  Each tracker is resolved
    in a process of its own, as ``python -m bnptrack.tracker.precompile NAME`` resolves it."""
    import json

    from bnptrack.tracker.precompile import MANIFEST, load_manifest

    trackers = load_manifest()
    assert trackers, f"{MANIFEST}: unreadable or written by another numba version"
    for name, entries in trackers.items():
        rows = [(module, qualname, len(sig)) for module, qualname, sig in entries]
        out = subprocess.run([sys.executable, "-c", _RESOLVE, name, json.dumps(rows)], cwd=REPO_ROOT,
                             env=bnptrack_env({}), capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        argcounts = json.loads(out.stdout.strip().splitlines()[-1])
        stale = [f"{m}.{q} ({n} arguments; found: {found})" for (m, q, n), found in zip(rows, argcounts)
                 if found != n]
        assert not stale, f"{MANIFEST}, tracker {name}: stale entries {stale}; rerun benchmarks/kernel_manifest.py"
