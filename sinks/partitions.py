"""Agreement of two partitions of the same items: the adjusted Rand index (the groups a tracker
infers against ``Scenario.groups``)."""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

__all__ = ["adjusted_rand_index"]


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
