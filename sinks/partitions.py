"""Agreement of two partitions of the same items: the adjusted Rand index (the groups a tracker
infers against ``Scenario.groups``); and summaries of sampled partitions: the posterior
similarity matrix, the point estimate that minimises Binder's loss, split R-hat."""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

__all__ = ["adjusted_rand_index", "similarity_matrix", "binder_loss", "binder_point", "split_rhat", "n_blocks"]


def adjusted_rand_index(a: Sequence[Hashable], b: Sequence[Hashable]) -> float:
    r"""Adjusted Rand index of two partitions of the same items (Hubert & Arabie 1985).

    ``a[i]``, ``b[i]``: the blocks of item ``i``.  With the contingency table :math:`n_{ij}`,
    row sums :math:`a_i`, column sums :math:`b_j` and :math:`\binom{\cdot}{2}` pair counts,

    .. math::
        \mathrm{ARI} = \frac{\sum_{ij} \binom{n_{ij}}{2} - E}{\tfrac12 (\sum_i \binom{a_i}{2}
        + \sum_j \binom{b_j}{2}) - E}, \qquad
        E = \sum_i \binom{a_i}{2} \sum_j \binom{b_j}{2} \Big/ \binom{n}{2} .

    1 for identical partitions, about 0 for chance agreement.  When the denominator is 0 (fewer
    than 2 items, or both partitions all singletons / both one block) the partitions are equal
    and the index is 1.
    """
    if len(a) != len(b):
        raise ValueError(f"the partitions cover {len(a)} and {len(b)} items")
    _, ia = np.unique(np.asarray([str(x) for x in a], dtype=object), return_inverse=True)
    _, ib = np.unique(np.asarray([str(x) for x in b], dtype=object), return_inverse=True)
    n = len(a)
    table = np.zeros((ia.max(initial=-1) + 1, ib.max(initial=-1) + 1))
    np.add.at(table, (ia, ib), 1.0)

    def pairs(x: np.ndarray) -> float:
        return float(np.sum(x * (x - 1.0) / 2.0))

    index, sa, sb = pairs(table), pairs(table.sum(axis=1)), pairs(table.sum(axis=0))
    expected = sa * sb / (n * (n - 1) / 2.0) if n >= 2 else 0.0
    top = 0.5 * (sa + sb)
    if top == expected:
        return 1.0
    return float((index - expected) / (top - expected))


def similarity_matrix(draws: np.ndarray) -> np.ndarray:
    """``(L, L)`` posterior similarity: the fraction of the partitions ``draws`` (``(M, L)``,
    block labels per item) in which items i and j share a block."""
    draws = np.asarray(draws)
    if draws.ndim != 2 or draws.shape[0] == 0:
        raise ValueError(f"similarity_matrix: need draws of shape (M >= 1, L), got {draws.shape}")
    out = np.zeros((draws.shape[1], draws.shape[1]))
    for z in draws:
        out += z[:, None] == z[None, :]
    return out / draws.shape[0]


def binder_loss(z: np.ndarray, psm: np.ndarray) -> float:
    r"""Posterior expected Binder loss (unit costs) of the partition ``z`` given the similarity
    matrix ``psm``: :math:`\sum_{i<j} [z_i = z_j](1 - p_{ij}) + [z_i \ne z_j] p_{ij}`."""
    same = np.asarray(z)[:, None] == np.asarray(z)[None, :]
    iu = np.triu_indices(psm.shape[0], 1)
    return float(np.sum(np.where(same, 1.0 - psm, psm)[iu]))


def binder_point(psm: np.ndarray, candidates: np.ndarray, max_passes: int = 50) -> np.ndarray:
    """The partition (labels ``0..K-1``) that minimises the expected Binder loss: the best of
    ``candidates`` (``(M, L)``, e.g. the draws), then single-item moves (to another block or a
    new one) while one lowers the loss (a greedy search in the manner of SALSO's sweeps)."""
    losses = [binder_loss(c, psm) for c in candidates]
    z = _relabel(np.asarray(candidates)[int(np.argmin(losses))])
    M = 1.0 - 2.0 * psm  # joining j's block costs 1 - 2 p_ij
    np.fill_diagonal(M, 0.0)
    for _ in range(max_passes):
        moved = False
        for i in range(z.size):
            cost = np.bincount(z, weights=M[i], minlength=int(z.max()) + 1)
            options = np.append(cost, 0.0)  # the last option: a new block of its own
            k = int(np.argmin(options))
            if options[k] < cost[z[i]] - 1e-12:
                z[i] = k
                z = _relabel(z)
                moved = True
        if not moved:
            break
    return z


def _relabel(z: np.ndarray) -> np.ndarray:
    """Block labels ``0..K-1`` in order of first appearance."""
    _, first, inv = np.unique(z, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    return order[inv].astype(np.int64)


def n_blocks(draws: np.ndarray) -> np.ndarray:
    """The number of blocks of each partition of ``draws`` (``(..., L)``)."""
    draws = np.asarray(draws)
    flat = draws.reshape(-1, draws.shape[-1])
    return np.array([np.unique(z).size for z in flat]).reshape(draws.shape[:-1])


def split_rhat(x: np.ndarray) -> float:
    r"""Split R-hat (Gelman et al., BDA3 sec. 11.4) of the scalar draws ``x`` (``(chains, n)``):
    each chain cut into halves; :math:`\sqrt{\hat V / W}` with W the mean within-half variance and
    :math:`\hat V = \frac{n' - 1}{n'} W + B / n'`.  1 when every half is constant at one value;
    inf when the halves are constant at different values."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] < 4:
        raise ValueError(f"split_rhat: need (chains, n >= 4) draws, got {x.shape}")
    h = x.shape[1] // 2
    halves = np.concatenate([x[:, :h], x[:, x.shape[1] - h:]])
    means, W = halves.mean(axis=1), halves.var(axis=1, ddof=1).mean()
    B = h * means.var(ddof=1)
    if W == 0.0:
        return 1.0 if B == 0.0 else float("inf")
    return float(np.sqrt(((h - 1) / h * W + B / h) / W))
