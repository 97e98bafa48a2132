"""Conventions of the Stone Soup comparison (benchmarks/vs_stonesoup.py) without Stone Soup.

The helpers are pure numpy; the Stone Soup side is checked by ``vs_stonesoup.py --selftest``
(the ``compare`` extra is optional, so it is not part of this suite).
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.anchor_convert import (
    JpdaSettings,
    PhdSettings,
    adaptive_birth_weights,
    birth_gaussians,
    clutter_intensity,
    extract_phd,
    from_stonesoup_bearing,
    position,
    to_stonesoup_bearing,
    to_stonesoup_measurements,
)
from benchmarks.vs_stonesoup import Scan, anchor_settings, score, split_sets, summarise
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import Frame, Truth


def test_bearing_conversion_hand_values():
    # bnptrack: from +y towards +x.  Stone Soup: from +x towards +y.
    b = np.deg2rad([0.0, 30.0, 90.0, -45.0, -90.0])
    want = np.deg2rad([90.0, 60.0, 0.0, 135.0, 180.0])
    got = to_stonesoup_bearing(b)
    np.testing.assert_allclose(np.cos(got - want), 1.0, atol=1e-12)  # same angle mod 2 pi
    assert np.all((got >= -np.pi) & (got < np.pi))


def test_bearing_conversion_matches_both_definitions_and_inverts():
    rng = np.random.default_rng(7)
    p = rng.uniform(-2000, 2000, size=(50, 2))
    b = np.arctan2(p[:, 0], p[:, 1])        # bnptrack's h
    phi = np.arctan2(p[:, 1], p[:, 0])      # Stone Soup's CartesianToBearingRange
    np.testing.assert_allclose(np.cos(to_stonesoup_bearing(b) - phi), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.sin(to_stonesoup_bearing(b) - phi), 0.0, atol=1e-12)
    np.testing.assert_allclose(from_stonesoup_bearing(to_stonesoup_bearing(b)), b, atol=1e-12)


def test_measurement_rows_keep_range_and_order():
    z = np.array([[np.deg2rad(30.0), 1000.0], [0.0, 5.0]])
    out = to_stonesoup_measurements(z)
    np.testing.assert_allclose(out, [[np.deg2rad(60.0), 1000.0], [np.pi / 2, 5.0]], atol=1e-12)


def test_state_order_is_shared():
    np.testing.assert_array_equal(position(np.array([[1.0], [2.0], [3.0], [4.0], [5.0]])), [1.0, 3.0])


def test_clutter_intensity_vo2017():
    # 15 clutter per scan over bearing [-90, 90] deg x range [0, 2000] m
    assert clutter_intensity(load_params("vo2017")) == pytest.approx(15.0 / (np.pi * 2000.0), rel=1e-12)


def test_birth_gaussian_at_a_measurement_straight_ahead():
    params = load_params("vo2017")  # sigma_b = 2 deg, sigma_r = 10 m
    mean, cov = birth_gaussians(np.array([[0.0, 1000.0]]), params, vel_std=20.0, turn_std_deg=2.0)
    np.testing.assert_allclose(mean, [[0.0, 0.0, 1000.0, 0.0, 0.0]], atol=1e-9)
    # J = [[r cos b, sin b], [-r sin b, cos b]] = diag(1000, 1): px var = (1000 * 2 deg)^2, py var = 10^2
    want = np.diag([(1000.0 * np.deg2rad(2.0)) ** 2, 400.0, 100.0, 400.0, np.deg2rad(2.0) ** 2])
    np.testing.assert_allclose(cov[0], want, rtol=1e-12, atol=1e-9)


def test_adaptive_birth_weights_ristic_2012():
    w = adaptive_birth_weights(np.array([0.0, 0.5, 1.0]), birth_rate=0.1)
    np.testing.assert_allclose(w, [0.1 / 1.5, 0.05 / 1.5, 0.0], rtol=1e-12)
    assert w.sum() == pytest.approx(0.1)
    np.testing.assert_array_equal(adaptive_birth_weights(np.ones(3), 0.1), np.zeros(3))


def test_extract_phd_thresholds_and_keeps_tags():
    comps = [("a", 0.9, np.array([1.0, 0, 2.0, 0, 0])), ("b", 0.4, np.zeros(5)), ("c", 0.51, np.ones(5))]
    out = extract_phd(comps, 0.5)
    assert [t for t, _ in out] == ["a", "c"]
    np.testing.assert_array_equal(out[0][1], [1.0, 2.0])


def test_anchor_settings_overrides_and_errors():
    phd, jpda = anchor_settings(("phd.gate=5.5", "jpda.min_points=6"))
    assert phd == PhdSettings(gate=5.5) and jpda == JpdaSettings(min_points=6)
    with pytest.raises(ValueError, match="start with 'phd.' or 'jpda.'"):
        anchor_settings(("gate=5",))
    with pytest.raises(ConfigError, match="unknown key 'nope'"):
        anchor_settings(("phd.nope=1",))
    with pytest.raises(ConfigError):
        anchor_settings(("jpda.min_points=0",))


def test_split_sets():
    assert split_sets(("scene.n_objects=5", "birth=[]")) == (["n_objects=5"], ["birth=[]"])


def _frame(k, ids, pos):
    states = np.zeros((len(ids), 5))
    states[:, [0, 2]] = pos
    return Frame(frame=k, stamp_ns=k * 10**9, sensor="s", kind="bearing_range", z=np.zeros((0, 2)),
                 truth=Truth(tuple(ids), states))


def test_score_hand_computed():
    # one object at (0, 0) for 2 scans; the estimate is 10 m off, then missing (cut-off 100)
    frames = [_frame(1, ["o"], [[0.0, 0.0]]), _frame(2, ["o"], [[0.0, 0.0]])]
    scans = [Scan(("x",), np.array([[10.0, 0.0]]), 2.0), Scan((), np.zeros((0, 2)), 4.0)]
    s = score(frames, scans)
    assert s["ospa"] == pytest.approx((10.0 + 100.0) / 2)
    assert s["card_err"] == pytest.approx(0.5)
    # OSPA(2): window 1 -> 10; window 2: track distance mean(10, 100) = 55
    assert s["ospa2"] == pytest.approx((10.0 + 55.0) / 2)
    assert s["ms"] == [2.0, 4.0] and s["crossing"] == []


def test_summarise_ratio_is_against_the_most_accurate_anchor():
    def r(name, ospa, ms):
        return dict(tracker=name, ospa=ospa, ospa2=ospa, card_err=0.0, switches=0.0, crossing=[True], ms=[ms])

    res = [r("ddp", 20.0, 3.0), r("ss-gmphd", 30.0, 200.0), r("ss-jpda", 35.0, 100.0)]
    out = summarise(res, ["ddp", "ss-gmphd", "ss-jpda"])
    assert out["ddp"]["best_anchor"] == "ss-gmphd"
    assert out["ddp"]["time_vs_best_anchor"] == pytest.approx(3.0 / 200.0)
    assert out["ss-jpda"]["time_vs_best_anchor"] == pytest.approx(0.5)
    assert out["ddp"]["crossing"] == 1.0 and out["ddp"]["crossing_pairs"] == 1


def test_missing_stonesoup_prints_one_line_and_exits(monkeypatch, capsys):
    import importlib.util

    import benchmarks.vs_stonesoup as vs

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "stonesoup" else real(name, *a))
    assert vs.main(["--seeds", "1"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == vs.MISSING and "pip install -e '.[compare]'" in err


def test_lagged_rows_of_a_tracker_are_the_fixed_lag_layer_output():
    from benchmarks.lagged_anchors import lagged_bnp
    from benchmarks.vs_stonesoup import _tiny_scene
    from bnptrack.tracker.lag import FixedLag, run_lagged
    from bnptrack.tracker.registry import build, kind

    params = load_params("vo2017", ["birth=[]"])
    frames = _tiny_scene(params, 8)
    tracker = build("ddp-mb", params, kind("ddp-mb").presets["ddp-mb"])
    scans = lagged_bnp(tracker, params, frames, 3, 2, Scan)
    direct = [e for _f, e, _s in run_lagged(FixedLag(tracker, params, 2), frames, 3)]
    assert len(scans) == len(direct) == 8
    for s, e in zip(scans, direct):
        assert s.labels == e.labels and s.ms >= 0
        np.testing.assert_array_equal(s.positions, np.asarray(e.positions).reshape(-1, 2))
