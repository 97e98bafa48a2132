"""Kernels that only other kernels call (``jit(..., kernels_only=True)``, tracker/_kernel_entry.py)
are compiled without numba's Python wrapper: other kernels call them as before, a Python call
still gives the kernel's result (through a second, wrapped copy), and the trackers' own Python
code calls none of them (each such call would compile that copy)."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker import numerics

pytestmark = pytest.mark.skipif(not numerics.JIT, reason="without numba every kernel is a Python function")


def _kernels_only_class() -> type:
    from bnptrack.tracker import _kernel_entry

    numerics.preload()  # numba imported, the pending kernels decorated
    return _kernel_entry._numba_classes()[0]


def test_kernels_and_python_both_call_a_kernels_only_kernel():
    from bnptrack.tracker.bnp import group_merge

    cls = _kernels_only_class()
    assert isinstance(numerics.argsort_stable, cls)
    keys = np.array([0.3, -1.0, 0.3, 2.0, -1.0])
    assert numerics.argsort_stable(keys).tolist() == [1, 4, 0, 2, 3]  # from Python: the wrapped copy
    entry = numerics.argsort_stable._python_entry
    assert entry is not None and entry.py_func.__qualname__ == "argsort_stable_python_entry"
    # from a kernel: greedy_groups ranks each cluster's partners with argsort_stable (int64 keys)
    r = np.array([0.5, 0.4, 0.3, 0.2])
    ptr, members = group_merge.greedy_groups(np.array([0, 0, 2]), np.array([1, 2, 3]), r,
                                             np.argsort(-r, kind="stable"))
    assert ptr.tolist() == [0, 2, 4] and members.tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize("tracker", ["ddp", "dpyp", "ddp-mb"])
def test_the_trackers_python_code_calls_no_kernels_only_kernel(tracker, monkeypatch):
    import bnptrack
    from bnptrack.pipeline.stages.tracker_warmup import warm_up_tracker

    cls = _kernels_only_class()
    called: list[str] = []
    monkeypatch.setattr(cls, "__call__", lambda self, *args: called.append(self.py_func.__qualname__))
    warm_up_tracker(bnptrack.make_tracker(tracker))  # every path of the warm-up's contests
    run = bnptrack.track(bnptrack.simulate("vo2017", seed=3)[:40], tracker=tracker)
    assert run.estimates[-1].tracks, "the run tracked nothing: the check saw no kernel"
    assert called == []
