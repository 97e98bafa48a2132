"""The arguments of the object -> cluster Gibbs kernels (:mod:`tracker.bnp.group_sample`,
:mod:`tracker.bnp.group_scan`, :mod:`tracker.bnp.group_partition`, :mod:`tracker.bnp.group_grid`),
bundled by what they are: typed NamedTuples of arrays and scalars, which numba passes to a
compiled kernel as one argument (a struct of the same fields; no copy of any array).  A bundle's
arrays are read and written in place; a bundle is rebuilt only when an array of it is replaced
(:class:`Records`, grown).

:class:`BlockArrays`, :class:`Sweeps` and :class:`Urn` are built at the Python edge, once a frame
(:func:`tracker.bnp.group_sample.sample_partition`); the gated kernel builds the others once per
call, around its sweeps.  Each helper kernel receives the bundles whose fields it mostly reads: a
field passed and not read still costs a first run compile time (numba flattens a NamedTuple
argument into its fields and counts the references to each array in it at every call; bundles
of every table and object array, passed whole to each helper, cost the group kernels about 20 %
more compile CPU).  The sums that seat and unseat an object (``_move``, ``_refresh``) keep their
arrays one by one: ``_setup`` and the reference scan call them too."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["BlockArrays", "Candidates", "Gate", "Grid", "Members", "Records", "Sums", "Sweeps",
           "Tables", "Urn"]


class BlockArrays(NamedTuple):
    """One part of theta as :func:`tracker.bnp.group_sample._sample_setup` reads it: members
    ``v`` (L, 2) with covariances ``R`` (L, 2, 2); the transitioned tables' priors ``prior_cov``
    (G, 2, 2), ``prior_mean`` (G, 2); H_2's part in information form ``h_lam`` (2, 2), ``h_eta`` (2,)."""

    v: np.ndarray
    R: np.ndarray
    prior_cov: np.ndarray
    prior_mean: np.ndarray
    h_lam: np.ndarray
    h_eta: np.ndarray


class Sweeps(NamedTuple):
    """The collapsed Gibbs's inputs: members ``v`` (P, L, 2) ~ N(theta, ``R`` (P, L, 2, 2)) per
    block; the tables' priors in information form ``lam0`` (P, T, 2, 2), ``eta0`` (P, T, 2); the
    shared theta's prior ``h_lam`` (2, 2), ``h_eta`` (2,) (the records' part 0); the tables' seated
    counts ``v_star`` (T,); the sample ``z`` (L,), drawn in place; the uniforms ``u`` (S, L)."""

    v: np.ndarray
    R: np.ndarray
    lam0: np.ndarray
    eta0: np.ndarray
    h_lam: np.ndarray
    h_eta: np.ndarray
    v_star: np.ndarray
    z: np.ndarray
    u: np.ndarray


class Urn(NamedTuple):
    """The urn's parameters: concentration ``alpha``, discount ``d``, and its reading
    (``occupied``: :func:`tracker.bnp.group_sample.urn_log_weights`)."""

    alpha: float
    d: float
    occupied: bool


class Members(NamedTuple):
    """The objects being seated: ``v`` (P, L, 2), ``R`` (P, L, 2, 2) as :class:`Sweeps`'; the
    gate's per-object terms ``c`` (L,) (sum over blocks of -log det(R)/2 - log 2 pi) and ``rho``
    (L,) (the largest eigenvalue of the indexed block's R)."""

    v: np.ndarray
    R: np.ndarray
    c: np.ndarray
    rho: np.ndarray


class Sums(NamedTuple):
    """The tables' information sums: members seated ``n`` (T,); ``lam`` (P, T, 2, 2), ``eta``
    (P, T, 2) over the priors ``lam0``, ``eta0`` (an empty table's sums are reset to them)."""

    n: np.ndarray
    lam: np.ndarray
    eta: np.ndarray
    lam0: np.ndarray
    eta0: np.ndarray


class Tables(NamedTuple):
    """What a move reads of each table: theta's posterior ``mu`` (P, T, 2), ``cov`` (P, T, 2, 2)
    and ``lm`` (T,), the largest eigenvalue of the indexed block's ``cov``; the log urn weight
    ``urn`` (T,); ``live`` (T,): seated or transitioned."""

    mu: np.ndarray
    cov: np.ndarray
    lm: np.ndarray
    urn: np.ndarray
    live: np.ndarray


class Gate(NamedTuple):
    """The gate's constants: the indexed block ``q``, whether to gate (``on``), ``U`` an upper
    bound of every urn weight's log, and ``log2pi`` = log(2 pi)."""

    q: int
    on: bool
    U: float
    log2pi: float


class Grid(NamedTuple):
    """The uniform grid over the tables' indexed theta means (:mod:`tracker.bnp.group_grid`):
    ``geo`` = (x0, y0, cell size, nx, ny); ``cap``, the largest covariance eigenvalue a table in a
    cell may have; per cell the first table ``head``; per table its cell ``cell_of`` and its
    neighbours in the cell's list ``nxt``, ``prv``; the wide tables ``wide[:n_wide[0]]`` and each
    one's place ``wide_pos``."""

    geo: np.ndarray
    cap: float
    head: np.ndarray
    cell_of: np.ndarray
    nxt: np.ndarray
    prv: np.ndarray
    wide: np.ndarray
    wide_pos: np.ndarray
    n_wide: np.ndarray


class Candidates(NamedTuple):
    """One move's options: the tables ``cand`` gathered, ``mark`` (T,) the move's stamp of each
    table gathered, ``logw`` (T,) their log weights and ``w`` (T,) their normalised weights."""

    cand: np.ndarray
    mark: np.ndarray
    logw: np.ndarray
    w: np.ndarray


class Records(NamedTuple):
    """The last sweep's options kept: ``count[0]`` of them, object ``obj``, weight ``w``, part 0's
    theta ``mu``, ``cov`` given the table's other members (arrays grown by doubling)."""

    count: np.ndarray
    obj: np.ndarray
    w: np.ndarray
    mu: np.ndarray
    cov: np.ndarray
