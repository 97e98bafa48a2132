"""The compiled kernels' cache folder is named by a digest of every kernel-defining source
file (``tracker.numerics.kernel_cache_dir``): numba checks only a kernel's own file before
loading it, so a caller whose callee in another file changed must not find its old entry."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bnptrack.tracker import numerics
from tests.testkit import REPO_ROOT, bnptrack_env


def _tree(tmp_path: Path) -> Path:
    root = tmp_path / "pkg"
    (root / "sub").mkdir(parents=True)
    (root / "a.py").write_text("from x import jit\n\n@jit\ndef f(x):\n    return x\n")
    (root / "sub" / "b.py").write_text("K = jit(lambda x: x + 1)\n")
    (root / "plain.py").write_text("def g():\n    return 1\n")
    return root


def test_digest_follows_every_kernel_file_and_only_them(tmp_path):
    root = _tree(tmp_path)
    first = numerics.kernel_sources_digest(root)
    assert len(first) == 16 and first == numerics.kernel_sources_digest(root)
    (root / "plain.py").write_text("def g():\n    return 2\n")  # no kernel in it
    assert numerics.kernel_sources_digest(root) == first
    (root / "sub" / "b.py").write_text("K = jit(lambda x: x + 2)\n")  # a callee changes
    second = numerics.kernel_sources_digest(root)
    assert second != first
    (root / "sub" / "b.py").rename(root / "b.py")  # same bytes, another path
    assert numerics.kernel_sources_digest(root) not in (first, second)


@pytest.mark.slow
@pytest.mark.parametrize("env_key", ["NUMBA_CACHE_DIR", "XDG_CACHE_HOME"])
def test_kernels_are_cached_under_the_digest_folder(tmp_path, env_key):
    if not numerics.JIT:
        pytest.fail("numba is a core dependency: the kernels must compile here")
    code = textwrap.dedent("""
        from numba import config
        from bnptrack.tracker import numerics
        before = config.CACHE_DIR
        numerics.preload()
        print(numerics.kernel_cache_dir())
        print(config.CACHE_DIR == before)
    """)
    env = bnptrack_env({env_key: str(tmp_path)})
    env.pop("NUMBA_CACHE_DIR" if env_key == "XDG_CACHE_HOME" else "XDG_CACHE_HOME", None)
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    folder, restored = out.stdout.split()
    base = tmp_path if env_key == "NUMBA_CACHE_DIR" else tmp_path / "bnptrack" / "numba"
    assert Path(folder) == base / numerics.kernel_sources_digest()
    assert restored == "True"  # numba's own setting is put back for other code in the process
    cached = [p.name for p in Path(folder).rglob("*") if p.suffix in (".nbi", ".nbc")]
    assert any(name.startswith("numerics._preload_kernel") for name in cached), sorted(os.listdir(folder))
