r"""DDP-EMM and DPY-STP: streaming Gibbs trackers that keep their Markov prior across frames.

``BnpTracker.step(state, frame, rng) -> (state, estimate)`` is a pure function of its inputs.
The state (:class:`BnpState`) is plain data: one row per cluster (object) with its label,
Gaussian state, existence probability and popularity, plus the hyperparameters.  One frame:

1. **Transition** (Algorithm 1, step 2): each cluster survives with :math:`P_S`
   (:math:`q_l = P_S r_l`), its parameter moves through the transition kernel
   :math:`\varphi` = the coordinated-turn model (UKF or EKF prediction), and its popularity
   carries forward with decay :math:`\rho` (``popularity_decay``).
2. **Association** (Algorithm 2, eq. (13)-(14)): collapsed Gibbs sweeps over measurement
   assignments with the dependent Polya-urn weights of cases D1-D3 / P1-P3
   (:mod:`tracker.bnp.gibbs`), the EKF/UKF predictive likelihood, :math:`P_D`, and Poisson clutter.
3. **Update**: each cluster's existence is its Gibbs-averaged detection probability plus the
   missed-detection term; its Gaussian is moment-matched over "missed" and "detected by the
   measurement it takes in the most probable one-to-one assignment" (JPDA*; or over every
   measurement, ``state_update = "mixture"``).  Each measurement that opened a new cluster in
   some sweeps starts a cluster from the base distribution :math:`H` conditioned on it
   (case D3/P3), with existence equal to that probability.
4. **Hyperparameters**: :math:`(\alpha, d)` on a grid: the Gamma priors times each frame's
   Poisson-urn likelihood of its last Gibbs sample, accumulated with forgetting; the next frame
   uses the posterior mean (or one draw, ``hyper_estimate = "sample"``).

``docs/trackers.md`` maps every term of the paper to this code and lists the choices made
where the paper is silent.

Modules: :mod:`~tracker.bnp.config` (settings, presets), :mod:`~tracker.bnp.filter` (the
tracker and its step), :mod:`~tracker.bnp.gibbs` (the collapsed Gibbs sampler),
:mod:`~tracker.bnp.urn` (Polya urn, hyperparameter grid), :mod:`~tracker.bnp.base_measure`
(the DP base measure :math:`H`: where new objects come from), :mod:`~tracker.bnp.clusters`
(cluster arrays, duplicate merging), :mod:`~tracker.bnp.assignment` (the JPDA* assignment
solver) and :mod:`~tracker.bnp.groups` (the two-level trackers).
"""

from bnptrack.tracker.bnp.config import TRACKER_PRESETS, BnpConfig
from bnptrack.tracker.bnp.birth_tracker import make_tracker  # the learned-H_k dispatch
from bnptrack.tracker.bnp.filter import BnpState, BnpTracker

__all__ = ["BnpConfig", "BnpState", "BnpTracker", "TRACKER_PRESETS", "make_tracker"]
