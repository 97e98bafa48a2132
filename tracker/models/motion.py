r"""Motion (transition) models on batch-first state arrays.

All models act on ``(N, n)`` arrays of states and are frozen dataclasses, so they can be
shared freely between trackers, sources and tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bnptrack.tracker.models._gauss import gaussian_logpdf

_OMEGA_EPS = 1e-10


def process_noise_block(dt: float, sigma_accel: float, period: float) -> np.ndarray:
    r"""Per-axis position/velocity block of :math:`Q(\Delta t)` (``(2, 2)``), with
    :math:`q = \sigma_a^2 T_0` (``period`` :math:`= T_0`):

    .. math::

        Q_{pv}(\Delta t) = q \begin{bmatrix} c(\Delta t) & \Delta t^2/2 \\
            \Delta t^2/2 & \Delta t \end{bmatrix}, \qquad
        c(\Delta t) = \begin{cases} \Delta t^3/4 & \Delta t \le T_0 \\
            \Delta t^3/3 - T_0^2 \Delta t / 12 & \Delta t \ge T_0 \end{cases}

    At :math:`\Delta t = T_0` both give the paper's :math:`\sigma_a^2 [[T_0^4/4, T_0^3/2],
    [T_0^3/2, T_0^2]]`.  For :math:`\Delta t = n T_0` the second is the sum
    :math:`\sum_{i<n} F^i Q(T_0) F^{iT}` (``n`` paper steps; :math:`\sum (i + 1/2)^2 =
    n^3/3 - n/12`), and for :math:`\Delta t_1, \Delta t_2 \ge T_0` it composes exactly:
    :math:`F(\Delta t_2) Q(\Delta t_1) F(\Delta t_2)^T + Q(\Delta t_2) = Q(\Delta t_1 +
    \Delta t_2)` (constant-velocity :math:`F`).  Below :math:`T_0` the second is indefinite,
    so the paper's rank-one form is kept with the acceleration variance scaled by
    :math:`T_0/\Delta t` (velocity variance still :math:`q \Delta t`)."""
    dt, q = abs(float(dt)), sigma_accel**2 * period
    c = dt**3 / 4 if dt <= period else dt**3 / 3 - period**2 * dt / 12
    return q * np.array([[c, dt**2 / 2], [dt**2 / 2, dt]])


def _chol2(B: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a PSD ``(2, 2)`` block (the Schur complement clipped at 0, so a
    block that is singular up to rounding factors too)."""
    a = np.sqrt(B[0, 0])
    b = B[1, 0] / a
    return np.array([[a, 0.0], [b, np.sqrt(max(B[1, 1] - b * b, 0.0))]])


@dataclass(frozen=True)
class CoordinatedTurn:
    r"""Coordinated-turn model with unknown turn rate (paper, Sec. 6; Vo et al. 2017, IV.B).

    State :math:`x = [p_x, v_x, p_y, v_y, \omega]^T`, sampling period :math:`T`.

    .. math::

        x_k = F(x_{k-1}) + G u_{k-1}, \qquad u_{k-1} \sim \mathcal N(0, I_3)

        F(x) = \begin{bmatrix}
            p_x + \frac{\sin\omega T}{\omega} v_x - \frac{1-\cos\omega T}{\omega} v_y \\
            \cos(\omega T) v_x - \sin(\omega T) v_y \\
            \frac{1-\cos\omega T}{\omega} v_x + p_y + \frac{\sin\omega T}{\omega} v_y \\
            \sin(\omega T) v_x + \cos(\omega T) v_y \\
            \omega
        \end{bmatrix}

        G = \operatorname{blockdiag}\!\left(\sigma_a \begin{bmatrix} T^2/2 \\ T\end{bmatrix},
            \sigma_a \begin{bmatrix} T^2/2 \\ T\end{bmatrix}, T \sigma_\omega\right),
        \qquad Q = G G^T .

    Per axis :math:`Q` is :math:`\sigma_a^2 [[T^4/4, T^3/2],[T^3/2, T^2]]`, the paper's
    :math:`Q_u` at :math:`T = 1` (the matrix :math:`D` and :math:`Q_u` of the paper's
    simulation section).  For :math:`|\omega| < 10^{-10}` the straight-line limit
    (:math:`\sin\omega T/\omega \to T`, :math:`(1-\cos\omega T)/\omega \to 0`) is used.

    **Other intervals.**  ``period`` is the scan period :math:`T_0` at which ``sigma_accel`` and
    ``sigma_turn`` are stated (``None``: ``T`` itself, the paper's model above).  Predicting
    over :math:`\Delta t = T \ne T_0` uses :math:`Q(\Delta t)` of :func:`process_noise_block`
    (docs/models.md, "Time between frames"): it equals the paper's :math:`Q` at
    :math:`\Delta t = T_0`, the :math:`n`-fold composition of the paper's step at
    :math:`\Delta t = n T_0` (a dropped frame is predicted as if the sensor had scanned and seen
    nothing), composes exactly for :math:`\Delta t \ge T_0`; below :math:`T_0` its velocity and
    turn-rate entries grow linearly in :math:`\Delta t` and its cross entry quadratically (Wiener velocity of intensity
    :math:`q = \sigma_a^2 T_0`, turn rate of intensity :math:`\sigma_\omega^2 T_0`).
    """

    T: float = 1.0
    sigma_accel: float = 5.0
    sigma_turn: float = np.pi / 180.0
    period: float | None = None
    """Scan period :math:`T_0` the noise is stated for (``None``: ``T``)."""

    ndim: int = 5

    @cached_property
    def G(self) -> np.ndarray:
        r"""Noise gain with :math:`Q = G G^T`: ``(5, 3)`` (rank 3) for :math:`\Delta t \le T_0`,
        ``(5, 5)`` (the blocks' Cholesky factors) beyond.  Noise is defined forward in time
        only: a negative ``T`` (the scenarios' noise-free back-propagation of a path with
        :meth:`f`) has no ``G``."""
        T, s = self.T, self.sigma_accel
        if not T >= 0:  # also NaN
            raise ValueError(f"CoordinatedTurn: process noise over T = {T!r}: T must be >= 0")
        T0 = T if self.period is None else float(self.period)
        if T == T0:  # the paper's G, bit for bit
            g = np.zeros((5, 3))
            g[0:2, 0] = s * np.array([T**2 / 2, T])
            g[2:4, 1] = s * np.array([T**2 / 2, T])
            g[4, 2] = T * self.sigma_turn
            return g
        L = _chol2(process_noise_block(T, s, T0)) if abs(T) > T0 else None
        g = np.zeros((5, 3 if L is None else 5))
        if L is None:  # the paper's shape, acceleration variance scaled by T0/|dt|
            col = s * np.sqrt(T0 / abs(T)) * np.array([T**2 / 2, T]) if T != 0 else np.zeros(2)
            g[0:2, 0], g[2:4, 1] = col, col
            g[4, 2] = self.sigma_turn * np.sqrt(T0 * abs(T))
        else:
            g[0:2, 0:2], g[2:4, 2:4] = L, L
            g[4, 4] = self.sigma_turn * np.sqrt(T0 * abs(T))
        return g

    @cached_property
    def Q(self) -> np.ndarray:
        """Process noise covariance :math:`G G^T` (``(5, 5)``, rank 3)."""
        return self.G @ self.G.T

    def _turn_terms(self, omega: np.ndarray) -> tuple[np.ndarray, ...]:
        wT = omega * self.T
        small = np.abs(omega) < _OMEGA_EPS
        safe = np.where(small, 1.0, omega)
        sin_w = np.where(small, self.T, np.sin(wT) / safe)
        cos_w = np.where(small, 0.0, 2.0 * np.sin(wT / 2.0) ** 2 / safe)  # (1-cos wT)/w, stable
        return np.sin(wT), np.cos(wT), sin_w, cos_w, small, safe

    def f(self, x: np.ndarray) -> np.ndarray:
        """Noise-free transition :math:`F(x)` of ``(N, 5)`` states."""
        x = np.asarray(x, dtype=float)
        px, vx, py, vy, w = (x[..., i] for i in range(5))
        s, c, a, b, _, _ = self._turn_terms(w)
        out = np.empty_like(x)
        out[..., 0] = px + a * vx - b * vy
        out[..., 1] = c * vx - s * vy
        out[..., 2] = b * vx + py + a * vy
        out[..., 3] = s * vx + c * vy
        out[..., 4] = w
        return out

    def path(self, x: np.ndarray, steps: int) -> np.ndarray:
        """``(steps + 1, 5)``: the state ``x`` (``(5,)``) and ``steps`` noise-free transitions
        :meth:`f`, bit for bit.  The turn rate, and with it every coefficient of :math:`F`,
        stays fixed along the path, so the coefficients are computed once and the recursion
        runs on Python floats (the same IEEE operations in the same order as :meth:`f`)."""
        x = np.asarray(x, dtype=float)
        s, c, a, b = (float(t) for t in self._turn_terms(x[4])[:4])
        px, vx, py, vy, w = (float(v) for v in x)
        rows = [(px, vx, py, vy, w)]
        for _ in range(steps):
            px, vx, py, vy = px + a * vx - b * vy, c * vx - s * vy, b * vx + py + a * vy, s * vx + c * vy
            rows.append((px, vx, py, vy, w))
        return np.array(rows)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        r"""Jacobian :math:`\partial F / \partial x` at each state, ``(N, 5, 5)``.

        The :math:`\omega` column uses the derivatives of :math:`\sin(\omega T)/\omega` and
        :math:`(1-\cos\omega T)/\omega`; at :math:`\omega \to 0` their limits
        :math:`0` and :math:`T^2/2`.
        """
        x = np.atleast_2d(np.asarray(x, dtype=float))
        T = self.T
        vx, vy, w = x[:, 1], x[:, 3], x[:, 4]
        s, c, a, b, small, safe = self._turn_terms(w)
        # derivatives w.r.t. omega of a = sin(wT)/w and b = (1-cos wT)/w
        da = np.where(small, 0.0, (T * c - a) / safe)
        db = np.where(small, T**2 / 2, (T * s - b) / safe)
        J = np.zeros((x.shape[0], 5, 5))
        J[:, 0, 0] = 1.0
        J[:, 0, 1] = a
        J[:, 0, 3] = -b
        J[:, 0, 4] = da * vx - db * vy
        J[:, 1, 1] = c
        J[:, 1, 3] = -s
        J[:, 1, 4] = -T * s * vx - T * c * vy
        J[:, 2, 1] = b
        J[:, 2, 2] = 1.0
        J[:, 2, 3] = a
        J[:, 2, 4] = db * vx + da * vy
        J[:, 3, 1] = s
        J[:, 3, 3] = c
        J[:, 3, 4] = T * c * vx - T * s * vy
        J[:, 4, 4] = 1.0
        return J

    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
        """Draw :math:`x_k \\sim F(x_{k-1}) + G u` for each row of ``x``."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        u = rng.standard_normal((x.shape[0], self.G.shape[1]))
        return self.f(x) + u @ self.G.T

    def logpdf(self, x_next: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Log transition density (degenerate Gaussian, density on the support of ``G``)."""
        return gaussian_logpdf(np.atleast_2d(x_next) - self.f(np.atleast_2d(x)), self.Q)


@dataclass(frozen=True)
class ConstantVelocity:
    r"""Nearly-constant-velocity model on :math:`x = [p_x, v_x, p_y, v_y]^T`.

    .. math::

        x_k = \operatorname{blockdiag}(A, A)\, x_{k-1} + w, \quad
        A = \begin{bmatrix}1 & T\\ 0 & 1\end{bmatrix}, \quad
        w \sim \mathcal N\!\left(0, \sigma_a^2 \operatorname{blockdiag}(B, B)\right),
        \quad B = \begin{bmatrix} T^4/4 & T^3/2 \\ T^3/2 & T^2 \end{bmatrix}

    (the same discrete white-noise-acceleration form as the coordinated-turn model's
    position/velocity blocks).
    """

    T: float = 1.0
    sigma_accel: float = 5.0

    ndim: int = 4

    @cached_property
    def F(self) -> np.ndarray:
        A = np.array([[1.0, self.T], [0.0, 1.0]])
        return np.kron(np.eye(2), A)

    @cached_property
    def Q(self) -> np.ndarray:
        T = self.T
        B = np.array([[T**4 / 4, T**3 / 2], [T**3 / 2, T**2]])
        return self.sigma_accel**2 * np.kron(np.eye(2), B)

    def f(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, dtype=float) @ self.F.T

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        return np.broadcast_to(self.F, (x.shape[0], 4, 4)).copy()

    def sample(self, rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(np.asarray(x, dtype=float))
        L = np.linalg.cholesky(self.Q)
        return self.f(x) + rng.standard_normal(x.shape) @ L.T

    def logpdf(self, x_next: np.ndarray, x: np.ndarray) -> np.ndarray:
        return gaussian_logpdf(np.atleast_2d(x_next) - self.f(np.atleast_2d(x)), self.Q)
