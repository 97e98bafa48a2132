r"""Seeded measurement generator for the simulation scenarios.

:func:`simulate` turns a :class:`~sources.scenarios.Scenario` and a
:class:`~tracker.models.params.ModelParams` into a stream of :class:`~tracker.types.Frame`\ s,
one per scan ``k = 1..K``:

1. ``params = scenario.adapt_params(params)`` (once; e.g. the ``snr`` scenario's -3 dB default).
2. Each true target is detected with ``params.detection()``: probability ``P_D`` inside the
   sensor field, ``0`` beyond ``range_max`` or outside the bearing field of view (such a
   target still counts in the truth).
3. Detected targets are measured with ``params.measurement(kind).sample`` (noise std scaled by
   ``sqrt(10**(-snr_db/10))`` when ``snr_db`` is set).
4. Clutter is drawn with ``params.clutter(kind).sample`` (Poisson count, uniform in the box).
5. The measurements are shuffled, so their order carries no information; bearings are
   wrapped to ``[-pi, pi)``.

Randomness: frame ``k`` uses its own stream
``np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(k,)))``, drawn in the order
detection, target noise, clutter, permutation.  Frame ``k`` is therefore reproducible on its
own (a live source may start at any frame, see ``start_frame`` and :func:`simulate_frame`),
and the same seed gives the same frames on every machine (numpy's PCG64 and SeedSequence
are platform independent).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from sources.scenarios import Scenario
from tracker.models.clutter import Detection, UniformClutter
from tracker.models.measurement import BearingRange, RangeOnly, wrap_angle
from tracker.models.params import ModelParams
from tracker.types import MEASUREMENT_DIM, Frame, Truth

__all__ = ["frame_rng", "measure", "simulate", "simulate_all", "simulate_frame", "simulate_many"]


def frame_rng(seed: int, k: int) -> np.random.Generator:
    """The random stream of frame ``k`` for ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(k),)))


def measure(
    rng: np.random.Generator, truth: Truth, params: ModelParams, kind: str
) -> np.ndarray:
    """One scan of shuffled measurements ``(M, d)`` of ``truth`` plus clutter.

    ``params`` must already be adapted to the scenario.  Draw order: detection indicators,
    target noise, clutter, permutation.
    """
    return _Models.build(params, kind).measure(rng, truth)


@dataclass(frozen=True)
class _Models:
    """The sensor models of one run, built once."""

    kind: str
    detection: Detection
    measurement: BearingRange | RangeOnly
    clutter: UniformClutter

    @classmethod
    def build(cls, params: ModelParams, kind: str) -> _Models:
        return cls(kind, params.detection(kind), params.measurement(kind), params.clutter(kind))

    def measure(self, rng: np.random.Generator, truth: Truth) -> np.ndarray:
        d = MEASUREMENT_DIM[self.kind]
        parts = []
        if truth.states.shape[0]:
            detected = self.detection.sample(rng, truth.states)
            if detected.any():
                parts.append(self.measurement.sample(rng, truth.states[detected]))
        parts.append(np.asarray(self.clutter.sample(rng), dtype=float).reshape(-1, d))
        z = np.concatenate(parts, axis=0) if len(parts) > 1 else parts[0]
        z = z[rng.permutation(z.shape[0])]
        if self.kind == "bearing_range":
            z[:, 0] = wrap_angle(z[:, 0])
        return z


def _frame(
    scenario: Scenario,
    models: _Models,
    T: float,
    seed: int,
    k: int,
    truth: Truth,
    sensor: str,
) -> Frame:
    z = models.measure(frame_rng(seed, k), truth)
    return Frame(
        frame=k,
        stamp_ns=int(round(k * T * 1e9)),
        sensor=sensor,
        kind=scenario.kind,
        z=z,
        truth=truth,
    )


def simulate(
    scenario: Scenario,
    params: ModelParams,
    seed: int,
    *,
    sensor: str = "sim0",
    start_frame: int = 1,
) -> Iterator[Frame]:
    """Yield frames ``start_frame..K`` of ``scenario`` one at a time.

    Frame ``k`` has ``stamp_ns = round(k * T * 1e9)``, ``kind = scenario.kind``, ``z`` of
    shape ``(M, d)`` and the scan's :class:`Truth`.  Frame ``k`` does not depend on
    ``start_frame``.
    """
    if not 1 <= start_frame <= scenario.K + 1:
        raise ValueError(f"start_frame must be in 1..{scenario.K + 1}, got {start_frame}")
    params = scenario.adapt_params(params)
    models = _Models.build(params, scenario.kind)
    truths = scenario.truth(params.T)
    for k in range(start_frame, scenario.K + 1):
        yield _frame(scenario, models, params.T, seed, k, truths[k - 1], sensor)


def simulate_frame(
    scenario: Scenario, params: ModelParams, seed: int, k: int, *, sensor: str = "sim0"
) -> Frame:
    """Frame ``k`` alone (identical to frame ``k`` of :func:`simulate`)."""
    if not 1 <= k <= scenario.K:
        raise ValueError(f"frame must be in 1..{scenario.K}, got {k}")
    params = scenario.adapt_params(params)
    truth = scenario.truth(params.T)[k - 1]
    models = _Models.build(params, scenario.kind)
    return _frame(scenario, models, params.T, seed, k, truth, sensor)


def simulate_all(
    scenario: Scenario,
    params: ModelParams,
    seed: int,
    *,
    sensor: str = "sim0",
    start_frame: int = 1,
) -> list[Frame]:
    """All frames of :func:`simulate` as a list."""
    return list(simulate(scenario, params, seed, sensor=sensor, start_frame=start_frame))


def simulate_many(
    scenario: Scenario, params: ModelParams, seeds: Sequence[int], *, sensor: str = "sim0"
) -> Iterator[list[Frame]]:
    """One full run per seed (Monte Carlo helper)."""
    for seed in seeds:
        yield simulate_all(scenario, params, seed, sensor=sensor)
