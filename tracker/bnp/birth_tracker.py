r"""The single-level tracker with a learned base distribution :math:`H_k` (``learn_births`` /
``learn_birth_velocity``; :mod:`tracker.bnp.birth_memory` has the model and its equations).

:class:`LearnedBirthTracker` is :class:`~tracker.bnp.filter.BnpTracker` whose base distribution
at frame :math:`k` is :math:`H_k`, built from the births recorded in the state: each step runs
the parent's step on a copy of the tracker whose ``base`` is :math:`H_k` (nothing else of the
step changes), then records the clusters that reached the lag.  Its state,
:class:`LearnedBirthState`, is the parent's plus the memory's plain arrays, so snapshots are
exact and a restored run resumes draw for draw.  With both switches off :func:`make_tracker`
builds the plain :class:`~tracker.bnp.filter.BnpTracker` (bit for bit the tracker without this
module).
"""

from __future__ import annotations

import copy
from functools import cached_property
from dataclasses import dataclass, field, fields, replace

import numpy as np

from bnptrack.tracker.bnp import filter as _filter
from bnptrack.tracker.bnp.birth_memory import ALPHA_H_GRID, BirthMemory, BirthSettings, birth_states, learned_base, record
from bnptrack.tracker.bnp.config import TRACKER_PRESETS, BnpConfig
from bnptrack.tracker.bnp.filter import BnpState, BnpTracker
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import Estimate, Frame, frame_dt


@dataclass(frozen=True)
class LearnedBirthState(BnpState):
    """:class:`BnpState` plus the recorded births (:class:`~tracker.bnp.birth_memory.BirthMemory`,
    flattened): ``birth_pos`` (B, 2), ``birth_cov`` (B, 2, 2), ``birth_weight`` (B,),
    ``birth_loglik`` (grid of alpha_H), ``birth_vel_stats`` (2,)."""

    birth_pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    birth_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    birth_weight: np.ndarray = field(default_factory=lambda: np.zeros(0))
    birth_loglik: np.ndarray = field(default_factory=lambda: np.zeros(ALPHA_H_GRID.size))
    birth_vel_stats: np.ndarray = field(default_factory=lambda: np.zeros(2))

    @property
    def memory(self) -> BirthMemory:
        return BirthMemory(self.birth_pos, self.birth_cov, self.birth_weight, self.birth_loglik, self.birth_vel_stats)

    def inner(self) -> BnpState:
        return BnpState(**{f.name: getattr(self, f.name) for f in fields(BnpState)})


@dataclass(frozen=True)
class LearnedBirthTracker(BnpTracker):
    """``ddp-mb`` / ``dpyp-mb`` with the learned :math:`H_k`."""

    @property
    def settings(self) -> BirthSettings:
        c = self.config
        return BirthSettings(c.learn_births, c.learn_birth_velocity, c.birth_memory_forgetting, c.birth_kernel_std,
                             c.birth_memory_lag, c.birth_velocity_std, c.birth_velocity_strength,
                             c.birth_alpha_min)

    def initial_state(self) -> LearnedBirthState:
        inner = super().initial_state()
        return LearnedBirthState(**{f.name: getattr(inner, f.name) for f in fields(BnpState)})

    @cached_property
    def _innovation_cache(self) -> dict:
        """Predicted measurements of the learned components by component set (a pure cache)."""
        return {}

    def frame_base(self, state: LearnedBirthState):
        """:math:`H_k` of the frame after ``state``."""
        return learned_base(self.base, state.memory, self.settings, self._innovation_cache)

    def step(self, state: LearnedBirthState, frame: Frame, rng: np.random.Generator
             ) -> tuple[LearnedBirthState, Estimate]:
        """The parent's step with :math:`H_k` as its base distribution, then the memory's update."""
        view = copy.copy(self)
        view.__dict__["base"] = self.frame_base(state)  # the cached property, for this frame only
        inner, est = BnpTracker.step(view, state.inner(), frame, rng)
        s = self.settings
        lo, hi = state.frame - s.lag, frame.frame - s.lag
        births = birth_states(inner.labels, inner.mean, inner.cov, inner.existence, lo, hi, frame.frame, self.params.T)
        dt = frame_dt(state.frame, state.stamp_ns, frame.frame, frame.stamp_ns, self.params.T)
        decay = s.forgetting ** (dt / self.params.T)
        sensor = self.params.frame_sensor(frame) if births[2].size else None
        meas = self.params.measurement(frame.kind, sensor) if sensor is not None else None
        clutter = self.params.clutter(frame.kind, sensor) if sensor is not None else None
        mem = record(state.memory, self.base, s, meas, clutter, decay, births)
        new = LearnedBirthState(**{f.name: getattr(inner, f.name) for f in fields(BnpState)},
                                birth_pos=mem.pos, birth_cov=mem.cov, birth_weight=mem.weight,
                                birth_loglik=mem.loglik, birth_vel_stats=mem.vel_stats)
        diag = dict(est.diagnostics, birth_memory=float(mem.weight.size),
                    birth_uniform_weight=float(view.base.uniform_weight))
        return new, replace(est, diagnostics=diag)


def make_tracker(name: str, params: ModelParams, config: BnpConfig | None = None) -> BnpTracker:
    """:func:`tracker.bnp.filter.make_tracker`, or :class:`LearnedBirthTracker` when the
    configuration learns the base distribution."""
    tracker = _filter.make_tracker(name, params, config)
    cfg = tracker.config
    if cfg.learn_births or cfg.learn_birth_velocity:
        return LearnedBirthTracker(params, cfg, name)
    return tracker


__all__ = ["LearnedBirthState", "LearnedBirthTracker", "make_tracker", "TRACKER_PRESETS"]
