r"""GLMB baseline: joint prediction-update with Gibbs-sampled truncation.

Vo, Vo & Hoang, "An Efficient Implementation of the Generalized Labeled Multi-Bernoulli
Filter", IEEE TSP 65(8), 2017 (arXiv:1606.08350), Gaussian (UKF or EKF) implementation with a
labeled multi-Bernoulli birth, as in the authors' ``jointglmb`` UKF demo.  ``docs/glmb.md``
lists the equations, the caps and the measured accuracy.

The GLMB filtering density :math:`\pi(X) = \Delta(X) \sum_{I, \xi} w^{(I,\xi)}
\delta_I[\mathcal L(X)] [p^{(\xi)}]^X` is held as plain arrays (:class:`GlmbState`):

* a **track table**: one row per (label, Gaussian) -- ``labels`` (T,), ``mean`` (T, 5),
  ``cov`` (T, 5, 5); a row is one label's density :math:`p^{(\xi)}(\cdot, \ell)` under one
  association history;
* **hypotheses**: ``hyp_tracks`` (H, maxN) sorted track-table rows padded with ``-1`` and
  normalised ``log_w`` (H,).

One frame (:meth:`GlmbTracker.step`):

1. predict every table row (the candidate survivors) and append the birth components;
2. per candidate row, the log of the :math:`\eta` costs over the options *dies / missed /
   detected by* :math:`z_j` (shared by all hypotheses; chi-square gating);
3. per hypothesis, Gibbs chains over the assignment vector :math:`\gamma` of its survivors
   plus the births, started at the optimal assignment, with a number of samples
   proportional to :math:`\sqrt{w}` (the authors' allocation);
4. distinct samples become child hypotheses (weight = parent weight x product of
   :math:`\eta`), children with identical track sets are merged, pruned and capped;
5. the new track table holds the (row, measurement) pairs used by the kept children, with
   the Gaussian update computed once per pair.

The Gibbs sweeps and the linear assignments run in numba-compiled kernels on plain arrays
(``BNPTRACK_NO_JIT=1`` runs the same functions interpreted, :mod:`tracker.numerics`); the
sweeps consume uniforms drawn up front from ``rng`` in the order of the vectorised reference
:func:`gibbs_chains_numpy`, so the output is identical to it.

Everything random comes from the caller's ``rng``; ``step`` is a pure function.

Modules: :mod:`~tracker.glmb.config` (settings, model protocol), :mod:`~tracker.glmb.state`
(the density), :mod:`~tracker.glmb.hypotheses` (candidates, :math:`\eta`, children),
:mod:`~tracker.glmb.gibbs` (the sampler), :mod:`~tracker.glmb.assignment` (the batched
linear assignment solver), :mod:`~tracker.glmb.starts`, :mod:`~tracker.glmb.children` and
:mod:`~tracker.glmb.row_sort` (the compiled starts and children of a frame),
:mod:`~tracker.glmb.births`, :mod:`~tracker.glmb.estimate` (marginals, estimators) and
:mod:`~tracker.glmb.filter` (the tracker and its step).
"""

from bnptrack.tracker.glmb.births import adaptive_birth_existence, measurement_state_prior
from bnptrack.tracker.glmb.config import GLMB_PRESETS, GlmbConfig, GlmbModel
from bnptrack.tracker.glmb.estimate import (continuity_rows, estimate_from_rows, map_cardinality_rows,
                                   marginal_label_rows, marginals)
from bnptrack.tracker.glmb.filter import GlmbTracker, make_glmb
from bnptrack.tracker.glmb.gibbs import (allocate_samples, gibbs_chains, gibbs_chains_numpy, split_chains, start_missed,
                                start_optimal)
from bnptrack.tracker.glmb.hypotheses import candidate_sets, eta_matrix
from bnptrack.tracker.glmb.state import GlmbState

__all__ = ["GlmbConfig", "GlmbState", "GlmbTracker", "GLMB_PRESETS", "make_glmb", "GlmbModel",
           "adaptive_birth_existence", "measurement_state_prior", "marginals",
           "map_cardinality_rows", "continuity_rows", "marginal_label_rows", "estimate_from_rows",
           "eta_matrix", "candidate_sets", "allocate_samples", "start_optimal", "start_missed",
           "gibbs_chains", "gibbs_chains_numpy", "split_chains"]
