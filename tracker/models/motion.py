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
    """

    T: float = 1.0
    sigma_accel: float = 5.0
    sigma_turn: float = np.pi / 180.0

    ndim: int = 5

    @cached_property
    def G(self) -> np.ndarray:
        T, s = self.T, self.sigma_accel
        g = np.zeros((5, 3))
        g[0:2, 0] = s * np.array([T**2 / 2, T])
        g[2:4, 1] = s * np.array([T**2 / 2, T])
        g[4, 2] = T * self.sigma_turn
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
        u = rng.standard_normal((x.shape[0], 3))
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
