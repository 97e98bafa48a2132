"""The scene: what a scenario is (its targets, their paths and births) and how it adapts a
parameter set (:meth:`Scenario.adapt_params`).  The tables live in :mod:`sources.scenarios`,
the generated families in :mod:`sources.scene_families`; both build :class:`Scenario`."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import msgspec
import numpy as np

from bnptrack.tracker.models.measurement import DEFAULT_KIND, KINDS
from bnptrack.tracker.models.motion import CoordinatedTurn
from bnptrack.tracker.models.params import BirthComponent, ModelParams
from bnptrack.tracker.types import STATE_DIM, Truth

__all__ = ["TargetSpec", "Scenario"]

#: Standard deviation of a birth region's Gaussian (x, vx, y, vy, turn rate).
_BIRTH_STD = (50.0, 50.0, 50.0, 50.0, float(np.deg2rad(6.0)))


@dataclass(frozen=True)
class TargetSpec:
    """One noiseless target: ``xstart`` is the state one scan before ``birth``.

    Present at scans ``birth..death`` inclusive; the state at ``birth`` is ``f(xstart)``.
    """

    id: str
    xstart: tuple[float, float, float, float, float]
    birth: int
    death: int

    def __post_init__(self) -> None:
        xs = tuple(float(v) for v in self.xstart)
        if len(xs) != STATE_DIM:
            raise ValueError(f"TargetSpec {self.id}: xstart needs {STATE_DIM} values")
        object.__setattr__(self, "xstart", xs)
        if not 1 <= self.birth <= self.death:
            raise ValueError(
                f"TargetSpec {self.id}: need 1 <= birth <= death, got {self.birth}..{self.death}"
            )


@dataclass(frozen=True)
class Scenario:
    """A named set of noiseless targets over ``K`` scans seen by one sensor ``kind``."""

    name: str
    description: str
    K: int = 100
    kind: str = DEFAULT_KIND
    """A measurement kind of the registry :data:`tracker.models.measurement.KINDS`."""
    targets: tuple[TargetSpec, ...] = ()
    default_snr_db: float | None = None
    default_range_clutter_rate: float | None = None
    default_birth_rate: float | None = None
    """Expected objects per scan appearing anywhere (``ModelParams.birth_rate``) when the
    parameters leave it unset: 0.01 for the fixed tables, whose birth regions cover every birth
    (a floor, so an object elsewhere is still found); ``None`` keeps the default (0.1)."""
    birth: tuple[tuple[float, tuple[float, ...]], ...] | None = None
    """Scenario-specific birth regions ``(r, mean)`` (std as in Vo's model): prior knowledge of
    where this scene's objects appear (``vo2017``/``dpy5``: Vo's four components), ``None`` to
    keep the parameter set's (which ship none: objects may appear anywhere), or ``()`` for none
    at all (the generated families: objects appear anywhere)."""
    crossings: tuple[tuple[str, str, int], ...] = ()
    """Crossing pairs ``(id_a, id_b, scan)``: the two targets are within 20 m at ``scan``
    (generated ``random`` family; see :func:`sinks.metrics.crossing_label_keeping`)."""
    groups: tuple[tuple[str, ...], ...] = ()
    """True motion groups (generated ``groups`` families): each tuple holds the ids of objects
    that share velocity and turn rate; objects in no tuple move alone (singletons)."""
    seed: int | None = None
    """Scene seed of a generated family (``None`` for the fixed tables)."""
    scene: tuple[str, ...] = ()
    """The ``scene.*`` overrides a generated scene was built with (without ``scene.``)."""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Scenario {self.name}: unknown measurement kind {self.kind!r} (known: {', '.join(KINDS)})")
        object.__setattr__(self, "targets", tuple(self.targets))
        ids = [t.id for t in self.targets]
        if len(set(ids)) != len(ids):
            raise ValueError(f"Scenario {self.name}: duplicate target ids {ids}")
        for t in self.targets:
            if t.death > self.K:
                raise ValueError(f"Scenario {self.name}: {t.id} dies after K={self.K}")
        object.__setattr__(self, "crossings", tuple(
            (str(a), str(b), int(k)) for a, b, k in self.crossings))
        object.__setattr__(self, "scene", tuple(self.scene))
        object.__setattr__(self, "groups", tuple(tuple(str(i) for i in g) for g in self.groups))
        for g in self.groups:
            if not set(g) <= set(ids):
                raise ValueError(f"Scenario {self.name}: group {g} names unknown targets")
        for a, b, _k in self.crossings:
            if a not in ids or b not in ids:
                raise ValueError(f"Scenario {self.name}: crossing ({a}, {b}) names unknown targets")

    # ------------------------------------------------------------------------------
    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(t.id for t in self.targets)

    @property
    def births(self) -> np.ndarray:
        return np.array([t.birth for t in self.targets], dtype=int)

    @property
    def deaths(self) -> np.ndarray:
        return np.array([t.death for t in self.targets], dtype=int)

    def presence(self) -> np.ndarray:
        """``(K, n)`` boolean: target ``j`` present at scan ``i + 1``."""
        k = np.arange(1, self.K + 1)[:, None]
        return (k >= self.births[None, :]) & (k <= self.deaths[None, :])

    def states(self, T: float = 1.0) -> np.ndarray:
        """``(K, n, 5)`` noiseless states; ``NaN`` where a target is absent (a fresh copy)."""
        return _states(self, float(T)).copy()

    def _compute_states(self, T: float) -> np.ndarray:
        n = len(self.targets)
        ct = CoordinatedTurn(T=float(T))
        x = np.array([t.xstart for t in self.targets], dtype=float).reshape(n, STATE_DIM)
        births = self.births
        out = np.full((self.K, n, STATE_DIM), np.nan)
        present = self.presence()
        for i in range(self.K):
            moving = births <= i + 1
            if moving.any():
                x[moving] = ct.f(x[moving])
            out[i, present[i]] = x[present[i]]
        out.flags.writeable = False
        return out

    def truth(self, T: float = 1.0) -> list[Truth]:
        """Ground truth for scans ``1..K`` (index ``i`` holds scan ``i + 1``)."""
        states = _states(self, float(T))  # cached, read-only; indexing below copies
        present = self.presence()
        ids = np.array(self.ids, dtype=object)
        return [
            Truth(tuple(ids[present[i]]), states[i, present[i]].reshape(-1, STATE_DIM))
            for i in range(self.K)
        ]

    def cardinality(self) -> np.ndarray:
        """``(K,)`` number of targets present at each scan."""
        return self.presence().sum(axis=1)

    def adapt_params(self, params: ModelParams) -> ModelParams:
        """Apply the scenario's defaults to ``params``.

        If the scenario has a ``default_snr_db`` (the ``snr`` scenario: -3 dB) and
        ``params.snr_db`` is unset, ``snr_db`` is set; likewise ``default_range_clutter_rate``
        (``snr``: 2 per scan) when ``params.range_clutter_rate`` is unset.  If it has its own birth regions
        (``proximity``: the path's entry point; ``snr``: the 11 entry points), they replace the
        parameter set's, so the GLMB's birth model and the BNP trackers' base distribution know
        where this scenario's objects appear, as Vo's components do for ``vo2017``.  An empty
        ``birth`` (the generated families) sets ``birth = []``: no birth regions at all.
        ``default_birth_rate`` sets ``birth_rate`` (objects appearing anywhere) when unset.
        """
        if self.default_snr_db is not None and params.snr_db is None:
            params = msgspec.structs.replace(params, snr_db=float(self.default_snr_db))
        if self.default_range_clutter_rate is not None and params.range_clutter_rate is None:
            params = msgspec.structs.replace(params, range_clutter_rate=float(self.default_range_clutter_rate))
        if self.default_birth_rate is not None and params.birth_rate is None:
            params = msgspec.structs.replace(params, birth_rate=float(self.default_birth_rate))
        if self.birth is not None:
            std = list(_BIRTH_STD)
            params = msgspec.structs.replace(
                params, birth=[BirthComponent(r=r, mean=list(m), std=std) for r, m in self.birth])
        return params


@functools.lru_cache(maxsize=64)
def _states(scenario: Scenario, T: float) -> np.ndarray:
    return scenario._compute_states(T)
