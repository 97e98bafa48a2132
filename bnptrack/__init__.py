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
from pathlib import Path
from typing import Any

# A source checkout (this folder beside pyproject.toml and the four package folders): the
# sub-packages are that checkout's folders, whichever copy is installed.  pyproject.toml's
# package-dir mapping gives the same layout to an installed wheel and to the editable install;
# this line makes a second work tree on PYTHONPATH (a baseline for an A/B benchmark, a clone
# under test) import its own code instead of the installed one's.
_CHECKOUT = Path(__file__).resolve().parent.parent
if (_CHECKOUT / "pyproject.toml").is_file() and (_CHECKOUT / "tracker" / "__init__.py").is_file():
    __path__.append(str(_CHECKOUT))  # noqa: F821  (the package's own __path__)

__all__ = ["simulate", "track", "make_tracker", "load_params", "read_log", "write_log", "TrackRun", "LogContents"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("bnptrack.api"), name)
    raise AttributeError(f"module 'bnptrack' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
