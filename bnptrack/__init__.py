"""bnptrack: streaming multi-object tracking with dependent Bayesian nonparametric priors.

The Python API for notebooks and scripts (docs/python.md)::

    import bnptrack
    frames = bnptrack.simulate("vo2017", seed=1)
    run = bnptrack.track(frames, tracker="ddp")
    run.mean_ospa, run.estimates[-1].tracks

The installed packages live under this one name: ``bnptrack.tracker`` (trackers, models, the
message contract), ``bnptrack.sources``, ``bnptrack.sinks`` and ``bnptrack.pipeline`` (the
command line and the streaming stages); docs/architecture.md says what sits where.

Importing :mod:`bnptrack` is cheap: each name below is imported from :mod:`bnptrack.api` on
first use, so the command line (which starts here) pays for nothing it does not run.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["simulate", "track", "make_tracker", "load_params", "read_log", "write_log", "TrackRun"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("bnptrack.api"), name)
    raise AttributeError(f"module 'bnptrack' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
