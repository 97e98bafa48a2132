"""The trackers bnptrack can run, by name: settings class, named presets and factory.

Every tool (``bnptrack track``, the pipeline's tracker stage, experiments) builds trackers
through :func:`build`, so a new tracker is one entry here plus its module.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

import msgspec

from bnptrack.tracker.config import did_you_mean
from bnptrack.tracker.models.params import ModelParams


class Tracker(Protocol):
    """What every tracker offers: a name, an initial state and a pure step."""

    name: str

    def initial_state(self) -> Any: ...

    def step(self, state: Any, frame: Any, rng: np.random.Generator) -> tuple[Any, Any]: ...


@dataclass(frozen=True)
class TrackerKind:
    name: str
    description: str
    config_cls: type[msgspec.Struct]
    presets: Mapping[str, msgspec.Struct]
    factory: Callable[[ModelParams, Any], Any]


def _bnp(name: str, description: str) -> TrackerKind:
    """The single-level tracker (``ddp-mb``, ``dpyp-mb``: objects = clusters), with its presets
    (``ddp-mb``, ``dpyp-mb``, ``ddp-mb-proximity``, ``ddp-mb-snr``)."""
    from bnptrack.tracker.bnp import TRACKER_PRESETS, BnpConfig, make_tracker

    return TrackerKind(name, description, BnpConfig, TRACKER_PRESETS,
                       lambda params, config: make_tracker(name, params, config))


def _groups(name: str, description: str) -> TrackerKind:
    """The two-level tracker (``ddp``, ``dpyp`` and their aliases ``ddp-groups``, ``dpyp-groups``),
    with its presets (``ddp``, ``dpyp``, ``ddp-proximity``, ``ddp-snr`` and their ``-groups`` names)."""
    from bnptrack.tracker.bnp.group_config import GROUP_PRESETS, GroupConfig
    from bnptrack.tracker.bnp.groups import make_group_tracker

    return TrackerKind(name, description, GroupConfig, GROUP_PRESETS,
                       lambda params, config: make_group_tracker(name, params, config))


def _glmb() -> TrackerKind:
    from bnptrack.tracker.glmb import GLMB_PRESETS, GlmbConfig, make_glmb

    return TrackerKind("glmb", "GLMB filter, joint prediction-update with Gibbs truncation (Vo et al. 2017)",
                       GlmbConfig, GLMB_PRESETS, make_glmb)


#: ``ddp``/``dpyp`` are the two-level trackers (the single level is ``ddp-mb``/``dpyp-mb``);
#: ``ddp-groups``/``dpyp-groups`` are accepted as their aliases.
_KINDS: dict[str, Callable[[], TrackerKind]] = {
    "ddp": lambda: _groups("ddp", "DDP-EMM (two-level): measurements -> objects -> motion clusters"),
    "dpyp": lambda: _groups("dpyp", "DPY-STP (two-level): Pitman-Yor discount on the object partition"),
    "glmb": _glmb,
    "ddp-mb": lambda: _bnp("ddp-mb", "DDP-EMM, single level (objects = clusters)"),
    "dpyp-mb": lambda: _bnp("dpyp-mb", "DPY-STP, single level (objects = clusters)"),
    "ddp-groups": lambda: _groups("ddp-groups", "alias of ddp"),
    "dpyp-groups": lambda: _groups("dpyp-groups", "alias of dpyp"),
}

#: Accepted old names -> the name they build the same tracker as.
ALIASES: Mapping[str, str] = {"ddp-groups": "ddp", "dpyp-groups": "dpyp"}

#: Names of the trackers, in display order.
TRACKERS: tuple[str, ...] = tuple(_KINDS)


def kind(name: str) -> TrackerKind:
    """The tracker ``name``; a clear error lists the valid names."""
    try:
        return _KINDS[name]()
    except KeyError:
        raise ValueError(f"unknown tracker {name!r}{did_you_mean(name, TRACKERS)}; valid trackers: "
                         f"{', '.join(TRACKERS)}") from None


def build(name: str, params: ModelParams, config: msgspec.Struct | None = None):
    """Build tracker ``name`` with ``config`` (default: its preset of the same name)."""
    k = kind(name)
    if config is None:
        config = k.presets[name]
    if not isinstance(config, k.config_cls):
        raise ValueError(f"tracker {name!r} takes a {k.config_cls.__name__}, not a {type(config).__name__}")
    return k.factory(params, config)


def warm_up(tracker: Any, frames: int = 3) -> None:
    """Step ``tracker`` through ``frames`` throw-away frames of every measurement kind that
    has example rows (:attr:`~tracker.models.measurement.MeasurementKind.examples`), each kind
    from ``initial_state()``, so lazily compiled kernels and caches are ready.  Frame ``k``'s
    rows are the examples drifted by ``k`` times 0.001 in each column but the last and 5 in
    the last (e.g. 5 m of range); then the tracker's ``warm_up_kernels()`` when it has one
    (kernels that a few frames do not reach).  Raises whatever a step raises (a tracker
    without the kind's model, say)."""
    from bnptrack.tracker.models.measurement import KINDS
    from bnptrack.tracker.types import Frame

    rng = np.random.default_rng(0)
    for name, entry in KINDS.items():
        if not entry.examples:
            continue
        base = np.array(entry.examples, dtype=float)
        drift = np.where(np.arange(base.shape[1]) == base.shape[1] - 1, 5.0, 0.001)
        state = tracker.initial_state()
        for k in range(1, frames + 1):
            state, _ = tracker.step(state, Frame(k, k * 10**9, "warm-up", name, base + k * drift), rng)
    kernels = getattr(tracker, "warm_up_kernels", None)  # the kernels a few frames do not reach
    if kernels is not None:
        kernels()
