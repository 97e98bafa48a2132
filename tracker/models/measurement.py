r"""Sensor models at a sensor pose ``(sensor_x, sensor_y, heading)`` (the origin, boresight
:math:`+y`, by default).

Bearing is measured from the sensor's boresight, positive clockwise: the boresight's own
direction (``heading``) is measured from :math:`+y` towards :math:`+x` like every bearing
(Vo et al. 2017's convention; see ``docs/models.md`` for why we do not use the paper's
:math:`\arctan(y/x)`).  ``noise`` (a ``d x d`` covariance as nested tuples) replaces the
diagonal noise of the sigmas when set (a frame's ``R``).

:data:`KINDS` is the registry of measurement kinds: name -> model class, dimension, wrapped
(angle) columns, value bounds, clutter model and detection region; the codec, the simulator,
``Frame`` and the parameter set look kinds up there.  A new kind is its model class (with a
``from_sensor`` classmethod) plus its entry in :data:`KINDS`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

from bnptrack.tracker.models._gauss import gaussian_logpdf
from bnptrack.tracker.models.clutter import ClutterModel, SectorClutter, UniformClutter

if TYPE_CHECKING:
    from bnptrack.tracker.models.sensors import Sensor

Noise = tuple[tuple[float, ...], ...] | None


def _rotate(pos: np.ndarray, cov: np.ndarray | None, heading: float, x: float, y: float):
    """Sensor-frame positions ``(M, 2)`` (and covariances) to the world frame: rotate by the
    heading (clockwise from +y, so a sensor-frame ``[sin b, cos b]`` becomes
    ``[sin(b + h), cos(b + h)]``) and translate by the sensor position."""
    if heading:
        c, s = np.cos(heading), np.sin(heading)
        Rm = np.array([[c, s], [-s, c]])
        pos = pos @ Rm.T
        if cov is not None:
            cov = Rm @ cov @ Rm.T
    return pos + np.array([x, y]), cov


class MeasurementModel(Protocol):
    """What every measurement kind's model offers (:mod:`tracker.filtering` uses ``dim``,
    ``R``, ``h``, ``jacobian``, ``residual``; births use ``to_cartesian`` and
    ``birth_position``; the simulator ``sample``)."""

    dim: int
    kind: str
    fixes_position: ClassVar[bool]
    """Whether one row fixes a position (:meth:`to_cartesian` is the measured point); a kind
    whose rows leave a direction free (range-only) also offers ``locus(z, bearings)`` (the
    ``(M, A, 2)`` positions consistent with each row at the ``A`` world bearings) and
    ``locus_point(z, toward)`` (the ``(M, 2)`` point of each row's locus nearest ``toward``;
    NaN rows: a default point).  The Rerun sink draws measurements through these."""

    @property
    def R(self) -> np.ndarray: ...
    def h(self, x: np.ndarray) -> np.ndarray: ...
    def jacobian(self, x: np.ndarray) -> np.ndarray: ...
    def residual(self, z: np.ndarray, z_pred: np.ndarray) -> np.ndarray: ...
    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray: ...
    def logpdf(self, z: np.ndarray, x: np.ndarray) -> np.ndarray: ...
    def to_cartesian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
    def birth_position(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles to :math:`[-\\pi, \\pi)`."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class BearingRange:
    r"""Bearing-range sensor (paper eq. (11) with the simulation section's :math:`R(\cdot)`).

    .. math::

        z = h(x) + w, \qquad
        h(x) = \begin{bmatrix} \operatorname{wrap}(\operatorname{atan2}(p_x - s_x,\; p_y - s_y) - \psi) \\
                               \sqrt{(p_x - s_x)^2 + (p_y - s_y)^2} \end{bmatrix},
        \qquad w \sim \mathcal N\!\left(0, \operatorname{diag}(\sigma_\phi^2, \sigma_r^2)\right)

    with :math:`\psi` the heading (``0``: the angle is not wrapped).
    Bearing residuals are wrapped to :math:`[-\pi, \pi)`.
    """

    sigma_bearing: float = np.deg2rad(2.0)
    sigma_range: float = 10.0
    sensor_x: float = 0.0
    sensor_y: float = 0.0
    heading: float = 0.0
    noise: Noise = None

    dim: int = 2
    kind: str = "bearing_range"
    fixes_position: ClassVar[bool] = True

    @classmethod
    def from_sensor(cls, s: Sensor) -> BearingRange:
        """The model of the resolved sensor ``s`` (its pose, sigmas and ``R``)."""
        return cls(s.sigma_bearing, s.sigma_range, s.x, s.y, s.heading, s.noise)

    @cached_property
    def R(self) -> np.ndarray:
        """Measurement noise covariance ``(2, 2)``."""
        if self.noise is not None:
            return np.array(self.noise, dtype=float)
        return np.diag([self.sigma_bearing**2, self.sigma_range**2])

    def h(self, x: np.ndarray) -> np.ndarray:
        """Noise-free measurement of ``(N, >=3)`` states -> ``(N, 2)``."""
        x = np.asarray(x, dtype=float)
        dx = x[..., 0] - self.sensor_x
        dy = x[..., 2] - self.sensor_y
        phi = np.arctan2(dx, dy)
        if self.heading:
            phi = wrap_angle(phi - self.heading)
        return np.stack([phi, np.hypot(dx, dy)], axis=-1)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        r"""``(N, 2, n)`` Jacobian :math:`\partial h/\partial x` (zeros for velocity, turn rate;
        the heading is a constant offset).

        .. math::
            \frac{\partial\phi}{\partial p_x} = \frac{\Delta y}{r^2},\;
            \frac{\partial\phi}{\partial p_y} = -\frac{\Delta x}{r^2},\;
            \frac{\partial r}{\partial p_x} = \frac{\Delta x}{r},\;
            \frac{\partial r}{\partial p_y} = \frac{\Delta y}{r}
        """
        x = np.atleast_2d(np.asarray(x, dtype=float))
        dx = x[:, 0] - self.sensor_x
        dy = x[:, 2] - self.sensor_y
        r2 = np.maximum(dx**2 + dy**2, 1e-12)
        r = np.sqrt(r2)
        H = np.zeros((x.shape[0], 2, x.shape[1]))
        H[:, 0, 0] = dy / r2
        H[:, 0, 2] = -dx / r2
        H[:, 1, 0] = dx / r
        H[:, 1, 2] = dy / r
        return H

    def residual(self, z: np.ndarray, z_pred: np.ndarray) -> np.ndarray:
        """``z - z_pred`` with the bearing component wrapped (broadcasts)."""
        d = np.asarray(z, dtype=float) - np.asarray(z_pred, dtype=float)
        d[..., 0] = wrap_angle(d[..., 0])
        return d

    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
        """Draw one noisy measurement per state row in canonical polar form: a negative noisy
        range ``r`` is written as the same point of the plane, range ``|r|`` at the opposite
        bearing (``+ pi``); bearing wrapped."""
        zp = self.h(np.atleast_2d(x))
        if self.noise is None:
            z = zp + rng.standard_normal(zp.shape) * np.array([self.sigma_bearing, self.sigma_range])
        else:
            z = zp + rng.standard_normal(zp.shape) @ np.linalg.cholesky(self.R).T
        behind = z[:, 1] < 0.0
        if behind.any():
            z[behind, 1] = -z[behind, 1]
            z[behind, 0] += np.pi
        z[:, 0] = wrap_angle(z[:, 0])
        return z

    def logpdf(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """:math:`\\log \\mathcal N(z; h(x), R)` for paired rows of ``z`` and ``x``."""
        return gaussian_logpdf(self.residual(np.atleast_2d(z), self.h(np.atleast_2d(x))), self.R)

    def to_cartesian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""Convert ``(M, 2)`` bearing-range measurements to world positions and covariances.

        .. math::
            p = s + r\,[\sin(\phi + \psi), \cos(\phi + \psi)]^T, \qquad
            P = J R J^T, \quad
            J = \begin{bmatrix} r\cos\phi' & \sin\phi' \\ -r\sin\phi' & \cos\phi' \end{bmatrix},
            \ \phi' = \phi + \psi

        Returns ``(M, 2)`` positions ``[p_x, p_y]`` and ``(M, 2, 2)`` first-order covariances.
        """
        z = np.atleast_2d(np.asarray(z, dtype=float))
        phi, r = z[:, 0], z[:, 1]
        if self.heading:
            phi = phi + self.heading
        s, c = np.sin(phi), np.cos(phi)
        pos = np.stack([self.sensor_x + r * s, self.sensor_y + r * c], axis=-1)
        J = np.empty((z.shape[0], 2, 2))
        J[:, 0, 0] = r * c
        J[:, 0, 1] = s
        J[:, 1, 0] = -r * s
        J[:, 1, 1] = c
        cov = J @ self.R @ np.swapaxes(J, 1, 2)
        return pos, cov

    def birth_position(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position and covariance of a new object seen at ``z`` (:meth:`to_cartesian`)."""
        return self.to_cartesian(z)


@dataclass(frozen=True)
class RangeOnly:
    r"""Range-only sensor (the paper's varying-SNR experiment).

    .. math::
        z = \sqrt{(p_x - s_x)^2 + (p_y - s_y)^2} + w, \qquad w \sim \mathcal N(0, \sigma_r^2)
    """

    sigma_range: float = 10.0
    sensor_x: float = 0.0
    sensor_y: float = 0.0
    half_fov: float = np.pi / 2
    """Half-width of the bearing field of view (rad); only the birth position uses it."""
    heading: float = 0.0
    noise: Noise = None

    dim: int = 1
    kind: str = "range"
    fixes_position: ClassVar[bool] = False
    """A range leaves the bearing free: the positions of a row are a ring (:meth:`locus`)."""

    @classmethod
    def from_sensor(cls, s: Sensor) -> RangeOnly:
        """The model of the resolved sensor ``s`` (its pose, field of view, sigma and ``R``)."""
        return cls(s.sigma_range, s.x, s.y, s.half_fov, s.heading, s.noise)

    @cached_property
    def R(self) -> np.ndarray:
        if self.noise is not None:
            return np.array(self.noise, dtype=float)
        return np.array([[self.sigma_range**2]])

    def h(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.hypot(x[..., 0] - self.sensor_x, x[..., 2] - self.sensor_y)[..., None]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(np.asarray(x, dtype=float))
        dx = x[:, 0] - self.sensor_x
        dy = x[:, 2] - self.sensor_y
        r = np.maximum(np.hypot(dx, dy), 1e-6)
        H = np.zeros((x.shape[0], 1, x.shape[1]))
        H[:, 0, 0] = dx / r
        H[:, 0, 2] = dy / r
        return H

    def residual(self, z: np.ndarray, z_pred: np.ndarray) -> np.ndarray:
        return np.asarray(z, dtype=float) - np.asarray(z_pred, dtype=float)

    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
        """Draw one noisy range per state row; a negative noisy range ``r`` is written as
        ``|r|`` (the same ring of points around the sensor)."""
        zp = self.h(np.atleast_2d(x))
        sigma = self.sigma_range if self.noise is None else np.sqrt(self.R[0, 0])
        return np.abs(zp + sigma * rng.standard_normal(zp.shape))

    def logpdf(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        return gaussian_logpdf(self.residual(np.atleast_2d(z), self.h(np.atleast_2d(x))), self.R)

    def to_cartesian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""Moment-matched position of ``(M, 1)`` range measurements: the bearing is not
        observed, so the object is anywhere on the arc of radius ``r`` inside the field of
        view.  With :math:`\phi \sim \mathcal U(-h, h)` (``h = half_fov``) and
        :math:`\rho \sim \mathcal N(r, \sigma_r^2)`, :math:`p = s + \rho [\sin\phi, \cos\phi]^T`
        (sensor frame, then rotated by the heading):

        .. math::
            E[p] = s + r\,[0,\ \tfrac{\sin h}{h}]^T, \qquad
            \operatorname{Cov}[p] = (r^2 + \sigma_r^2)\operatorname{diag}(a, b)
                - r^2 \big(\tfrac{\sin h}{h}\big)^2 e_y e_y^T,

        :math:`a = \tfrac12 - \tfrac{\sin 2h}{4h}`, :math:`b = \tfrac12 + \tfrac{\sin 2h}{4h}`
        (the exact first two moments of that arc distribution).  Returns ``(M, 2)`` positions
        and ``(M, 2, 2)`` covariances.
        """
        r = np.atleast_2d(np.asarray(z, dtype=float))[:, 0]
        h = float(self.half_fov)
        c = np.sin(h) / h
        a, b = 0.5 - np.sin(2 * h) / (4 * h), 0.5 + np.sin(2 * h) / (4 * h)
        pos = np.stack([np.zeros(r.shape), r * c], axis=-1)
        second = r**2 + self.R[0, 0]
        cov = np.zeros((r.size, 2, 2))
        cov[:, 0, 0] = second * a
        cov[:, 1, 1] = second * b - (r * c) ** 2
        return _rotate(pos, cov, self.heading, self.sensor_x, self.sensor_y)

    def birth_position(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A new object's position from its range: on the boresight at range ``r``, spread
        uniformly along the arc (variance ``(2 h r)^2 / 12`` across, ``sigma_r^2`` along)."""
        rng_m = np.atleast_2d(np.asarray(z, dtype=float))[:, 0]
        n = rng_m.size
        pos = np.stack([np.zeros(n), rng_m], axis=1)
        pcov = np.zeros((n, 2, 2))
        pcov[:, 0, 0] = (rng_m * 2 * self.half_fov) ** 2 / 12.0
        pcov[:, 1, 1] = self.R[0, 0]
        return _rotate(pos, pcov, self.heading, self.sensor_x, self.sensor_y)

    def locus(self, z: np.ndarray, bearings: np.ndarray) -> np.ndarray:
        """``(M, A, 2)``: the positions consistent with each range row, the ring of radius
        ``r`` around the sensor, at the ``A`` world ``bearings`` (from +y, clockwise)."""
        r = np.atleast_2d(np.asarray(z, dtype=float))[:, 0]
        b = np.asarray(bearings, dtype=float)
        return np.stack([self.sensor_x + r[:, None] * np.sin(b)[None],
                         self.sensor_y + r[:, None] * np.cos(b)[None]], -1)

    def locus_point(self, z: np.ndarray, toward: np.ndarray) -> np.ndarray:
        """``(M, 2)``: the point of each row's ring nearest the position ``toward[i]``; a NaN
        row of ``toward``: the ring's point straight up (+y) from the sensor."""
        r = np.atleast_2d(np.asarray(z, dtype=float))[:, 0]
        t = np.asarray(toward, dtype=float).reshape(-1, 2)
        known = ~np.isnan(t).any(axis=1)
        ang = np.zeros(r.shape[0])
        if known.any():
            ang[known] = np.arctan2(t[known, 0] - self.sensor_x, t[known, 1] - self.sensor_y)
        return np.stack([self.sensor_x + r * np.sin(ang), self.sensor_y + r * np.cos(ang)], axis=-1)


@dataclass(frozen=True)
class Cartesian:
    r"""Cartesian position detections in the world frame (kind ``"xy"``): camera or lidar
    detections projected to the ground, ADS-B and AIS positions.

    .. math::
        z = H x + w, \qquad H = \begin{bmatrix}1&0&0&0&0\\0&0&1&0&0\end{bmatrix}, \qquad
        w \sim \mathcal N(0, R), \quad R = \sigma^2 I \text{ (or the frame's } R)

    Linear, so the EKF and the UKF are both the Kalman filter.  The sensor pose does not enter
    the measurement (it only bounds the field of view, :class:`~tracker.models.clutter.Detection`).
    """

    sigma: float = 10.0
    sensor_x: float = 0.0
    sensor_y: float = 0.0
    heading: float = 0.0
    noise: Noise = None

    dim: int = 2
    kind: str = "xy"
    fixes_position: ClassVar[bool] = True

    @classmethod
    def from_sensor(cls, s: Sensor) -> Cartesian:
        """The model of the resolved sensor ``s`` (its pose, sigma and ``R``)."""
        return cls(s.sigma_xy, s.x, s.y, s.heading, s.noise)

    @cached_property
    def R(self) -> np.ndarray:
        if self.noise is not None:
            return np.array(self.noise, dtype=float)
        return self.sigma**2 * np.eye(2)

    def h(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.stack([x[..., 0], x[..., 2]], axis=-1)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(np.asarray(x, dtype=float))
        H = np.zeros((x.shape[0], 2, x.shape[1]))
        H[:, 0, 0] = H[:, 1, 2] = 1.0
        return H

    def residual(self, z: np.ndarray, z_pred: np.ndarray) -> np.ndarray:
        return np.asarray(z, dtype=float) - np.asarray(z_pred, dtype=float)

    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
        zp = self.h(np.atleast_2d(x))
        return zp + rng.standard_normal(zp.shape) @ np.linalg.cholesky(self.R).T

    def logpdf(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        return gaussian_logpdf(self.residual(np.atleast_2d(z), self.h(np.atleast_2d(x))), self.R)

    def to_cartesian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M, 2)`` positions (the measurements) and ``(M, 2, 2)`` covariances ``R``."""
        z = np.atleast_2d(np.asarray(z, dtype=float))
        return z.copy(), np.broadcast_to(self.R, (z.shape[0], 2, 2)).copy()

    def birth_position(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A new object's position is measured; its velocity comes from the prior."""
        return self.to_cartesian(z)


# --------------------------------------------------------------------------- kinds registry


def _bearing_range_clutter(s: Sensor) -> UniformClutter:
    """Uniform over the field of view in (bearing, range) space."""
    return UniformClutter(s.clutter_rate, (-s.half_fov, s.range_min), (s.half_fov, s.range_max))


def _range_clutter(s: Sensor) -> UniformClutter:
    """Uniform over the range interval."""
    return UniformClutter(s.clutter_rate, (s.range_min,), (s.range_max,))


def _sector_clutter(s: Sensor) -> SectorClutter:
    """Uniform over the field of view's sector in world coordinates."""
    return SectorClutter(s.clutter_rate, s.range_min, s.range_max, s.half_fov, s.x, s.y, s.heading)


@dataclass(frozen=True)
class MeasurementKind:
    """One measurement kind: its model class (built by ``model.from_sensor(sensor)``), row
    dimension, wrapped (angle) columns, per-column value bounds (inclusive; what the codec
    accepts), its clutter model of a sensor (uniform over the field of view in its
    measurement space), whether its detection region ignores bearings (``range_only``),
    the :class:`~tracker.models.params.ModelParams` field, if any, that overrides
    ``clutter_rate`` for it, and example rows for the warm-up."""

    name: str
    model: type
    dim: int
    wrapped: tuple[int, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    columns: str
    clutter: Callable[[Any], ClutterModel]
    range_only: bool = False
    clutter_rate_field: str | None = None
    world_frame: bool = False
    """Rows are world coordinates: the sensor's pose does not move them, it only bounds the
    field of view and the clutter region."""
    examples: tuple[tuple[float, ...], ...] = ()
    """A few typical rows: the pipeline's warm-up (:func:`tracker.registry.warm_up`) steps a
    tracker on frames of them so its kernels compile before the first real frame (none: the
    kind is not warmed up)."""

    def measurement(self, sensor: Sensor) -> MeasurementModel:
        """The measurement model of ``sensor`` for this kind."""
        return self.model.from_sensor(sensor)


_BIG = float(np.finfo(float).max)

#: The registry: every place that needs to know a kind (Frame, codec, simulator, trackers,
#: sinks) looks it up here.  Register a new kind by adding one entry (and its model).
KINDS: dict[str, MeasurementKind] = {
    "bearing_range": MeasurementKind("bearing_range", BearingRange, 2, (0,), (-np.pi, 0.0), (np.pi, _BIG),
                                     "[bearing_rad, range_m]", _bearing_range_clutter,
                                     examples=((0.1, 500.0), (0.2, 800.0), (-0.3, 1200.0), (0.5, 300.0))),
    "range": MeasurementKind("range", RangeOnly, 1, (), (0.0,), (_BIG,), "[range_m]", _range_clutter,
                             range_only=True, clutter_rate_field="range_clutter_rate",
                             examples=((500.0,), (800.0,), (1200.0,))),
    "xy": MeasurementKind("xy", Cartesian, 2, (), (-_BIG, -_BIG), (_BIG, _BIG), "[x_m, y_m]", _sector_clutter,
                         world_frame=True),
}

#: The kind of a frame or sensor that does not say (the paper's bearing-range radar).
DEFAULT_KIND = "bearing_range"


def measurement_kind(kind: str) -> MeasurementKind:
    """The registry entry of ``kind`` (``ValueError`` listing the known kinds otherwise)."""
    try:
        return KINDS[kind]
    except KeyError:
        raise ValueError(f"unknown measurement kind {kind!r} (known: {', '.join(KINDS)})") from None
