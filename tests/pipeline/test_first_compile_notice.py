"""``track`` / ``launch`` / ``replay`` say on one line that a first run compiles the numba
kernels (pipeline/cli/common.py ``announce_first_compile``), and only then."""

from __future__ import annotations

from pathlib import Path

import pytest

from bnptrack.pipeline.cli.common import announce_first_compile
from bnptrack.tracker._numerics import JIT, kernel_cache_dir


@pytest.mark.skipif(not JIT, reason="nothing compiles without numba")
def test_notice_only_on_a_cold_kernel_cache(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    announce_first_compile(quiet=False)
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("bnptrack: first run of this version on this machine: compiling the numba kernels once")
    assert str(tmp_path) in err
    announce_first_compile(quiet=True)
    assert capsys.readouterr().err == ""
    # a kernel compiled into this version's folder (numba's index files sit in subfolders)
    index = Path(kernel_cache_dir()) / "bnp_x" / "kernel.py.nbi"
    index.parent.mkdir(parents=True)
    index.write_bytes(b"")
    announce_first_compile(quiet=False)
    assert capsys.readouterr().err == ""
