r"""The object partition's :math:`(\alpha_2, d)` likelihood from the objects' arrivals (two-level tracker).

Eq. (condd) of the paper: given the previous frame, the object partition of frame :math:`k` is
marginally :math:`\mathrm{PYP}(d, \alpha, H_1)`.  Its exchangeable partition probability, built
one object at a time (the Pitman-Yor Chinese restaurant, the :math:`d`-form of cases P1-P3), is

.. math::
    \Pr(\ell \to \text{table } c) = \frac{n_c - d}{\alpha + n}, \qquad
    \Pr(\ell \to \text{new table}) = \frac{\alpha + d K}{\alpha + n}

with :math:`n_c` the objects already at table :math:`c`, :math:`n` all objects seated before
:math:`\ell` and :math:`K` the occupied tables.  :func:`arrivals_loglik_grid` counts each object
**once**, at the frame it enters the partition (its existence first reaches
``member_existence``), seated after the objects already there.  Over a stream the product is the
partition's Pitman-Yor EPPF :math:`\prod_{k<K}(\alpha + k d)\,/\,(\alpha+1)^{\overline{n-1}}
\prod_c (1-d)^{\overline{n_c-1}}` (for objects that stay).  Re-counting every frame's re-seating
(``hyper_likelihood = "reseat"``, :func:`tracker.bnp.urn.frame_loglik_grid`) multiplies in a
factor :math:`(v^*_c + i - d)` for each of ~50 re-seats of every object, each falling with
:math:`d`, and drives :math:`d` to 0 whatever the group sizes (issue 14).
"""

from __future__ import annotations

import numpy as np


def arrivals_loglik_grid(alpha: np.ndarray, d: np.ndarray, z: np.ndarray, arrived: np.ndarray) -> np.ndarray:
    """Log Pitman-Yor predictive of this frame's arrivals on the ``(alpha, d)`` grid (broadcast shapes).

    ``z`` (L,): every member's table this frame; ``arrived`` (L,) bool: members that entered the
    partition this frame (seated in index order, after the others)."""
    alpha = np.asarray(alpha, dtype=float)
    d = np.asarray(d, dtype=float)
    out = np.zeros(np.broadcast_shapes(alpha.shape, d.shape))
    tables, counts = np.unique(z[~arrived], return_counts=True)
    seated = dict(zip(tables.tolist(), counts.tolist()))
    n = int(counts.sum())
    for t in z[arrived].tolist():
        c = seated.get(t, 0)
        out = out + np.log(c - d if c > 0 else alpha + d * len(seated)) - np.log(alpha + n)
        seated[t] = c + 1
        n += 1
    return out
