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
and the same seed gives the same draws on every machine (numpy's PCG64 and SeedSequence
are platform independent): the same frames, each with the same number of measurements in the
same order.  The values computed from the draws go through numpy's transcendental functions
(``arctan2``, ``sin``, ``cos``), whose vectorised versions depend on the CPU (``arctan2`` on
AVX-512 machines is not correctly rounded), so a value can differ in its last binary digit
between machines.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bnptrack.sources.scenarios import Scenario
from bnptrack.tracker.input_checks import SIM_SENSOR
from bnptrack.tracker.models.clutter import Detection, SectorClutter, UniformClutter
from bnptrack.tracker.models.measurement import measurement_kind, wrap_angle
from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import Frame, Truth

__all__ = ["measurement_frame_rng", "measure_with", "move_truth", "sensor_rng", "simulate", "simulate_sensors", "truth_at_time", "simulate_all", "simulate_frame"]


def measurement_frame_rng(seed: int, k: int) -> np.random.Generator:
    """The measurement stream of frame ``k`` for ``seed`` (spawn key ``(k,)``): detections,
    noise and clutter; the tracker draws from another stream,
    :func:`tracker.state.tracker_frame_rng`."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(k),)))


def measure_with(rng: np.random.Generator, truth: Truth, params: ModelParams, kind: str, sensor: str
                 ) -> tuple[np.ndarray, str, tuple[float, float, float] | None]:
    """One scan of shuffled measurements ``(M, d)`` of ``truth`` plus clutter by sensor
    ``sensor`` of ``params`` (its ``[sensors.NAME]`` table, else the default sensor of ``kind``):
    ``(z, kind, pose)``, ``pose`` ``None`` for an undeclared sensor.

    ``params`` must already be adapted to the scenario.  Draw order: detection indicators,
    target noise, clutter, permutation.
    """
    models = _Models.build(params, kind, sensor)
    return models.measure(rng, truth), models.kind, models.pose


class _Sampler(Protocol):
    """A measurement model (the registry's ``measurement_kind(kind).model``) as the simulator
    uses it."""

    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class _Models:
    """The sensor models of one run, built once."""

    kind: str
    detection: Detection
    measurement: _Sampler
    clutter: UniformClutter | SectorClutter
    pose: tuple[float, float, float] | None = None
    """Written into each frame when the sensor is declared (``[sensors.NAME]``)."""

    @classmethod
    def build(cls, params: ModelParams, kind: str, sensor: str = "") -> _Models:
        """The models of sensor ``sensor``: its ``[sensors.NAME]`` table (kind, pose, field of
        view, noise) when the parameter set declares one, else the default sensor."""
        spec = params.sensors.get(sensor)
        kind = spec.kind if spec is not None and spec.kind is not None else kind
        s = params.sensor(sensor, kind)
        return cls(kind, params.detection(kind, s), params.measurement(kind, s), params.clutter(kind, s),
                   s.pose if spec is not None else None)

    def measure(self, rng: np.random.Generator, truth: Truth) -> np.ndarray:
        spec = measurement_kind(self.kind)  # the registry entry: dimension, wrapped columns
        d = spec.dim
        parts = []
        if truth.states.shape[0]:
            detected = self.detection.sample(rng, truth.states)
            if detected.any():
                parts.append(self.measurement.sample(rng, truth.states[detected]))
        parts.append(np.asarray(self.clutter.sample(rng), dtype=float).reshape(-1, d))
        z = np.concatenate(parts, axis=0) if len(parts) > 1 else parts[0]
        z = z[rng.permutation(z.shape[0])]
        for col in spec.wrapped:
            z[:, col] = wrap_angle(z[:, col])
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
    z = models.measure(measurement_frame_rng(seed, k), truth)
    return Frame(
        frame=k,
        stamp_ns=int(round(k * T * 1e9)),
        sensor=sensor,
        kind=models.kind,
        z=z,
        truth=truth,
        pose=models.pose,
    )


def simulate(
    scenario: Scenario,
    params: ModelParams,
    seed: int,
    *,
    sensor: str = SIM_SENSOR,
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
    models = _Models.build(params, scenario.kind, sensor)
    truths = scenario.truth(params.T)
    for k in range(start_frame, scenario.K + 1):
        yield _frame(scenario, models, params.T, seed, k, truths[k - 1], sensor)


def simulate_frame(
    scenario: Scenario, params: ModelParams, seed: int, k: int, *, sensor: str = SIM_SENSOR
) -> Frame:
    """Frame ``k`` alone (identical to frame ``k`` of :func:`simulate`)."""
    if not 1 <= k <= scenario.K:
        raise ValueError(f"frame must be in 1..{scenario.K}, got {k}")
    params = scenario.adapt_params(params)
    truth = scenario.truth(params.T)[k - 1]
    models = _Models.build(params, scenario.kind, sensor)
    return _frame(scenario, models, params.T, seed, k, truth, sensor)


def simulate_all(
    scenario: Scenario,
    params: ModelParams,
    seed: int,
    *,
    sensor: str = SIM_SENSOR,
    start_frame: int = 1,
) -> list[Frame]:
    """All frames of :func:`simulate` as a list."""
    return list(simulate(scenario, params, seed, sensor=sensor, start_frame=start_frame))


def move_truth(truth: Truth, pose: tuple[float, float, float]) -> Truth:
    r"""``truth`` carried rigidly by ``pose = (x, y, heading)``: a scene laid out around a
    sensor at the origin facing +y, moved so that it lies around a sensor at ``pose``.

    Positions and velocities are rotated by the heading (clockwise from +y, so a direction
    ``[sin b, cos b]`` becomes ``[sin(b + h), cos(b + h)]``) and positions translated; turn
    rates are unchanged (a proper rotation keeps them).  The moved scene seen from ``pose``
    gives the same bearing-range measurements as the original seen from the origin.
    """
    x, y, h = (float(v) for v in pose)
    c, s = np.cos(h), np.sin(h)
    st = truth.states.copy()
    for i, j in ((0, 2), (1, 3)):  # positions, velocities
        a, b = truth.states[:, i], truth.states[:, j]
        st[:, i], st[:, j] = c * a + s * b, -s * a + c * b
    st[:, 0] += x
    st[:, 2] += y
    return Truth(truth.ids, st)


def truth_at_time(scenario: Scenario, t: float, T: float = 1.0) -> Truth:
    """Ground truth at time ``t`` seconds (scan ``k`` is at ``k T``): the objects present at
    scan ``floor(t / T)`` carried forward by the noiseless CT model over the remainder (the
    scenarios' own motion), so frames can be simulated at irregular times."""
    from bnptrack.tracker.models.motion import CoordinatedTurn

    k = int(np.floor(t / T + 1e-12))
    if not 1 <= k <= scenario.K:
        raise ValueError(f"time {t} s is outside scans 1..{scenario.K}")
    base = scenario.truth(T)[k - 1]
    rest = t - k * T
    if rest <= 0.0 or base.states.shape[0] == 0:
        return base
    return Truth(base.ids, CoordinatedTurn(T=rest).f(base.states))


def sensor_rng(seed: int, k: int, i: int) -> np.random.Generator:
    """The stream of sensor ``i``'s frame at scan ``k`` (sensor 0: :func:`measurement_frame_rng`)."""
    if i == 0:
        return measurement_frame_rng(seed, k)
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(k), int(i))))


def simulate_sensors(scenario: Scenario, params: ModelParams, seed: int, sensors: Sequence[str]
                     ) -> Iterator[Frame]:
    """Frames of several sensors observing one scene, interleaved by time.

    Every scan ``k`` yields one frame per sensor, in the order of ``sensors``, all stamped
    ``round(k T 10^9)`` (the sensors scan at the same instants) and numbered
    ``(k - 1) n + i + 1`` (``n`` sensors, ``i`` the sensor's index).  Sensor ``NAME`` uses its
    ``[sensors.NAME]`` table of ``params`` (kind, pose, field of view, noise; the pose is written
    into each frame); sensor ``i``'s measurements use :func:`sensor_rng`, so sensor 0's frames
    equal :func:`simulate`'s.
    """
    params = scenario.adapt_params(params)
    models = [_Models.build(params, scenario.kind, name) for name in sensors]
    truths = scenario.truth(params.T)
    n = len(sensors)
    for k in range(1, scenario.K + 1):
        for i, (name, m) in enumerate(zip(sensors, models)):
            z = m.measure(sensor_rng(seed, k, i), truths[k - 1])
            yield Frame((k - 1) * n + i + 1, int(round(k * params.T * 1e9)), name, m.kind, z,
                        truths[k - 1], pose=m.pose)
