"""The GLMB filtering density as plain arrays: a track table and the hypotheses over it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bnptrack.tracker.calibration import CalibrationFields
from bnptrack.tracker.models.measurement import DEFAULT_KIND
from bnptrack.tracker.types import STATE_DIM


def _empty_hyps() -> np.ndarray:
    return np.zeros((1, 0), dtype=np.int64)


@dataclass(frozen=True)
class GlmbState(CalibrationFields):
    """The GLMB density after ``frame`` (snapshot with :mod:`tracker.state`).

    Track table: ``labels`` (T,), ``mean`` (T, 5), ``cov`` (T, 5, 5).  Hypotheses:
    ``hyp_tracks`` (H, maxN) int64 sorted table rows padded with ``-1``; ``log_w`` (H,)
    normalised log weights.  The initial state is the single empty hypothesis of weight 1.
    ``birth_*``: the last frame's measurements and their assignment probabilities, from
    which the next frame's adaptive births are built.  The published existence's calibration
    state: the inherited ``cal_*`` fields.
    """

    frame: int = -1
    stamp_ns: int = 0
    labels: tuple[str, ...] = ()
    mean: np.ndarray = field(default_factory=lambda: np.zeros((0, STATE_DIM)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, STATE_DIM, STATE_DIM)))
    hyp_tracks: np.ndarray = field(default_factory=_empty_hyps)
    log_w: np.ndarray = field(default_factory=lambda: np.zeros(1))
    birth_frame: int = -1
    """Frame of ``birth_z`` (the last processed frame; ``-1``: none)."""
    birth_kind: str = DEFAULT_KIND
    birth_sensor: str = ""
    birth_pose: tuple[float, ...] = ()
    """The last frame's sensor, pose (``()``: none) and ``R`` (``(0, 0)``: none)."""
    birth_R: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    birth_z: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """The last frame's measurements ``(M, d)``: the adaptive births of the next frame."""
    birth_r_u: np.ndarray = field(default_factory=lambda: np.zeros(0))
    r"""``(M,)`` :math:`r_U(z)`: posterior probability that ``birth_z[m]`` was assigned to a
    track (sum of the weights of the hypotheses that use it)."""
    est_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """Table rows reported by the last estimate (the ``marginal-labels`` estimator follows
    their association histories)."""

    @property
    def n_tracks(self) -> int:
        return len(self.labels)

    @property
    def n_hypotheses(self) -> int:
        return int(self.log_w.shape[0])

    def cardinality(self) -> np.ndarray:
        """Cardinality distribution ``(maxN + 1,)``: :math:`\\rho(n) = \\sum_{|I|=n} w^{(I)}`."""
        n = np.sum(self.hyp_tracks >= 0, axis=1)
        return np.bincount(n, weights=np.exp(self.log_w), minlength=self.hyp_tracks.shape[1] + 1)
