"""The two-level tracker's state (:class:`GroupState`): flat plain data, the object level's
fields plus the cluster level, so that :mod:`tracker.state` snapshots it exactly."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from bnptrack.tracker.bnp.birth_tracker import LearnedBirthState
from bnptrack.tracker.bnp.filter import BnpState
from bnptrack.tracker.calibration import CalibrationFields

__all__ = ["GroupState", "previous_rows"]


@dataclass(frozen=True)
class GroupState(CalibrationFields):
    """The inner :class:`BnpState`'s fields (one row per object) plus the cluster level.

    ``cluster`` (N,) is each object's cluster id (-1: not in the partition); ``group_ids``
    (G,), ``group_mean`` (G, 2), ``group_cov`` (G, 2, 2), ``group_count`` (G,) = v* hold the
    clusters that transition to the next frame (posterior of theta given all members).
    """

    frame: int = -1
    stamp_ns: int = 0
    labels: tuple[str, ...] = ()
    mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 5, 5)))
    existence: np.ndarray = field(default_factory=lambda: np.zeros(0))
    popularity: np.ndarray = field(default_factory=lambda: np.zeros(0))
    alpha: float = 1.0
    d: float = 0.0
    hyper_loglik: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    cluster: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    group_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    group_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    group_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    group_count: np.ndarray = field(default_factory=lambda: np.zeros(0))
    group_pos_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    group_pos_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    alpha2: float = 0.5
    d2: float = 0.0
    hyper2_loglik: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    next_group: int = 0
    counted: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(N,) the cluster id in which each object is counted in the partition's history (-1: never)."""
    hist_total: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(G,) objects ever counted in each of ``group_ids`` (the live clusters)."""
    dead_k: int = 0
    """Clusters of the history that have died (no longer transition)."""
    dead_n: int = 0
    """Objects counted in them."""
    dead_factor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(D,) their sum_j log (1-d)^(n_j - 1) (rising factorial) on the tracker's d grid."""
    birth_pos: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_pos)
    """The object level's recorded births (:class:`~tracker.bnp.birth_tracker.LearnedBirthState`;
    empty unless ``objects.learn_births`` / ``objects.learn_birth_velocity``), and below."""
    birth_cov: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_cov)
    birth_weight: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_weight)
    birth_loglik: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_loglik)
    birth_vel_stats: np.ndarray = field(default_factory=lambda: LearnedBirthState().birth_vel_stats)
    own_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    """(N, 5) each object's own estimate, without the sharing (``membership = "own"``; empty
    otherwise, and in snapshots that lack it: then every object starts from its state)."""
    own_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 5, 5)))
    """(N, 5, 5) its covariance."""
    together: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(N,) consecutive scans each object has sat in its cluster with another object (``share_after``;
    empty when off)."""
    id_frames: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """The crossing check's ring (:class:`tracker.bnp.identity.Ring`; empty when off): its scans,
    and below its stamps, own posteriors, measurement information, last exchanges and clusters."""
    id_stamps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    id_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 5)))
    id_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 5, 5)))
    id_lam: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 5, 5)))
    id_eta: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 5)))
    id_swapped: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    id_cluster: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))

    def inner(self) -> BnpState:
        return BnpState(**{n: getattr(self, n) for n in _INNER_FIELDS})

    def inner_learned(self) -> LearnedBirthState:
        """The object level's state with its recorded births (``objects.learn_births``)."""
        return LearnedBirthState(**{n: getattr(self, n) for n in _LEARNED_FIELDS})


#: :class:`BnpState`'s fields in order (each a field of :class:`GroupState` of the same name).
_INNER_FIELDS = tuple(f.name for f in fields(BnpState))
#: :class:`LearnedBirthState`'s fields in order: the above, then the ``birth_*`` memory.
_LEARNED_FIELDS = tuple(f.name for f in fields(LearnedBirthState))
_BIRTH_FIELDS = _LEARNED_FIELDS[len(_INNER_FIELDS):]


def previous_rows(state: GroupState, labels: tuple[str, ...]) -> np.ndarray:
    """Each of ``labels``' row in ``state`` (-1: not there; a label twice in ``state``: its last row)."""
    row = {lab: i for i, lab in enumerate(state.labels)}
    return np.array([row.get(lab, -1) for lab in labels], dtype=np.int64)


def _rows_of(values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``values[rows]`` as int64 with -1 where ``rows`` is -1 (an object not in the last state)."""
    out = np.full(rows.size, -1, dtype=np.int64)
    have = rows >= 0
    out[have] = values[rows[have]]
    return out
