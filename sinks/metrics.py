r"""Multi-object tracking performance metrics: OSPA, OSPA(2), GOSPA and cardinality error (the
running scores of a run as frames arrive are :mod:`sinks.run_scorer`).  Label
keeping through crossings is :mod:`sinks.crossings`, the adjusted Rand index
:mod:`sinks.partitions`, the input checks :mod:`sinks.metric_checks`.  This module imports
neither rerun nor scipy at import (scipy comes with the first score), so a process can score
frames without paying for the recording's imports and vice versa.

All functions take plain numpy arrays (or anything :func:`numpy.asarray` accepts) and return
frozen dataclasses or floats. Inputs are validated once at the public functions; the private
``_*_unchecked`` helpers form the hot path used inside loops (e.g. :func:`ospa2_series`).

Conventions
-----------
* A *point set* with ``m`` elements in ``d`` dimensions is an ``(m, d)`` array. The empty set may
  be given as ``(0, d)``, ``(0, 0)`` or ``[]``; an empty set with no dimension is compatible with
  any ``d``.
* A *set of tracks* over a window of ``W`` scans is an ``(n_tracks, W, d)`` array holding ``NaN``
  at the scans where a track does not exist.
* The base distance on points is Euclidean, cut off at ``c``:
  :math:`d^{(c)}(x, y) = \min(c, \lVert x - y\rVert_2)`.

References
----------
* D. Schuhmacher, B.-T. Vo and B.-N. Vo, "A consistent metric for performance evaluation of
  multi-object filters", IEEE Trans. Signal Processing 56(8), 2008.
* M. Beard, B.-T. Vo and B.-N. Vo, "OSPA(2): Using the OSPA metric to evaluate multi-target
  tracking performance", ICCAIS 2017; and "A solution for large-scale multi-object tracking",
  IEEE Trans. Signal Processing 68, 2020.
* A. S. Rahmathullah, A. F. Garcia-Fernandez and L. Svensson, "Generalized optimal sub-pattern
  assignment metric", FUSION 2017.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import asdict, dataclass
from itertools import chain

import numpy as np
from numpy.typing import ArrayLike

from bnptrack.sinks.metric_checks import (LabelledScan, as_scans, check_alpha, check_labelled_run, check_order, check_points,
                                 check_positive, check_same_dim, check_tracks, optimal_assignment)

__all__ = ["GospaResult", "OspaResult", "cardinality_error", "gospa", "ospa", "ospa2", "ospa2_series",
           "track_distance", "OSPA_C", "OSPA_P", "OSPA2_WINDOW"]

# --------------------------------------------------------------------------- the runs' settings

#: OSPA cut-off (m) and order of the paper's experiments: ``bnptrack track``, the experiments
#: and the recordings all use these.
OSPA_C = 100.0
OSPA_P = 1.0
#: OSPA(2) sliding window in scans (and its inner order q = 1).
OSPA2_WINDOW = 10


# --------------------------------------------------------------------------- results


@dataclass(frozen=True, slots=True)
class OspaResult:
    r"""OSPA (or OSPA(2)) value and its decomposition.

    ``total ** p == localisation ** p + cardinality ** p`` (up to rounding); for ``p == 1``
    ``total == localisation + cardinality`` exactly.
    """

    total: float
    localisation: float
    cardinality: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True, slots=True)
class GospaResult:
    r"""GOSPA value, its decomposition and the number of missed / false objects.

    The parts are the three ``p``-th-power sums each raised to ``1/p`` (so they are distances,
    like ``total``): ``total ** p == localisation ** p + missed ** p + false ** p`` (up to
    rounding); for ``p == 1`` ``total == localisation + missed + false`` exactly.
    """

    total: float
    localisation: float
    missed: float
    false: float
    n_missed: int
    n_false: int

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)



# --------------------------------------------------------------------------- hot path


def _root(x: float, p: float) -> float:
    return float(x) if p == 1.0 else float(x) ** (1.0 / p)


def _cutoff_distances(X: np.ndarray, Y: np.ndarray, c: float) -> np.ndarray:
    """``(m, n)`` matrix of :math:`\\min(c, \\lVert x_i - y_j \\rVert)`."""
    if X.shape[0] == 0 or Y.shape[0] == 0:
        return np.empty((X.shape[0], Y.shape[0]))
    return np.minimum(_euclidean(X, Y), c)


def _euclidean(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``scipy.spatial.distance.cdist(X, Y)`` (Euclidean), the same doubles without importing
    ``scipy.spatial`` (0.1-0.4 s): like scipy, each pair's squared coordinate differences are
    summed in coordinate order from 0, then square-rooted (``tests/sinks/test_metrics_solvers.py``)."""
    X, Y = np.asarray(X, dtype=float), np.asarray(Y, dtype=float)
    acc = np.zeros((X.shape[0], Y.shape[0]))
    for k in range(X.shape[1]):
        diff = X[:, k, None] - Y[None, :, k]
        acc += diff * diff
    return np.sqrt(acc)


def _ospa_unchecked(D: np.ndarray, c: float, p: float) -> OspaResult:
    """OSPA from an ``(m, n)`` matrix of base distances already cut off at ``c``."""
    m, n = D.shape
    if m > n:
        D, m, n = D.T, n, m
    if n == 0:
        return OspaResult(0.0, 0.0, 0.0)
    if m == 0:
        return OspaResult(c, 0.0, c)
    cost = D**p
    rows, cols = optimal_assignment(cost)
    loc_term = math.fsum(cost[rows, cols]) / n  # correctly rounded, order-free
    card_term = c**p * (n - m) / n
    return OspaResult(_root(loc_term + card_term, p), _root(loc_term, p), _root(card_term, p))


def _gospa_unchecked(D: np.ndarray, c: float, p: float, alpha: float) -> GospaResult:
    """GOSPA from an ``(m, n)`` truth-by-estimate matrix of distances cut off at ``c``."""
    m, n = D.shape
    if m and n:
        rows, cols = optimal_assignment(D**p)
        d = D[rows, cols]
    else:
        d = np.empty(0)
    return _gospa_from_pairs(d, m, n, c, p, alpha)


def _gospa_from_pairs(d: np.ndarray, m: int, n: int, c: float, p: float, alpha: float) -> GospaResult:
    """GOSPA from the cut-off distances ``d`` of the optimally assigned pairs of ``m`` true and
    ``n`` estimated points."""
    if alpha == 2.0:  # a pair at the cut-off costs the same as one missed plus one false
        d = d[d < c]
    loc_sum = math.fsum(d**p)
    n_missed, n_false = m - d.size, n - d.size
    unit = c**p / alpha
    missed_sum, false_sum = unit * n_missed, unit * n_false
    return GospaResult(
        total=_root(loc_sum + missed_sum + false_sum, p),
        localisation=_root(loc_sum, p),
        missed=_root(missed_sum, p),
        false=_root(false_sum, p),
        n_missed=n_missed,
        n_false=n_false,
    )


def _track_distances(X: np.ndarray, Y: np.ndarray, c: float, q: float) -> np.ndarray:
    """``(m, n)`` OSPA(2) base distances between ``(m, W, d)`` and ``(n, W, d)`` track sets."""
    m, n = X.shape[0], Y.shape[0]
    if m == 0 or n == 0:
        return np.empty((m, n))
    ex = ~np.isnan(X[..., 0])[:, None, :]  # (m, 1, W)
    ey = ~np.isnan(Y[..., 0])[None, :, :]  # (1, n, W)
    both, union = ex & ey, ex | ey
    dist = np.linalg.norm(X[:, None] - Y[None, :], axis=-1)  # NaN unless both exist
    per_scan = np.where(both, np.minimum(dist, c), c) ** q
    count = union.sum(axis=-1)
    mean = np.where(union, per_scan, 0.0).sum(axis=-1) / np.maximum(count, 1)
    return mean if q == 1.0 else mean ** (1.0 / q)


def _window_tracks(run: Sequence[tuple[tuple[Hashable, ...], np.ndarray]], dim: int) -> np.ndarray:
    """``(n_labels, len(run), dim)`` NaN-padded array of the labels present in ``run``
    (first-seen order), each scan given as (labels, ``(n, dim)`` positions): one indexed write
    per scan.  Shared by :func:`ospa2_series` and :class:`RunScorer`."""
    index = {label: i for i, label in enumerate(dict.fromkeys(chain.from_iterable(lab for lab, _ in run)))}
    arr = np.full((len(index), len(run), dim), np.nan)
    for t, (labels, pos) in enumerate(run):
        if labels:
            arr[[index[label] for label in labels], t] = pos
    return arr


# --------------------------------------------------------------------------- public API


def ospa(X: ArrayLike, Y: ArrayLike, c: float = OSPA_C, p: float = 1.0) -> OspaResult:
    r"""OSPA distance between two finite point sets (Schuhmacher, Vo & Vo 2008).

    With :math:`X = \{x_1..x_m\}`, :math:`Y = \{y_1..y_n\}`, :math:`m \le n` (otherwise swap),
    :math:`d^{(c)}(x, y) = \min(c, \lVert x - y \rVert_2)` and :math:`\Pi_n` the permutations of
    :math:`\{1..n\}`:

    .. math::
        \bar d_p^{(c)}(X, Y) = \Big(\frac{1}{n}\Big(\min_{\pi \in \Pi_n} \sum_{i=1}^{m}
            d^{(c)}(x_i, y_{\pi(i)})^p + c^p (n - m)\Big)\Big)^{1/p}

    decomposed as :math:`\bar d^p = e_{\mathrm{loc}}^p + e_{\mathrm{card}}^p` with

    .. math::
        e_{\mathrm{loc}} = \Big(\frac{1}{n}\min_\pi \sum_{i=1}^{m}
            d^{(c)}(x_i, y_{\pi(i)})^p\Big)^{1/p}, \qquad
        e_{\mathrm{card}} = \Big(\frac{c^p (n - m)}{n}\Big)^{1/p}.

    Both sets empty gives 0; exactly one empty gives ``total = cardinality = c``. The optimal
    assignment is found with :func:`scipy.optimize.linear_sum_assignment`.

    Args:
        X, Y: ``(m, d)`` and ``(n, d)`` position arrays (empty: ``(0, d)`` or ``[]``).
        c: cut-off, > 0.
        p: order, >= 1.
    """
    c, p = check_positive(c, "c"), check_order(p, "p")
    X, Y = check_points(X, "X"), check_points(Y, "Y")
    check_same_dim(X, Y, "X", "Y")
    return _ospa_unchecked(_cutoff_distances(X, Y, c), c, p)


def gospa(
    X: ArrayLike, Y: ArrayLike, c: float = OSPA_C, p: float = 1.0, alpha: float = 2.0
) -> GospaResult:
    r"""GOSPA distance (Rahmathullah, Garcia-Fernandez & Svensson 2017); not size-normalised.

    ``X`` is the ground truth (``m`` points), ``Y`` the estimate (``n`` points). For
    :math:`m \le n` (otherwise swap):

    .. math::
        d_p^{(c, \alpha)}(X, Y) = \Big(\min_{\pi \in \Pi_n} \sum_{i=1}^{m}
            d^{(c)}(x_i, y_{\pi(i)})^p + \frac{c^p}{\alpha}(n - m)\Big)^{1/p}.

    For :math:`\alpha = 2` this equals the assignment-set form

    .. math::
        d_p^{(c, 2)}(X, Y) = \Big(\min_{\gamma \in \Gamma} \sum_{(i, j) \in \gamma}
            \lVert x_i - y_j \rVert^p + \frac{c^p}{2}\big(|X| - |\gamma|\big)
            + \frac{c^p}{2}\big(|Y| - |\gamma|\big)\Big)^{1/p},

    with :math:`\Gamma` the partial one-to-one assignments using only pairs closer than ``c``:
    assigning a pair at cost :math:`c^p` equals leaving both points out at
    :math:`c^p/2 + c^p/2`, so the permutation optimum on :math:`\min(d, c)^p` is computed and its
    pairs with :math:`d \ge c` are counted as one missed plus one false object.

    Reported parts (each a :math:`p`-th-power sum raised to :math:`1/p`, so
    ``total**p == localisation**p + missed**p + false**p``; exact sum for ``p == 1``):
    ``localisation`` from the assigned pairs, ``missed`` :math:`= (c^p n_{\mathrm{missed}} /
    \alpha)^{1/p}`, ``false`` :math:`= (c^p n_{\mathrm{false}} / \alpha)^{1/p}`. For
    :math:`\alpha < 2` no pair is reclassified (pairs at the cut-off stay assigned, in
    ``localisation``) and only the cardinality surplus counts as missed or false.

    Args:
        X: ``(m, d)`` true positions.
        Y: ``(n, d)`` estimated positions.
        c: cut-off, > 0.
        p: order, >= 1.
        alpha: cardinality-mismatch weight in (0, 2]; 2 is the standard choice.
    """
    c, p, alpha = check_positive(c, "c"), check_order(p, "p"), check_alpha(alpha)
    X, Y = check_points(X, "X"), check_points(Y, "Y")
    check_same_dim(X, Y, "X", "Y")
    return _gospa_unchecked(_cutoff_distances(X, Y, c), c, p, alpha)


def track_distance(x: ArrayLike, y: ArrayLike, c: float = OSPA_C, q: float = 1.0) -> float:
    r"""OSPA(2) base distance between two tracks (Beard, Vo & Vo 2017/2020).

    ``x`` and ``y`` are ``(W, d)`` arrays over the same window, ``NaN`` where the track does not
    exist. With :math:`\mathcal T` the scans at which at least one of them exists,

    .. math::
        \tilde d^{(c)}(x, y) = \Big(\frac{1}{|\mathcal T|} \sum_{t \in \mathcal T}
            d^{(c)}(x_t, y_t)^q\Big)^{1/q}, \qquad
        d^{(c)}(x_t, y_t) = \begin{cases} \min(c, \lVert x_t - y_t \rVert) & \text{both exist} \\
            c & \text{only one exists} \end{cases}

    (the OSPA distance between the at-most-singleton sets :math:`\{x_t\}` and :math:`\{y_t\}`),
    and 0 when :math:`\mathcal T = \emptyset`. ``q = 1`` is the plain mean.
    """
    c, q = check_positive(c, "c"), check_order(q, "q")
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    for name, arr in (("x", x), ("y", y)):
        if arr.ndim != 2:
            raise ValueError(f"{name} must be a (W, d) array, got shape {arr.shape}")
    if x.shape != y.shape:
        raise ValueError(f"x and y have mismatched shapes: {x.shape} vs {y.shape}")
    xs, ys = check_tracks(x[None], "x"), check_tracks(y[None], "y")
    if xs.shape[0] == 0 or ys.shape[0] == 0:  # a never-existing track
        return 0.0 if xs.shape[0] == ys.shape[0] else c
    return float(_track_distances(xs, ys, c, q)[0, 0])


def ospa2(
    tracks_X: ArrayLike, tracks_Y: ArrayLike, c: float = OSPA_C, p: float = 1.0, q: float = 1.0
) -> OspaResult:
    r"""OSPA(2) distance between two sets of tracks over a window (Beard, Vo & Vo 2017/2020).

    OSPA of order ``p`` and cut-off ``c`` (see :func:`ospa`) over the sets of tracks, with the
    base distance :func:`track_distance` (order ``q``, bounded by ``c``) in place of the
    Euclidean one:

    .. math::
        \breve d_{p,q}^{(c)}(X, Y) = \Big(\frac{1}{n}\Big(\min_{\pi \in \Pi_n} \sum_{i=1}^{m}
            \tilde d^{(c)}(x_i, y_{\pi(i)})^p + c^p (n - m)\Big)\Big)^{1/p}, \quad m \le n.

    Unlike per-scan OSPA it penalises label switches and track fragmentation. Tracks that do not
    exist at any scan of the window are not part of the set and are dropped.

    Args:
        tracks_X, tracks_Y: ``(n_tracks, W, d)`` arrays, ``NaN`` where a track does not exist
            (a position is either all ``NaN`` or all finite).
        c: cut-off, > 0.
        p: outer (OSPA) order, >= 1.
        q: order of the time average in the base distance, >= 1 (1: plain mean).
    """
    c, p, q = check_positive(c, "c"), check_order(p, "p"), check_order(q, "q")
    X, Y = check_tracks(tracks_X, "tracks_X"), check_tracks(tracks_Y, "tracks_Y")
    check_same_dim(X, Y, "tracks_X", "tracks_Y")
    return _ospa_unchecked(_track_distances(X, Y, c, q), c, p)


def ospa2_series(
    est_tracks: Sequence[LabelledScan],
    true_tracks: Sequence[LabelledScan],
    window: int = 10,
    c: float = OSPA_C,
    p: float = 1.0,
    q: float = 1.0,
) -> np.ndarray:
    r"""OSPA(2) total at every scan of a run, over a sliding window.

    At scan ``k`` the window is scans :math:`\max(0, k - w + 1) .. k` (shorter at the start of
    the run); the track sets are built from the labels present in that window (identity by
    label, ``NaN`` where a label is absent) and compared with :func:`ospa2`.

    Args:
        est_tracks, true_tracks: length-``K`` sequences (one entry per scan) of
            ``{label: (d,) position}`` mappings.
        window: window length ``w`` in scans, >= 1.
        c, p, q: as in :func:`ospa2`.

    Returns:
        ``(K,)`` float array of OSPA(2) totals.
    """
    c, p, q = check_positive(c, "c"), check_order(p, "p"), check_order(q, "q")
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise ValueError(f"window must be an integer >= 1, got {window!r}")
    est, d_est = check_labelled_run(est_tracks, "est_tracks")
    true, d_true = check_labelled_run(true_tracks, "true_tracks")
    if len(est) != len(true):
        raise ValueError(
            f"est_tracks and true_tracks must have one entry per scan: {len(est)} vs {len(true)}"
        )
    if d_est is not None and d_true is not None and d_est != d_true:
        raise ValueError(
            f"est_tracks and true_tracks have mismatched dimensions: {d_est} vs {d_true}"
        )
    dim = d_est if d_est is not None else d_true
    out = np.zeros(len(est))
    if dim is None:
        return out
    est_scans, true_scans = as_scans(est, dim), as_scans(true, dim)
    for k in range(len(est)):
        start = max(0, k - int(window) + 1)
        X = _window_tracks(est_scans[start:k + 1], dim)
        Y = _window_tracks(true_scans[start:k + 1], dim)
        out[k] = _ospa_unchecked(_track_distances(X, Y, c, q), c, p).total
    return out


def cardinality_error(n_est: float, n_true: float) -> float:
    r"""Absolute cardinality error :math:`|\hat n - n|`.

    Accepts non-negative finite reals so that expected cardinalities (e.g. the mean of a
    posterior cardinality distribution) can be scored too.
    """
    vals = []
    for name, v in (("n_est", n_est), ("n_true", n_true)):
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a non-negative number, got {v!r}") from None
        if not math.isfinite(f) or f < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        vals.append(f)
    return abs(vals[0] - vals[1])


