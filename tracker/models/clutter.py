r"""Clutter and detection models."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np


class ClutterModel(Protocol):
    """What a kind's clutter model offers: Poisson rate, log density and intensity inside its
    region, the log density of measurements and one scan of samples."""

    rate: float

    @property
    def log_density(self) -> float: ...
    @property
    def log_intensity(self) -> float: ...
    def logpdf(self, z: np.ndarray) -> np.ndarray: ...
    def sample(self, rng: np.random.Generator) -> np.ndarray: ...


@dataclass(frozen=True)
class UniformClutter:
    r"""Poisson clutter, uniform over a box in measurement space.

    .. math::
        |K| \sim \operatorname{Poisson}(\lambda_c), \qquad
        \kappa(z) = \lambda_c \, u(z), \quad u(z) = \frac{\mathbb 1[z \in V]}{|V|}

    For the bearing-range sensor :math:`V = [-\pi/2, \pi/2] \times [0, 2000]`, so
    :math:`u = 1/(2000\pi)` per rad·m (Vo et al. 2017).
    """

    rate: float = 15.0
    low: tuple[float, ...] = (-np.pi / 2, 0.0)
    high: tuple[float, ...] = (np.pi / 2, 2000.0)

    @cached_property
    def volume(self) -> float:
        return float(np.prod(np.subtract(self.high, self.low)))

    @cached_property
    def log_density(self) -> float:
        """:math:`\\log u(z)` inside the box."""
        return -float(np.log(self.volume))

    @cached_property
    def log_intensity(self) -> float:
        """:math:`\\log \\kappa(z) = \\log\\lambda_c + \\log u(z)` inside the box."""
        return float(np.log(self.rate)) + self.log_density if self.rate > 0 else -np.inf

    def logpdf(self, z: np.ndarray) -> np.ndarray:
        """:math:`\\log u(z)` for ``(M, d)`` measurements (``-inf`` outside the box)."""
        z = np.atleast_2d(z)
        inside = np.all((z >= self.low) & (z <= self.high), axis=-1)
        return np.where(inside, self.log_density, -np.inf)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Draw one scan of clutter, ``(K, d)`` with ``K ~ Poisson(rate)``."""
        n = rng.poisson(self.rate)
        low, high = np.asarray(self.low), np.asarray(self.high)
        return low + rng.random((n, low.size)) * (high - low)


@dataclass(frozen=True)
class Detection:
    r"""State-dependent detection probability.

    .. math::
        P_D(x) = \begin{cases} p_D & \text{if } r(x) \le r_{\max} \text{ and }
        \phi(x) \in [\phi_{\min}, \phi_{\max}] \\ 0 & \text{otherwise} \end{cases}

    A target beyond the sensor's range or outside its bearing field of view is not detected
    (it still counts in the truth).

    SNR option (Swerling I; off unless ``snr_reference_db`` is set): with the false-alarm
    probability fixed by requiring :math:`p_D` at the reference SNR,
    :math:`P_{FA} = p_D^{1 + \mathrm{snr}_{ref}}`, the detection probability at SNR
    :math:`\mathrm{snr}` (linear) is

    .. math::
        p_D(\mathrm{snr}) = P_{FA}^{1/(1+\mathrm{snr})}
        = p_D^{(1+\mathrm{snr}_{ref})/(1+\mathrm{snr})} .
    """

    p_detect: float = 0.98
    range_max: float = 2000.0
    bearing_min: float = -np.pi / 2
    bearing_max: float = np.pi / 2
    snr_db: float | None = None
    snr_reference_db: float | None = None
    sensor_x: float = 0.0
    sensor_y: float = 0.0
    range_only: bool = False
    """A range-only sensor has no bearing limits (only the range limit applies)."""
    heading: float = 0.0
    """Boresight direction (rad, from +y towards +x); bearings are relative to it."""
    range_min: float = 0.0

    @cached_property
    def p_detect_effective(self) -> float:
        """:math:`p_D` after the optional Swerling-I SNR correction."""
        if self.snr_db is None or self.snr_reference_db is None:
            return self.p_detect
        snr = 10.0 ** (self.snr_db / 10.0)
        ref = 10.0 ** (self.snr_reference_db / 10.0)
        return float(self.p_detect ** ((1.0 + ref) / (1.0 + snr)))

    def visible(self, x: np.ndarray) -> np.ndarray:
        """``(N,)`` booleans: the state's position lies inside the field of view."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        dx = x[:, 0] - self.sensor_x
        dy = x[:, 2] - self.sensor_y
        r = np.hypot(dx, dy)
        in_range = r <= self.range_max
        if self.range_min > 0.0:
            in_range &= r >= self.range_min
        if self.range_only:
            return in_range
        phi = np.arctan2(dx, dy)
        if self.heading:
            phi = (phi - self.heading + np.pi) % (2.0 * np.pi) - np.pi
        return in_range & (phi >= self.bearing_min) & (phi <= self.bearing_max)

    def prob(self, x: np.ndarray) -> np.ndarray:
        """``(N,)`` detection probabilities of ``(N, >=3)`` states."""
        return np.where(self.visible(x), self.p_detect_effective, 0.0)

    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
        """``(N,)`` boolean detection indicators."""
        p = self.prob(x)
        return rng.random(p.shape) < p


@dataclass(frozen=True)
class SectorClutter:
    r"""Poisson clutter uniform over a sensor's field of view in world coordinates (kind
    ``"xy"``): the annular sector of ranges ``[range_min, range_max]`` and bearings
    ``+-half_fov`` about the heading, seen from ``(sensor_x, sensor_y)``.

    .. math::
        u(z) = \frac{\mathbb 1[z \in V]}{|V|}, \qquad
        |V| = h\,(r_{\max}^2 - r_{\min}^2)

    (a sector of angle :math:`2h`).  Sampling: :math:`r = \sqrt{U(r_{\min}^2, r_{\max}^2)}`,
    :math:`\phi \sim U(-h, h)`, which is uniform in area.
    """

    rate: float = 15.0
    range_min: float = 0.0
    range_max: float = 2000.0
    half_fov: float = np.pi / 2
    sensor_x: float = 0.0
    sensor_y: float = 0.0
    heading: float = 0.0

    @cached_property
    def volume(self) -> float:
        return float(self.half_fov * (self.range_max**2 - self.range_min**2))

    @cached_property
    def log_density(self) -> float:
        return -float(np.log(self.volume))

    @cached_property
    def log_intensity(self) -> float:
        return float(np.log(self.rate)) + self.log_density if self.rate > 0 else -np.inf

    def _region(self) -> Detection:
        return Detection(1.0, self.range_max, -self.half_fov, self.half_fov, sensor_x=self.sensor_x,
                         sensor_y=self.sensor_y, heading=self.heading, range_min=self.range_min)

    def logpdf(self, z: np.ndarray) -> np.ndarray:
        z = np.atleast_2d(np.asarray(z, dtype=float))
        states = np.zeros((z.shape[0], 3))
        states[:, 0], states[:, 2] = z[:, 0], z[:, 1]
        return np.where(self._region().visible(states), self.log_density, -np.inf)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        n = rng.poisson(self.rate)
        r = np.sqrt(self.range_min**2 + rng.random(n) * (self.range_max**2 - self.range_min**2))
        phi = self.heading + self.half_fov * (2.0 * rng.random(n) - 1.0)
        return np.stack([self.sensor_x + r * np.sin(phi), self.sensor_y + r * np.cos(phi)], axis=-1)
