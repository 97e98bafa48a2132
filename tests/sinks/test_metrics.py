"""Tests for sinks.metrics: OSPA, OSPA(2), GOSPA, cardinality error."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bnptrack.sinks.metrics import (
    GospaResult,
    OspaResult,
    cardinality_error,
    gospa,
    ospa,
    ospa2,
    ospa2_series,
    track_distance,
)

NAN = np.nan


# --------------------------------------------------------------------------- references


def brute_ospa(X, Y, c, p):
    """OSPA total by enumerating every injective assignment of the smaller set."""
    X, Y = np.asarray(X, float).reshape(-1, 2), np.asarray(Y, float).reshape(-1, 2)
    if len(X) > len(Y):
        X, Y = Y, X
    m, n = len(X), len(Y)
    if n == 0:
        return 0.0
    best = min(
        sum(min(c, float(np.linalg.norm(X[i] - Y[j]))) ** p for i, j in enumerate(perm))
        for perm in itertools.permutations(range(n), m)
    )
    return ((best + c**p * (n - m)) / n) ** (1 / p)


def brute_gospa(X, Y, c, p):
    """alpha = 2 GOSPA total by enumerating every partial assignment (pairs closer than c)."""
    X, Y = np.asarray(X, float).reshape(-1, 2), np.asarray(Y, float).reshape(-1, 2)
    m, n = len(X), len(Y)
    best = math.inf
    for choice in itertools.product(range(-1, n), repeat=m):  # -1: truth i unassigned
        used = [j for j in choice if j >= 0]
        if len(used) != len(set(used)):
            continue
        dists = [float(np.linalg.norm(X[i] - Y[j])) for i, j in enumerate(choice) if j >= 0]
        if any(d >= c for d in dists):
            continue
        k = len(dists)
        best = min(best, sum(d**p for d in dists) + c**p / 2 * (m - k + n - k))
    return best ** (1 / p)


def tracks(*rows):
    """Build an (n, W, 2) track array from per-track lists of (x, y) or None (absent)."""
    out = np.full((len(rows), len(rows[0]) if rows else 0, 2), NAN)
    for i, row in enumerate(rows):
        for t, pos in enumerate(row):
            if pos is not None:
                out[i, t] = pos
    return out


# --------------------------------------------------------------------------- OSPA hand cases


def test_ospa_single_pair():
    r = ospa([[0, 0]], [[3, 4]], c=100, p=1)
    assert r == OspaResult(5.0, 5.0, 0.0)


def test_ospa_cardinality_mismatch():
    r = ospa([[0, 0], [10, 0]], [[0, 0]], c=100, p=1)
    assert r.total == pytest.approx(50.0)
    assert r.localisation == 0.0
    assert r.cardinality == pytest.approx(50.0)
    assert ospa([[0, 0]], [[0, 0], [10, 0]], c=100, p=1) == r


def test_ospa_cutoff():
    r = ospa([[0, 0]], [[150, 0]], c=100, p=1)
    assert r == OspaResult(100.0, 100.0, 0.0)
    r = ospa([[0, 0], [0, 500]], [[150, 0], [3, 504]], c=100, p=1)
    assert r.total == pytest.approx((100 + 5) / 2)


def test_ospa_p2_by_hand():
    # (0,0)-(3,4) = 5 beats (0,10)-(3,4) = sqrt(45); one unassigned point costs c^2.
    r = ospa([[0, 0], [0, 10]], [[3, 4]], c=10, p=2)
    assert r.total == pytest.approx(math.sqrt((25 + 100) / 2))
    assert r.localisation == pytest.approx(math.sqrt(12.5))
    assert r.cardinality == pytest.approx(math.sqrt(50))
    r = ospa([[0, 0], [10, 0]], [[0, 0]], c=100, p=2)
    assert r.total == pytest.approx(100 / math.sqrt(2))


def test_ospa_empty_sets():
    assert ospa([], []) == OspaResult(0.0, 0.0, 0.0)
    assert ospa(np.empty((0, 2)), np.empty((0, 2)), c=7, p=3) == OspaResult(0.0, 0.0, 0.0)
    for p in (1, 2, 3.7):
        assert ospa([], [[1, 2], [3, 4]], c=42, p=p) == OspaResult(42.0, 0.0, 42.0)
        assert ospa(np.empty((0, 2)), [[1, 2]], c=42, p=p) == OspaResult(42.0, 0.0, 42.0)
        assert ospa([[1, 2]], [], c=42, p=p) == OspaResult(42.0, 0.0, 42.0)


def test_ospa_needs_optimal_assignment():
    # Greedy nearest-first may pair (0,0)-(1,0) and be left with (2,0)-(-1,0) = 3 (mean 2);
    # the optimum pairs (0,0)-(-1,0) and (2,0)-(1,0), both at distance 1.
    X = [[0, 0], [2, 0]]
    Y = [[1, 0], [-1, 0]]
    assert ospa(X, Y).total == 1.0 == brute_ospa(X, Y, 100, 1)


def test_ospa_matches_brute_force_random():
    rng = np.random.default_rng(12345)
    for _ in range(200):
        m, n = rng.integers(0, 6, size=2)
        X, Y = rng.uniform(-150, 150, (m, 2)), rng.uniform(-150, 150, (n, 2))
        c = float(rng.choice([10.0, 50.0, 100.0]))
        p = float(rng.choice([1.0, 2.0, 3.0]))
        assert ospa(X, Y, c, p).total == pytest.approx(brute_ospa(X, Y, c, p), rel=1e-12, abs=1e-12)


def test_result_dataclasses():
    r = ospa([[0, 0]], [[3, 4]])
    assert r.as_dict() == {"total": 5.0, "localisation": 5.0, "cardinality": 0.0}
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.total = 1.0  # type: ignore[misc]
    g = gospa([[0, 0]], [])
    assert g.as_dict() == {
        "total": 50.0,
        "localisation": 0.0,
        "missed": 50.0,
        "false": 0.0,
        "n_missed": 1,
        "n_false": 0,
    }
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.n_false = 3  # type: ignore[misc]


# --------------------------------------------------------------------------- GOSPA hand cases


def test_gospa_one_missed():
    assert gospa([[0, 0]], [], c=100, p=1) == GospaResult(50.0, 0.0, 50.0, 0.0, 1, 0)


def test_gospa_one_false():
    assert gospa([], [[0, 0]], c=100, p=1) == GospaResult(50.0, 0.0, 0.0, 50.0, 0, 1)


def test_gospa_close_pair():
    assert gospa([[0, 0]], [[3, 4]], c=100, p=1) == GospaResult(5.0, 5.0, 0.0, 0.0, 0, 0)


def test_gospa_far_pair_is_missed_plus_false():
    assert gospa([[0, 0]], [[200, 0]], c=100, p=1) == GospaResult(100.0, 0.0, 50.0, 50.0, 1, 1)
    # exactly at the cut-off also counts as missed + false
    assert gospa([[0, 0]], [[100, 0]], c=100, p=1) == GospaResult(100.0, 0.0, 50.0, 50.0, 1, 1)


def test_gospa_not_normalised():
    X = [[0, 0], [100, 100], [500, 500]]
    Y = [[3, 4], [100, 103]]
    g = gospa(X, Y, c=100, p=1)
    assert g.total == pytest.approx(5 + 3 + 50)
    assert (g.localisation, g.missed, g.false) == (pytest.approx(8.0), 50.0, 0.0)
    assert (g.n_missed, g.n_false) == (1, 0)


def test_gospa_p2_by_hand():
    g = gospa([[0, 0], [100, 0]], [[3, 4]], c=10, p=2)
    assert g.total == pytest.approx(math.sqrt(25 + 50))
    assert g.localisation == pytest.approx(5.0)
    assert g.missed == pytest.approx(math.sqrt(50))
    assert g.false == 0.0
    assert g.total**2 == pytest.approx(g.localisation**2 + g.missed**2 + g.false**2)


def test_gospa_alpha_below_two_keeps_cutoff_pairs_assigned():
    g = gospa([[0, 0]], [[200, 0]], c=100, p=1, alpha=1)
    assert g == GospaResult(100.0, 100.0, 0.0, 0.0, 0, 0)
    g = gospa([[0, 0], [5, 5]], [[200, 0]], c=100, p=1, alpha=1)
    # one pair at the cut-off (100) plus one unassigned truth at c / alpha = 100
    assert g == GospaResult(200.0, 100.0, 100.0, 0.0, 1, 0)


def test_gospa_empty():
    assert gospa([], []) == GospaResult(0.0, 0.0, 0.0, 0.0, 0, 0)


def test_gospa_matches_brute_force_random():
    rng = np.random.default_rng(777)
    for _ in range(150):
        m, n = rng.integers(0, 5, size=2)
        X, Y = rng.uniform(-100, 100, (m, 2)), rng.uniform(-100, 100, (n, 2))
        c = float(rng.choice([20.0, 60.0, 100.0]))
        p = float(rng.choice([1.0, 2.0]))
        g = gospa(X, Y, c, p)
        assert g.total == pytest.approx(brute_gospa(X, Y, c, p), rel=1e-12, abs=1e-12)
        assert g.n_missed - g.n_false == m - n


# --------------------------------------------------------------------------- OSPA(2) hand cases


def test_track_distance_identical_is_zero():
    x = tracks([(0, 0), (1, 1), None, (3, 3)])[0]
    assert track_distance(x, x) == 0.0


def test_track_distance_half_window():
    full = tracks([(0, 0)] * 10)[0]
    half = tracks([None] * 5 + [(0, 0)] * 5)[0]
    assert track_distance(full, half, c=100) == pytest.approx(50.0)
    assert ospa2(full[None], half[None], c=100) == OspaResult(50.0, 50.0, 0.0)


def test_track_distance_mixed_and_q():
    x = tracks([(0, 0), (0, 0), (0, 0), None])[0]
    y = tracks([(0, 0), (3, 4), (300, 0), None])[0]
    # scans 0..2 exist in both: 0, 5, min(100, 300); scan 3 in neither (excluded)
    assert track_distance(x, y, c=100) == pytest.approx(105 / 3)
    assert track_distance(x, y, c=100, q=2) == pytest.approx(math.sqrt((25 + 100**2) / 3))


def test_track_distance_never_existing():
    none = tracks([None, None])[0]
    some = tracks([(0, 0), None])[0]
    assert track_distance(none, none, c=10) == 0.0
    assert track_distance(none, some, c=10) == 10.0


def test_ospa2_identical_sets():
    X = tracks([(0, 0), (1, 0), (2, 0)], [None, (5, 5), (6, 6)])
    assert ospa2(X, X) == OspaResult(0.0, 0.0, 0.0)


def test_ospa2_empty_and_dropped_tracks():
    X = tracks([(0, 0), (1, 0)])
    ghost = tracks([(0, 0), (1, 0)], [None, None])
    assert ospa2(ghost, X) == ospa2(X, X) == OspaResult(0.0, 0.0, 0.0)
    assert ospa2([], []) == OspaResult(0.0, 0.0, 0.0)
    assert ospa2(np.empty((0, 2, 2)), X, c=30) == OspaResult(30.0, 0.0, 30.0)
    assert ospa2(tracks([None, None]), X, c=30) == OspaResult(30.0, 0.0, 30.0)


def test_ospa2_fragmented_track():
    truth = tracks([(0, 0)] * 10)
    est = tracks([(0, 0)] * 5 + [None] * 5, [None] * 5 + [(0, 0)] * 5)
    r = ospa2(est, truth, c=100, p=1)
    # each fragment is at base distance 50 from the truth; one fragment is surplus (cost c)
    assert r.total == pytest.approx((50 + 100) / 2)
    assert r.localisation == pytest.approx(25.0)
    assert r.cardinality == pytest.approx(50.0)


A, B = (0.0, 0.0), (50.0, 0.0)


def label_switch_run(K=20, switch=5):
    truth = [{"a": np.array(A), "b": np.array(B)} for _ in range(K)]
    est = [
        {1: np.array(A), 2: np.array(B)} if k < switch else {1: np.array(B), 2: np.array(A)}
        for k in range(K)
    ]
    return est, truth


def test_label_switch_raises_ospa2_but_not_ospa():
    est, truth = label_switch_run(K=10, switch=5)
    for e, t in zip(est, truth):  # per-scan OSPA sees no error at all
        assert ospa(np.array(list(e.values())), np.array(list(t.values()))).total == 0.0
    X = tracks(*[[e[lab] for e in est] for lab in (1, 2)])
    Y = tracks(*[[t[lab] for t in truth] for lab in ("a", "b")])
    # each estimate track follows one truth for 5 scans and is 50 away for the other 5
    r = ospa2(X, Y, c=100, p=1)
    assert r.total == pytest.approx(25.0)
    assert r.cardinality == 0.0


def test_ospa2_series_label_switch():
    K, switch, w = 20, 5, 10
    est, truth = label_switch_run(K, switch)
    series = ospa2_series(est, truth, window=w, c=100, p=1)
    assert series.shape == (K,)
    expected = []
    for k in range(K):
        scans = range(max(0, k - w + 1), k + 1)
        before = sum(s < switch for s in scans)
        expected.append(50.0 * min(before, len(scans) - before) / len(scans))
    np.testing.assert_allclose(series, expected, rtol=1e-12, atol=1e-12)
    assert series[:5] == pytest.approx([0.0] * 5)
    assert series[5] == pytest.approx(50 / 6)
    assert series[9] == pytest.approx(25.0)
    assert series[10] == pytest.approx(20.0)
    assert series[14:] == pytest.approx([0.0] * 6)  # window no longer spans the switch


def test_ospa2_series_births_deaths_and_empty_scans():
    truth = [{}, {"a": [0.0, 0.0]}, {"a": [1.0, 0.0]}, {}]
    est = [{}, {}, {7: [1.0, 0.0]}, {}]
    s = ospa2_series(est, truth, window=2, c=10)
    # k=0: nothing; k=1: one truth, no estimate -> c; k=2: window 1..2, base distance
    # (10 + 0)/2 = 5; k=3: window 2..3, both exist only at scan 2 -> 0
    np.testing.assert_allclose(s, [0.0, 10.0, 5.0, 0.0])
    assert np.all(ospa2_series([{}, {}], [{}, {}]) == 0.0)
    assert ospa2_series([], []).shape == (0,)


def test_ospa2_series_matches_ospa2():
    rng = np.random.default_rng(3)
    K = 12
    truth = [{lab: rng.normal(0, 30, 2) for lab in "abc" if rng.random() < 0.8} for _ in range(K)]
    est = [{lab: rng.normal(0, 30, 2) for lab in range(4) if rng.random() < 0.7} for _ in range(K)]
    s = ospa2_series(est, truth, window=4, c=40, p=2)
    for k in range(K):
        lo = max(0, k - 3)
        win_e, win_t = est[lo : k + 1], truth[lo : k + 1]
        X = tracks(*[[e.get(lab) for e in win_e] for lab in range(4)])
        Y = tracks(*[[t.get(lab) for t in win_t] for lab in "abc"])
        assert s[k] == pytest.approx(ospa2(X, Y, c=40, p=2).total, rel=1e-12, abs=1e-12)


# --------------------------------------------------------------------------- cardinality error


def test_cardinality_error():
    assert cardinality_error(3, 5) == 2.0
    assert cardinality_error(5, 3) == 2.0
    assert cardinality_error(np.int64(4), 4) == 0.0
    assert cardinality_error(2.5, 1) == 1.5
    assert isinstance(cardinality_error(1, 1), float)


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize("fn", [ospa, gospa])
def test_point_metric_validation(fn):
    with pytest.raises(ValueError, match="mismatched dimensions"):
        fn([[0, 0]], [[0, 0, 0]])
    with pytest.raises(ValueError, match="X"):
        fn([[NAN, 0]], [[0, 0]])
    with pytest.raises(ValueError, match="Y"):
        fn([[0, 0]], [[0, np.inf]])
    with pytest.raises(ValueError, match="X"):
        fn([0, 0], [[0, 0]])  # 1-D non-empty: not a point array
    for c in (0, -1, NAN, np.inf, "abc"):
        with pytest.raises(ValueError, match="c"):
            fn([[0, 0]], [[1, 1]], c=c)
    for p in (0.5, 0, -2, NAN):
        with pytest.raises(ValueError, match="p"):
            fn([[0, 0]], [[1, 1]], p=p)


def test_gospa_alpha_validation():
    for alpha in (0, 2.5, -1):
        with pytest.raises(ValueError, match="alpha"):
            gospa([[0, 0]], [[1, 1]], alpha=alpha)


def test_ospa2_validation():
    X = tracks([(0, 0), (1, 1)])
    with pytest.raises(ValueError, match="mismatched dimensions"):
        ospa2(X, np.zeros((1, 3, 2)))
    with pytest.raises(ValueError, match="mismatched dimensions"):
        ospa2(X, np.zeros((1, 2, 3)))
    with pytest.raises(ValueError, match="tracks_Y"):
        ospa2(X, np.array([[[0.0, NAN], [1.0, 1.0]]]))  # partially NaN position
    with pytest.raises(ValueError, match="tracks_X"):
        ospa2(np.zeros((2, 2)), X)
    with pytest.raises(ValueError, match="tracks_X"):
        ospa2(np.full((1, 2, 2), np.inf), X)
    with pytest.raises(ValueError, match="c"):
        ospa2(X, X, c=0)
    with pytest.raises(ValueError, match="p"):
        ospa2(X, X, p=0.9)
    with pytest.raises(ValueError, match="q"):
        ospa2(X, X, q=0.5)
    with pytest.raises(ValueError, match="mismatched shapes"):
        track_distance(X[0], np.zeros((3, 2)))
    with pytest.raises(ValueError, match="x"):
        track_distance(np.zeros(2), np.zeros(2))


def test_ospa2_series_validation():
    good = [{1: [0.0, 0.0]}]
    with pytest.raises(ValueError, match="one entry per scan"):
        ospa2_series(good, good * 2)
    with pytest.raises(ValueError, match="window"):
        ospa2_series(good, good, window=0)
    with pytest.raises(ValueError, match="mismatched dimensions"):
        ospa2_series(good, [{1: [0.0, 0.0, 0.0]}])
    with pytest.raises(ValueError, match="est_tracks"):
        ospa2_series([{1: [0.0, 0.0]}, {1: [0.0]}], good * 2)
    with pytest.raises(ValueError, match="true_tracks"):
        ospa2_series(good, [{1: [NAN, 0.0]}])
    with pytest.raises(ValueError, match="true_tracks"):
        ospa2_series(good, [[0.0, 0.0]])
    with pytest.raises(ValueError, match="c"):
        ospa2_series(good, good, c=-1)


def test_cardinality_error_validation():
    for bad in (-1, NAN, np.inf, "x", None):
        with pytest.raises(ValueError, match="n_est"):
            cardinality_error(bad, 1)
        with pytest.raises(ValueError, match="n_true"):
            cardinality_error(1, bad)


# --------------------------------------------------------------------------- properties

coord = st.floats(-1000, 1000, allow_nan=False, allow_infinity=False)
point_sets = st.lists(st.tuples(coord, coord), max_size=5).map(
    lambda pts: np.array(pts, dtype=float).reshape(-1, 2)
)
cutoffs = st.floats(1.0, 2000.0)
orders = st.one_of(st.just(1.0), st.just(2.0), st.floats(1.0, 4.0))
PROP = settings(max_examples=100, deadline=None)  # hypothesis's default number of examples
# The property tests are marked slow (0.3-1 s each, most of it generating examples): the fast
# subset keeps the hand cases and the brute-force comparisons of the same metrics above.


def tol(*vals):
    return 1e-9 * max(1.0, *vals)


@pytest.mark.slow
@PROP
@given(point_sets, point_sets, point_sets, cutoffs, orders)
def test_ospa_metric_properties(X, Y, Z, c, p):
    dxy, dyx = ospa(X, Y, c, p), ospa(Y, X, c, p)
    dxz, dyz = ospa(X, Z, c, p).total, ospa(Y, Z, c, p).total
    assert ospa(X, X, c, p).total == 0.0
    # symmetric up to rounding (near-tied assignments may be picked differently)
    for a, b in zip(dataclasses.astuple(dxy), dataclasses.astuple(dyx)):
        assert a == pytest.approx(b, rel=1e-12, abs=tol(c) * 1e-3)
    assert 0.0 <= dxy.total <= c * (1 + 1e-12)
    assert min(dxy.localisation, dxy.cardinality) >= 0.0
    assert dxy.total**p == pytest.approx(dxy.localisation**p + dxy.cardinality**p, rel=1e-9)
    if p == 1.0:
        assert dxy.total == dxy.localisation + dxy.cardinality
    assert dxz <= dxy.total + dyz + tol(c)


@pytest.mark.slow
@PROP
@given(point_sets, point_sets, point_sets, cutoffs, orders, st.sampled_from([2.0, 1.0, 0.5]))
def test_gospa_metric_properties(X, Y, Z, c, p, alpha):
    g = gospa(X, Y, c, p, alpha)
    g_rev = gospa(Y, X, c, p, alpha)
    assert gospa(X, X, c, p, alpha).total == 0.0
    assert g.total == pytest.approx(g_rev.total, rel=1e-12)  # parts summed in another order
    assert (g.n_missed, g.n_false) == (g_rev.n_false, g_rev.n_missed)
    assert min(g.total, g.localisation, g.missed, g.false) >= 0.0
    bound = (c**p / alpha * (len(X) + len(Y))) ** (1 / p)
    assert g.total <= bound * (1 + 1e-12)
    assert g.total**p == pytest.approx(
        g.localisation**p + g.missed**p + g.false**p, rel=1e-9, abs=1e-300
    )
    if p == 1.0:
        assert g.total == g.localisation + g.missed + g.false
    assert len(X) - g.n_missed == len(Y) - g.n_false >= 0
    dxz, dyz = gospa(X, Z, c, p, alpha).total, gospa(Y, Z, c, p, alpha).total
    assert dxz <= g.total + dyz + tol(c, g.total, dxz, dyz)


@st.composite
def track_triples(draw, n_tracks=1, max_w=6):
    """Three track sets (or single tracks) of ``(k, W, 2)`` over a shared window ``W``."""
    W = draw(st.integers(1, max_w))
    present = st.one_of(st.none(), st.tuples(coord, coord))
    track = st.lists(present, min_size=W, max_size=W).filter(
        lambda r: any(x is not None for x in r)
    )
    sizes = st.integers(n_tracks if n_tracks == 1 else 0, n_tracks)
    return tuple(tracks(*draw(st.lists(track, min_size=k, max_size=k))).reshape(-1, W, 2)
                 for k in (draw(sizes), draw(sizes), draw(sizes)))


@pytest.mark.slow
@PROP
@given(track_triples(), cutoffs, st.sampled_from([1.0, 2.0]))
def test_track_distance_metric_properties(xyz, c, q):
    x, y, z = (a[0] for a in xyz)
    dxy = track_distance(x, y, c, q)
    assert track_distance(x, x, c, q) == 0.0
    assert dxy == track_distance(y, x, c, q)
    assert 0.0 <= dxy <= c * (1 + 1e-12)
    assert track_distance(x, z, c, q) <= dxy + track_distance(y, z, c, q) + tol(c)


@pytest.mark.slow
@PROP
@given(track_triples(n_tracks=3), cutoffs, orders)
def test_ospa2_metric_properties(xyz, c, p):
    X, Y, Z = xyz
    dxy = ospa2(X, Y, c, p)
    assert ospa2(X, X, c, p).total == 0.0
    assert dxy.total == pytest.approx(ospa2(Y, X, c, p).total, rel=1e-12, abs=tol(c) * 1e-3)
    assert 0.0 <= dxy.total <= c * (1 + 1e-12)
    if p == 1.0:
        assert dxy.total == dxy.localisation + dxy.cardinality
    assert ospa2(X, Z, c, p).total <= dxy.total + ospa2(Y, Z, c, p).total + tol(c)


@pytest.mark.slow
@PROP
@given(point_sets, point_sets, cutoffs, orders)
def test_ospa2_single_scan_equals_ospa(X, Y, c, p):
    r2 = ospa2(X[:, None, :], Y[:, None, :], c, p)
    r = ospa(X, Y, c, p)
    for a, b in zip(dataclasses.astuple(r2), dataclasses.astuple(r)):
        assert a == pytest.approx(b, rel=1e-9, abs=tol(c))


# --------------------------------------------------------------------------- crossings


def _crossing_run(labels_a, labels_b, *, K=21, lost_b_at=()):
    """Two objects crossing at scan 11 (x = 10 * (k - 11), y = +-5 (k - 11)); tracks sit 3 m
    off each object and carry ``labels_a[k-1]`` / ``labels_b[k-1]``; object b's track is
    missing at the scans in ``lost_b_at``."""
    true, est = [], []
    for k in range(1, K + 1):
        pa = np.array([10.0 * (k - 11), 5.0 * (k - 11)])
        pb = np.array([10.0 * (k - 11), -5.0 * (k - 11)])
        true.append({"A": pa, "B": pb})
        scan = {labels_a[k - 1]: pa + [0.0, 3.0]}
        if k not in lost_b_at:
            scan[labels_b[k - 1]] = pb + [0.0, -3.0]
        est.append(scan)
    return true, est


def test_crossing_label_keeping_kept_swapped_lost():
    from bnptrack.sinks.crossings import crossing_label_keeping

    K = 21
    true, est = _crossing_run(["t1"] * K, ["t2"] * K)
    res = crossing_label_keeping(true, est, [("A", "B", 11)])
    p = res.pairs[0]
    assert res.fraction_kept == 1.0 and p.kept
    assert (p.before, p.after) == (6, 16)
    assert p.labels_before == ("t1", "t2") and p.labels_after == ("t1", "t2")
    # swapped after the crossing: the track labelled t2 follows A from scan 12 on
    swap_a = ["t1"] * 11 + ["t2"] * 10
    swap_b = ["t2"] * 11 + ["t1"] * 10
    res = crossing_label_keeping(*_crossing_run(swap_a, swap_b), [("A", "B", 11)])
    assert res.fraction_kept == 0.0
    assert res.pairs[0].labels_after == ("t2", "t1") and not res.pairs[0].kept
    # B's track missing at scan 16 (c + 5): not kept, B unassigned there
    res = crossing_label_keeping(*_crossing_run(["t1"] * K, ["t2"] * K, lost_b_at=(16,)),
                                 [("A", "B", 11)])
    assert res.pairs[0].labels_after == ("t1", None) and res.fraction_kept == 0.0
    # lost only at the crossing scan itself: still kept (only c -+ 5 are checked)
    res = crossing_label_keeping(*_crossing_run(["t1"] * K, ["t2"] * K, lost_b_at=(11,)),
                                 [("A", "B", 11)])
    assert res.fraction_kept == 1.0
    # a new label for B after the crossing (track restarted): not kept
    res = crossing_label_keeping(*_crossing_run(["t1"] * K, ["t2"] * 11 + ["t9"] * 10),
                                 [("A", "B", 11)])
    assert res.pairs[0].labels_after == ("t1", "t9") and not res.pairs[0].kept


def test_crossing_label_keeping_gate_clipping_and_fraction():
    from bnptrack.sinks.crossings import crossing_label_keeping

    K = 21
    true, est = _crossing_run(["t1"] * K, ["t2"] * K)
    # gate below the 3 m offset: nothing is assigned, not kept
    res = crossing_label_keeping(true, est, [("A", "B", 11)], gate=2.0)
    assert res.pairs[0].labels_before == (None, None) and res.fraction_kept == 0.0
    # clipping to both lifetimes: B present only from scan 9 (c - 2) -> checked at 9 and 16
    true2 = [dict(s) for s in true]
    for k in range(1, 9):
        del true2[k - 1]["B"]
    p = crossing_label_keeping(true2, est, [("A", "B", 11)]).pairs[0]
    assert (p.before, p.after) == (9, 16) and p.kept
    # first_scan shifts the numbering; two pairs, one kept, one swapped -> 0.5
    swap = crossing_label_keeping(*_crossing_run(["t1"] * 11 + ["t2"] * 10,
                                                 ["t2"] * 11 + ["t1"] * 10), [("A", "B", 11)])
    assert swap.fraction_kept == 0.0
    t3 = [{**s, "C": s["A"] + [0.0, 500.0], "D": s["B"] + [0.0, -500.0]} for s in true]
    e3 = [{**s, "u": t3[k]["C"], "v": t3[k]["D"] if k < 13 else t3[k]["C"] + [0, 1e3]}
          for k, s in enumerate(est)]
    res = crossing_label_keeping(t3, e3, [("A", "B", 111), ("C", "D", 111)], first_scan=101)
    assert [p.kept for p in res.pairs] == [True, False] and res.fraction_kept == 0.5
    assert res.pairs[1].labels_after == ("u", None)
    assert math.isnan(crossing_label_keeping(true, est, []).fraction_kept)
    with pytest.raises(ValueError, match="outside"):
        crossing_label_keeping(true, est, [("A", "B", 30)])
    with pytest.raises(ValueError, match="never present"):
        crossing_label_keeping(true, est, [("A", "Z", 11)])
    with pytest.raises(ValueError, match="scans"):
        crossing_label_keeping(true, est[:-1], [("A", "B", 11)])
