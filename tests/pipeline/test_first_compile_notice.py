"""``track`` / ``launch`` / ``replay`` say that a tracker's first run compiles its numba kernels
and show how many are done, at most once a second (pipeline/compile_notice.py); each tracker's
first run says it, a finished run marks it, and then nothing is printed."""

from __future__ import annotations

import io
import threading
from pathlib import Path

import pytest

from bnptrack.pipeline import compile_notice
from bnptrack.pipeline.compile_notice import compile_progress
from bnptrack.tracker.numerics import JIT, kernel_cache_dir, kernel_file_prefixes

pytestmark = pytest.mark.skipif(not JIT, reason="nothing compiles without numba")


def test_progress_counts_new_index_files_until_the_run_ends(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(compile_notice, "INTERVAL_S", 0.05)
    folder = Path(kernel_cache_dir())
    out = io.StringIO()
    seen = threading.Event()
    with compile_progress("ddp", quiet=False, out=out, helper=False):
        total = int(out.getvalue().split("(up to ")[1].split(")")[0])
        # every ddp kernel is defined once its modules are imported, none compiled in this folder
        assert total == len(kernel_file_prefixes()) > 20
        for k, prefix in enumerate(kernel_file_prefixes()[:3]):  # as numba writes them
            (folder / "sub").mkdir(parents=True, exist_ok=True)
            (folder / "sub" / f"{prefix}.py311.nbi").write_bytes(b"")
            for _ in range(200):
                if f"compiling kernels: {k + 1}/{total} done" in out.getvalue():
                    break
                seen.wait(0.01)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("bnptrack: first run of tracker ddp with this version on this machine: "
                               "compiling its numba kernels once")
    assert [ln.split(" done")[0] for ln in lines[1:-1]] == [
        f"bnptrack: compiling kernels: {k}/{total}" for k in (1, 2, 3)]
    assert lines[-1].startswith("bnptrack: compiled 3 kernels in ")
    assert (folder / "compiled-ddp").exists()
    out = io.StringIO()
    with compile_progress("ddp", quiet=False, out=out, helper=False):  # ddp has run here: nothing
        pass
    assert out.getvalue() == ""
    with compile_progress("glmb", quiet=False, out=out, helper=False):  # glmb's first run still says it
        pass
    assert "first run of tracker glmb" in out.getvalue()


def test_quiet_prints_nothing_and_a_failed_run_leaves_no_mark(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    out = io.StringIO()
    with compile_progress("ddp", quiet=True, out=out, helper=False):
        pass
    assert out.getvalue() == ""
    assert (Path(kernel_cache_dir()) / "compiled-ddp").exists()  # a quiet run that finished marks too
    with pytest.raises(RuntimeError):
        with compile_progress("glmb", quiet=False, out=out, helper=False):
            raise RuntimeError("the run failed")
    assert out.getvalue().count("\n") == 1  # the first line only
    assert not (Path(kernel_cache_dir()) / "compiled-glmb").exists()


def _cache_every_kernel(folder: Path) -> None:
    """An index file for every kernel defined so far, as a finished run of another tracker leaves."""
    (folder / "sub").mkdir(parents=True, exist_ok=True)
    for prefix in kernel_file_prefixes():
        (folder / "sub" / f"{prefix}.py311.nbi").write_bytes(b"")


def test_a_tracker_whose_kernels_are_all_cached_says_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    folder = Path(kernel_cache_dir())
    with compile_progress("ddp", quiet=True, out=io.StringIO(), helper=False):
        pass
    _cache_every_kernel(folder)  # ddp's run compiled them; dpyp shares every one of them
    out = io.StringIO()
    with compile_progress("dpyp", quiet=False, out=out, helper=False):
        pass
    assert out.getvalue() == ""  # no "compiled 0 kernels"
    assert (folder / "compiled-dpyp").exists()


def test_a_run_that_compiles_nothing_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    out = io.StringIO()
    with compile_progress("ddp", quiet=False, out=out, helper=False):
        total = int(out.getvalue().split("(up to ")[1].split(")")[0])
    last = out.getvalue().splitlines()[-1]
    assert last.startswith(f"bnptrack: compiled no kernel: the run called none of the {total} not cached yet (")
    assert total == len(kernel_file_prefixes())
