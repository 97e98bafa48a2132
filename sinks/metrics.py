r"""Multi-object tracking performance metrics: OSPA, OSPA(2), GOSPA, cardinality error and
label keeping through crossings (:func:`crossing_label_keeping`).

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
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import asdict, dataclass
from itertools import chain

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "CrossingPairResult",
    "CrossingResult",
    "crossing_label_keeping",
    "GospaResult",
    "adjusted_rand_index",
    "OspaResult",
    "cardinality_error",
    "gospa",
    "ospa",
    "ospa2",
    "ospa2_series",
    "track_distance",
]

LabelledScan = Mapping[Hashable, ArrayLike]


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


# --------------------------------------------------------------------------- validation


def _check_positive(value: object, name: str) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def _check_order(value: object, name: str) -> float:
    v = _check_positive(value, name)
    if v < 1.0:
        raise ValueError(f"{name} must be >= 1 (the metric needs order >= 1), got {value!r}")
    return v


def _check_alpha(value: object) -> float:
    v = _check_positive(value, "alpha")
    if v > 2.0:
        raise ValueError(f"alpha must be in (0, 2] (GOSPA is a metric only there), got {value!r}")
    return v


def _check_points(A: ArrayLike, name: str) -> np.ndarray:
    """``(m, d)`` finite float array; ``[]`` becomes ``(0, 0)`` (empty, dimension unknown)."""
    arr = np.asarray(A, dtype=float)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 0)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be an (m, d) point array, got shape {arr.shape}")
    if arr.shape[0] > 0 and arr.shape[1] == 0:
        raise ValueError(f"{name} has points with no coordinates (shape {arr.shape})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _check_same_dim(X: np.ndarray, Y: np.ndarray, nx: str, ny: str) -> None:
    """Trailing dimensions must agree unless one side is an empty set given without one."""
    if X.shape[-1] == 0 and X.shape[0] == 0 or Y.shape[-1] == 0 and Y.shape[0] == 0:
        return
    if X.shape[1:] != Y.shape[1:]:
        raise ValueError(
            f"{nx} and {ny} have mismatched dimensions: {X.shape[1:]} vs {Y.shape[1:]}"
        )


def _check_tracks(A: ArrayLike, name: str) -> np.ndarray:
    """``(n, W, d)`` float array with whole-position NaNs only; never-existing tracks dropped."""
    arr = np.asarray(A, dtype=float)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 0, 0)
    if arr.ndim != 3:
        raise ValueError(f"{name} must be an (n_tracks, W, d) array, got shape {arr.shape}")
    if arr.shape[0] > 0 and arr.shape[1] > 0 and arr.shape[2] == 0:
        raise ValueError(f"{name} has positions with no coordinates (shape {arr.shape})")
    if np.any(np.isinf(arr)):
        raise ValueError(f"{name} contains infinite values")
    nan = np.isnan(arr)
    if np.any(nan.any(axis=-1) != nan.all(axis=-1)):
        raise ValueError(f"{name} has partially-NaN positions (a position is all NaN or finite)")
    exists = ~nan.all(axis=-1)  # (n, W); all False when d == 0
    return arr[exists.any(axis=1)]


def _check_labelled_run(run: Sequence[LabelledScan], name: str) -> tuple[list[dict], int | None]:
    """Per-scan ``{label: (d,) position}`` dicts -> (list of dicts of arrays, d or None)."""
    if isinstance(run, (str, bytes, Mapping)) or not isinstance(run, Sequence):
        raise ValueError(
            f"{name} must be a sequence (one entry per scan) of label -> position dicts"
        )
    out: list[dict] = []
    dim: int | None = None
    for k, scan in enumerate(run):
        if not isinstance(scan, Mapping):
            raise ValueError(f"{name}[{k}] must be a mapping label -> position, got {type(scan)}")
        conv = {}
        for label, pos in scan.items():
            x = np.asarray(pos, dtype=float)
            if x.ndim != 1 or x.size == 0:
                raise ValueError(f"{name}[{k}][{label!r}] must be a (d,) position, got {x.shape}")
            if not np.all(np.isfinite(x)):
                raise ValueError(f"{name}[{k}][{label!r}] contains NaN or infinite values")
            if dim is not None and x.size != dim:
                raise ValueError(f"{name}[{k}][{label!r}] has dimension {x.size}, expected {dim}")
            dim = x.size
            conv[label] = x
        out.append(conv)
    return out, dim


def _as_scans(run: list[dict], dim: int) -> list[tuple[tuple[Hashable, ...], np.ndarray]]:
    """Checked ``{label: position}`` scans as (labels, ``(n, dim)`` positions)."""
    return [(tuple(scan), np.array(list(scan.values()), dtype=float).reshape(len(scan), dim)) for scan in run]


# --------------------------------------------------------------------------- hot path


def _root(x: float, p: float) -> float:
    return float(x) if p == 1.0 else float(x) ** (1.0 / p)


def _cutoff_distances(X: np.ndarray, Y: np.ndarray, c: float) -> np.ndarray:
    """``(m, n)`` matrix of :math:`\\min(c, \\lVert x_i - y_j \\rVert)`."""
    if X.shape[0] == 0 or Y.shape[0] == 0:
        return np.empty((X.shape[0], Y.shape[0]))
    from scipy.spatial.distance import cdist  # lazy, see _assign

    return np.minimum(cdist(X, Y), c)


def _assign(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Optimal assignment (:func:`scipy.optimize.linear_sum_assignment`).

    scipy is imported here, at the first score: importing ``scipy.optimize`` takes about 0.5 s,
    which a process that only unpickles :class:`OspaResult` (the Rerun recording process, see
    ``sinks.rerun_writer``) should not pay.
    """
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment(cost)


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
    rows, cols = _assign(cost)
    loc_term = math.fsum(cost[rows, cols]) / n  # correctly rounded, order-free
    card_term = c**p * (n - m) / n
    return OspaResult(_root(loc_term + card_term, p), _root(loc_term, p), _root(card_term, p))


def _gospa_unchecked(D: np.ndarray, c: float, p: float, alpha: float) -> GospaResult:
    """GOSPA from an ``(m, n)`` truth-by-estimate matrix of distances cut off at ``c``."""
    m, n = D.shape
    if m and n:
        rows, cols = _assign(D**p)
        d = D[rows, cols]
    else:
        d = np.empty(0)
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
    per scan.  Shared by :func:`ospa2_series` and :class:`sinks.scoring.RunScorer`."""
    index = {label: i for i, label in enumerate(dict.fromkeys(chain.from_iterable(lab for lab, _ in run)))}
    arr = np.full((len(index), len(run), dim), np.nan)
    for t, (labels, pos) in enumerate(run):
        if labels:
            arr[[index[label] for label in labels], t] = pos
    return arr


# --------------------------------------------------------------------------- public API


def ospa(X: ArrayLike, Y: ArrayLike, c: float = 100.0, p: float = 1.0) -> OspaResult:
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
    c, p = _check_positive(c, "c"), _check_order(p, "p")
    X, Y = _check_points(X, "X"), _check_points(Y, "Y")
    _check_same_dim(X, Y, "X", "Y")
    return _ospa_unchecked(_cutoff_distances(X, Y, c), c, p)


def gospa(
    X: ArrayLike, Y: ArrayLike, c: float = 100.0, p: float = 1.0, alpha: float = 2.0
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
    c, p, alpha = _check_positive(c, "c"), _check_order(p, "p"), _check_alpha(alpha)
    X, Y = _check_points(X, "X"), _check_points(Y, "Y")
    _check_same_dim(X, Y, "X", "Y")
    return _gospa_unchecked(_cutoff_distances(X, Y, c), c, p, alpha)


def track_distance(x: ArrayLike, y: ArrayLike, c: float = 100.0, q: float = 1.0) -> float:
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
    c, q = _check_positive(c, "c"), _check_order(q, "q")
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    for name, arr in (("x", x), ("y", y)):
        if arr.ndim != 2:
            raise ValueError(f"{name} must be a (W, d) array, got shape {arr.shape}")
    if x.shape != y.shape:
        raise ValueError(f"x and y have mismatched shapes: {x.shape} vs {y.shape}")
    xs, ys = _check_tracks(x[None], "x"), _check_tracks(y[None], "y")
    if xs.shape[0] == 0 or ys.shape[0] == 0:  # a never-existing track
        return 0.0 if xs.shape[0] == ys.shape[0] else c
    return float(_track_distances(xs, ys, c, q)[0, 0])


def ospa2(
    tracks_X: ArrayLike, tracks_Y: ArrayLike, c: float = 100.0, p: float = 1.0, q: float = 1.0
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
    c, p, q = _check_positive(c, "c"), _check_order(p, "p"), _check_order(q, "q")
    X, Y = _check_tracks(tracks_X, "tracks_X"), _check_tracks(tracks_Y, "tracks_Y")
    _check_same_dim(X, Y, "tracks_X", "tracks_Y")
    return _ospa_unchecked(_track_distances(X, Y, c, q), c, p)


def ospa2_series(
    est_tracks: Sequence[LabelledScan],
    true_tracks: Sequence[LabelledScan],
    window: int = 10,
    c: float = 100.0,
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
    c, p, q = _check_positive(c, "c"), _check_order(p, "p"), _check_order(q, "q")
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise ValueError(f"window must be an integer >= 1, got {window!r}")
    est, d_est = _check_labelled_run(est_tracks, "est_tracks")
    true, d_true = _check_labelled_run(true_tracks, "true_tracks")
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
    est_scans, true_scans = _as_scans(est, dim), _as_scans(true, dim)
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


# --------------------------------------------------------------------------- partitions


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


# --------------------------------------------------------------------------- crossings


@dataclass(frozen=True, slots=True)
class CrossingPairResult:
    """Label keeping of one crossing pair ``(id_a, id_b)`` crossing at ``scan``.

    ``before``/``after`` are the scans checked; ``labels_before``/``labels_after`` the track
    labels assigned to ``(id_a, id_b)`` there (``None``: unassigned).  ``kept`` when all four
    exist and each object has the same label before and after.
    """

    id_a: Hashable
    id_b: Hashable
    scan: int
    before: int
    after: int
    labels_before: tuple[Hashable | None, Hashable | None]
    labels_after: tuple[Hashable | None, Hashable | None]
    kept: bool


@dataclass(frozen=True, slots=True)
class CrossingResult:
    """Fraction of crossing pairs that kept both labels (``nan`` without pairs) and each pair."""

    fraction_kept: float
    pairs: tuple[CrossingPairResult, ...]


def _assigned_labels(truth: dict, est: dict, gate: float) -> dict:
    """Object id -> track label by optimal assignment of positions; pairs at distance
    ``>= gate`` stay unassigned (as ``benchmarks/accuracy.py``'s label-switch count)."""
    if not truth or not est:
        return {}
    ids, labels = list(truth), list(est)
    X = np.array([truth[i] for i in ids], dtype=float)
    Y = np.array([est[j] for j in labels], dtype=float)
    D = np.linalg.norm(X[:, None, :] - Y[None, :, :], axis=2)
    rows, cols = _assign(np.minimum(D, gate))
    return {ids[r]: labels[c] for r, c in zip(rows, cols) if D[r, c] < gate}


def _presence(true: list[dict], obj: Hashable, first_scan: int) -> tuple[int, int]:
    scans = [first_scan + k for k, scan in enumerate(true) if obj in scan]
    if not scans:
        raise ValueError(f"crossing object {obj!r} is never present in the truth")
    return scans[0], scans[-1]


def crossing_label_keeping(
    true_tracks: Sequence[LabelledScan],
    est_tracks: Sequence[LabelledScan],
    crossings: Sequence[tuple[Hashable, Hashable, int]],
    *,
    offset: int = 5,
    gate: float = 100.0,
    first_scan: int = 1,
) -> CrossingResult:
    r"""Do both objects of each crossing pair keep their track label through the crossing?

    ``true_tracks[k]`` / ``est_tracks[k]`` are the ``{id: position}`` / ``{label: position}``
    dicts of scan ``first_scan + k``; ``crossings`` holds ``(id_a, id_b, scan)``.  For a pair
    crossing at scan :math:`c` the scans checked are :math:`c - \text{offset}` and
    :math:`c + \text{offset}`, clipped to the scans where *both* objects are present.  At each,
    all true objects are optimally assigned (Hungarian) to the estimated tracks with cost
    :math:`\min(\lVert x - y \rVert, \text{gate})`, pairs at distance ``>= gate`` unassigned.
    The pair **keeps labels** when both objects have a label at both scans and each object's
    label after equals its label before (a swap or a lost object fails).
    """
    true, dim_t = _check_labelled_run(true_tracks, "true_tracks")
    est, dim_e = _check_labelled_run(est_tracks, "est_tracks")
    if len(true) != len(est):
        raise ValueError(f"true_tracks has {len(true)} scans, est_tracks {len(est)}")
    if dim_t is not None and dim_e is not None and dim_t != dim_e:
        raise ValueError(f"true_tracks and est_tracks have dimensions {dim_t} and {dim_e}")
    gate = _check_positive(gate, "gate")
    last_scan = first_scan + len(true) - 1
    out = []
    for id_a, id_b, scan in crossings:
        scan = int(scan)
        if not first_scan <= scan <= last_scan:
            raise ValueError(f"crossing ({id_a!r}, {id_b!r}) at scan {scan} is outside "
                             f"{first_scan}..{last_scan}")
        (fa, la), (fb, lb) = (_presence(true, o, first_scan) for o in (id_a, id_b))
        before = max(scan - int(offset), fa, fb)
        after = min(scan + int(offset), la, lb)
        got = []
        for s in (before, after):
            k = s - first_scan
            lab = _assigned_labels(true[k], est[k], gate)
            got.append((lab.get(id_a), lab.get(id_b)))
        (a0, b0), (a1, b1) = got
        kept = None not in (a0, b0, a1, b1) and a0 == a1 and b0 == b1
        out.append(CrossingPairResult(id_a, id_b, scan, before, after, got[0], got[1], kept))
    frac = float(np.mean([p.kept for p in out])) if out else float("nan")
    return CrossingResult(frac, tuple(out))
