r"""Posterior draws of the two-level tracker's object partition, for scoring (opt-in).

The tracker itself keeps one Gibbs sample of the object -> cluster partition per frame (the last
of ``sweeps`` sweeps, warm-started at last frame's clusters).  :class:`PosteriorGroupTracker` is
the same tracker with, at the frames it summarises, ``chains`` further Markov chains of the same
collapsed Gibbs kernel (:func:`tracker.bnp.groups.sample_partition`) on the same frame's
conditional: the same members' estimates, transitioned clusters and :math:`(\alpha_2, d)`.
Chain 0 starts at the tracker's warm start, chain 1 with every member at a table of its own,
chain 2 (if any) with all of them at one new table; each runs ``burn`` sweeps, then keeps the
partition after each of ``keep`` more.  The chains draw from a stream of their own
(``rng.spawn``, which leaves the tracker's generator where it was), so the tracker's estimates
and states are bit for bit those of :class:`~tracker.bnp.groups.GroupTracker`.

Every frame also records the posterior of the discount :math:`d` on the tracker's grid
(:func:`d_posterior`): the history likelihood the tracker holds times the priors, marginal over
:math:`\alpha_2`; it is conditional on the tracker's own sampled history of partitions.

The records go to :attr:`PosteriorGroupTracker.log` (a list, one :class:`FrameDraws` per frame),
read by the scorer (``benchmarks/pitman_yor.py``); the summaries (similarity matrix, point
estimate, split R-hat) are :mod:`sinks.partitions`'.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bnptrack.tracker.bnp.groups import Block, GroupState, GroupTracker, sample_partition
from bnptrack.tracker.types import Estimate, Frame

__all__ = ["FrameDraws", "PosteriorGroupTracker", "d_posterior", "grid_interval"]


@dataclass(frozen=True)
class FrameDraws:
    """One frame's record: the partition's members (track labels), the kept draws
    ``(chains, keep, L)`` (table indices; ``None`` at frames not summarised) and the posterior
    of d on ``d_grid``."""

    frame: int
    labels: tuple[str, ...]
    draws: np.ndarray | None
    d_grid: np.ndarray
    d_prob: np.ndarray


def d_posterior(tracker: GroupTracker, state: GroupState) -> tuple[np.ndarray, np.ndarray]:
    """The posterior of d on the tracker's grid at ``state``: its (alpha_2, d) log-likelihood plus
    the priors the tracker uses, normalised, summed over alpha_2.  A tracker that does not infer
    d has the one-point grid of its fixed d."""
    log_post = state.hyper2_loglik if state.hyper2_loglik.size else np.zeros((tracker.hyper.alpha_grid.size, tracker.hyper.d_grid.size))
    log_post = log_post + tracker.hyper.alpha_log_prior[:, None]
    if tracker.hyper.d_log_prior is not None:
        log_post = log_post + tracker.hyper.d_log_prior[None, :]
    p = np.exp(log_post - log_post.max())
    p = p.sum(axis=0)
    return tracker.hyper.d_grid.copy(), p / p.sum()


def grid_interval(grid: np.ndarray, prob: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """(mean, lower, upper) of a distribution on a grid: the equal-tailed interval's ends are the
    grid points where the cumulative probability first reaches ``(1 - level) / 2`` and ``(1 + level) / 2``."""
    cdf = np.cumsum(prob)
    q = (1.0 - level) / 2.0
    lo = grid[min(int(np.searchsorted(cdf, q)), grid.size - 1)]
    hi = grid[min(int(np.searchsorted(cdf, 1.0 - q)), grid.size - 1)]
    return float(np.dot(grid, prob)), float(lo), float(hi)


@dataclass(frozen=True)
class PosteriorGroupTracker(GroupTracker):
    """:class:`GroupTracker` that also records posterior draws of its object partition (module docstring)."""

    chains: int = 2
    burn: int = 20
    keep: int = 20
    first_frame: int = 1
    every: int = 1
    """Frames summarised: ``first_frame``, ``first_frame + every``, ..."""
    log: list = field(default_factory=list, compare=False, repr=False)
    _scratch: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.chains < 1 or self.keep < 1 or self.burn < 0 or self.every < 1:
            raise ValueError("PosteriorGroupTracker: need chains >= 1, keep >= 1, burn >= 0, every >= 1")

    def summarises(self, frame: int) -> bool:
        return frame >= self.first_frame and (frame - self.first_frame) % self.every == 0

    def step(self, state: GroupState, frame: Frame, rng: np.random.Generator) -> tuple[GroupState, Estimate]:
        self._scratch.clear()
        self._scratch["frame"] = frame.frame
        new_state, est = super().step(state, frame, rng)
        members = np.flatnonzero(new_state.cluster >= 0)
        labels = tuple(new_state.labels[i] for i in members)
        grid, prob = d_posterior(self, new_state)
        self.log.append(FrameDraws(frame.frame, labels, self._scratch.get("draws"), grid, prob))
        return new_state, est

    def _partition(self, rng, state: GroupState, blocks: list[Block], init_ids):
        z, shares = super()._partition(rng, state, blocks, init_ids)
        frame = self._scratch.get("frame")
        if z.size and frame is not None and self.summarises(frame):
            slot = {int(g): i for i, g in enumerate(state.group_ids.tolist())}
            init = np.array([slot.get(int(g), -1) for g in init_ids], dtype=np.int64)
            self._scratch["draws"] = self.draw_chains(rng.spawn(1)[0], state, blocks, init)
        return z, shares

    def draw_chains(self, rng: np.random.Generator, state: GroupState, blocks: list[Block],
                    init: np.ndarray) -> np.ndarray:
        """``(chains, keep, L)`` partitions: each chain ``burn`` sweeps from its start, then one kept per sweep."""
        L, G = init.size, state.group_ids.size
        starts = [init, np.full(L, -1, dtype=np.int64), np.full(L, G, dtype=np.int64)]
        out = np.empty((self.chains, self.keep, L), dtype=np.int64)
        for c in range(self.chains):
            z = starts[c] if c < len(starts) else rng.integers(G, G + L, size=L)
            if self.burn:
                z = self._sweeps(rng, state, blocks, z, self.burn)
            for s in range(self.keep):
                z = self._sweeps(rng, state, blocks, z, 1)
                out[c, s] = z
        return out

    def _sweeps(self, rng, state: GroupState, blocks: list[Block], z: np.ndarray, n: int) -> np.ndarray:
        z, _ = sample_partition(rng, blocks, state.group_count, state.alpha2, state.d2, z, n,
                                flat_share=self.config.share_prior == "flat",
                                occupied=self.config.urn_reading == "occupied")
        return z
