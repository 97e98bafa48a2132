"""Scenarios (ground truth of the simulation study) and the seeded measurement generator."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import linear_sum_assignment

from bnptrack.sources.scenarios import (
    PROXIMITY_PATH_START,
    SCENARIOS,
    Scenario,
    TargetSpec,
    get_scenario,
)
from bnptrack.sources.synthetic import measurement_frame_rng, simulate, simulate_all, simulate_frame
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.models.measurement import wrap_angle
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import Frame, Truth

VO = get_scenario("vo2017")
CLEAN = ["clutter_rate=0", "range_clutter_rate=0", "p_detect=1"]


def _target_states(scenario: Scenario, tid: str) -> tuple[np.ndarray, np.ndarray]:
    """(scans, states) of one target over its lifetime."""
    j = scenario.ids.index(tid)
    spec = scenario.targets[j]
    states = scenario.states()[spec.birth - 1 : spec.death, j]
    return np.arange(spec.birth, spec.death + 1), states


def _frames_equal(a: Frame, b: Frame) -> bool:
    return (
        a.frame == b.frame
        and a.stamp_ns == b.stamp_ns
        and a.sensor == b.sensor
        and a.kind == b.kind
        and np.array_equal(a.z, b.z)
        and a.truth.ids == b.truth.ids
        and np.array_equal(a.truth.states, b.truth.states)
    )


# ------------------------------------------------------------------------------------
# vo2017 ground truth: the spec's check values
# ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "tid, at_birth, last",
    [
        ("T1", [993.89, -9.96, 1478.23, -10.04, 0.004363], (250.0, 305.0)),
        ("T4", [-1457.00, 43.00, 250.00, 0.00, 0.0], (951.0, 250.0)),
        ("T8", [200.00, -50.00, 750.22, 0.44, -0.008727], (-1756.5, 1112.8)),
        ("T10", [209.89, -40.22, 774.83, 24.65, 0.008727], (-1536.7, 1463.0)),
    ],
)
def test_vo2017_check_values(tid, at_birth, last):
    _, states = _target_states(VO, tid)
    np.testing.assert_allclose(states[0, :4], at_birth[:4], atol=0.005 + 1e-9)
    np.testing.assert_allclose(states[0, 4], at_birth[4], atol=5e-7)
    np.testing.assert_allclose(states[-1, [0, 2]], last, atol=0.1)


def test_vo2017_truth_list_layout():
    truth = VO.truth()
    assert len(truth) == VO.K == 100
    assert all(isinstance(t, Truth) for t in truth)
    assert truth[0].ids == ("T1",)
    assert truth[0].states.shape == (1, 5)
    # index i holds scan i + 1: T1's state at scan 1 is f(xstart)
    np.testing.assert_allclose(truth[0].states[0, 0], 993.889448, atol=1e-5)
    assert truth[9].ids == ("T1", "T2", "T3", "T4")
    assert truth[99].ids == ("T1", "T2", "T3", "T6", "T7", "T9", "T10")
    assert VO.ids == tuple(f"T{i}" for i in range(1, 11))


def test_vo2017_cardinality_profile():
    expected = np.empty(100, dtype=int)
    for (a, b), n in {
        (1, 9): 1,
        (10, 19): 4,
        (20, 39): 5,
        (40, 59): 8,
        (60, 66): 10,
        (67, 80): 9,
        (81, 100): 7,
    }.items():
        expected[a - 1 : b] = n
    card = VO.cardinality()
    assert card.shape == (100,)
    np.testing.assert_array_equal(card, expected)
    assert card.sum() == 645
    assert [len(t.ids) for t in VO.truth()] == list(expected)


def test_vo2017_targets_8_9_10_leave_range_and_are_not_detected():
    params = load_params("vo2017", CLEAN)
    det = params.detection()
    states = VO.states()
    r = np.hypot(states[..., 0], states[..., 2])  # (K, n), NaN when absent
    with np.errstate(invalid="ignore"):
        out = r > params.range_max
    # only targets 8, 9, 10 ever leave the range, and only near the end
    leavers = {VO.ids[j] for j in np.nonzero(out.any(axis=0))[0]}
    assert leavers == {"T8", "T9", "T10"}
    for tid in ("T8", "T9", "T10"):
        j = VO.ids.index(tid)
        spec = VO.targets[j]
        assert r[spec.birth - 1, j] < params.range_max
        assert r[spec.death - 1, j] > params.range_max
        first_out = np.nonzero(out[:, j])[0][0] + 1
        assert first_out >= 75
        assert out[first_out - 1 : spec.death, j].all()  # stays out once it has left

    frames = simulate_all(VO, params, seed=3)
    n_out = 0
    for f in frames:
        visible = det.prob(f.truth.states) > 0
        r_true = np.hypot(f.truth.states[:, 0], f.truth.states[:, 2])
        np.testing.assert_array_equal(visible, r_true <= params.range_max)
        n_out += int((~visible).sum())
        # the out-of-range targets still count in the truth but give no measurement
        assert f.n_measurements == int(visible.sum())
        if f.n_measurements:
            sig = params.measurement().sigma_range
            assert f.z[:, 1].max() < params.range_max + 5 * sig
    assert n_out == int(np.nansum(out))
    assert n_out > 0


# ------------------------------------------------------------------------------------
# other scenarios
# ------------------------------------------------------------------------------------
def test_registry_and_error():
    assert set(SCENARIOS) == {"vo2017", "dpy5", "proximity", "snr"}
    for name, sc in SCENARIOS.items():
        assert get_scenario(name) is sc
        assert sc.K == 100
        assert len(sc.truth()) == 100
    with pytest.raises(ConfigError) as info:
        get_scenario("nope")
    for name in SCENARIOS:
        assert name in str(info.value)


def test_dpy5_is_targets_1_to_5():
    dpy = get_scenario("dpy5")
    assert dpy.targets == VO.targets[:5]
    assert dpy.kind == "bearing_range"
    np.testing.assert_array_equal(dpy.states(), VO.states()[:, :5])
    assert dpy.cardinality().max() == 5


def test_proximity_same_path():
    prox = get_scenario("proximity")
    assert len(prox.targets) == 5
    assert [(t.birth, t.death) for t in prox.targets] == [
        (1, 70),
        (5, 100),
        (20, 100),
        (30, 45),
        (40, 80),
    ]
    states = prox.states()
    paths = [_target_states(prox, t.id)[1] for t in prox.targets]
    for p in paths:
        np.testing.assert_allclose(p[0], PROXIMITY_PATH_START, atol=1e-9)
    # at their own relative time all targets are at the same state
    for a in paths:
        for b in paths:
            n = min(len(a), len(b))
            np.testing.assert_allclose(a[:n], b[:n], atol=1e-8)
    # the longest-lived target covers the path the others use
    assert max(len(p) for p in paths) == 96
    # and they are at different places at the same time (distinct while both present)
    pres = prox.presence()
    for i in range(5):
        for j in range(i + 1, 5):
            both = pres[:, i] & pres[:, j]
            d = np.hypot(*(states[both, i][:, [0, 2]] - states[both, j][:, [0, 2]]).T)
            assert d.min() > 50.0
    # inside the sensor field of view (range < 2000 m, bearing in (-90, 90) deg)
    pos = states[pres][:, [0, 2]]
    assert np.hypot(pos[:, 0], pos[:, 1]).max() < 2000.0
    assert pos[:, 1].min() > 0.0
    # a gentle constant turn
    assert np.all(states[pres][:, 4] == PROXIMITY_PATH_START[4])


def test_snr_scenario():
    snr = get_scenario("snr")
    assert snr.kind == "range"
    assert snr.default_snr_db == -3.0
    assert len(snr.targets) == 11
    assert np.all(np.array([t.xstart[4] for t in snr.targets]) == 0.0)
    card = snr.cardinality()
    assert card.min() < card.max() == 11
    for t in snr.targets:
        scans, st = _target_states(snr, t.id)
        assert 70 <= t.death <= 100
        np.testing.assert_array_equal(st[:, 4], 0.0)
        # straight line at constant velocity
        np.testing.assert_allclose(st[:, [1, 3]], st[:1, [1, 3]].repeat(len(st), 0), atol=1e-12)
        rel = (scans - scans[0])[:, None]
        np.testing.assert_allclose(st[:, [0, 2]], st[0, [0, 2]] + rel * st[0, [1, 3]], atol=1e-8)
        r = np.hypot(st[:, 0], st[:, 2])
        assert 0.0 < r.min() and r.max() < 2000.0
        assert st[:, 2].min() > 0.0  # inside the +-90 deg field used by the detection model
        r0 = np.hypot(st[0, 0], st[0, 2])
        speed = np.hypot(st[0, 1], st[0, 3])
        assert 300.0 <= r0 <= 1800.0
        assert 5.0 <= speed <= 25.0

    params = load_params("vo2017")
    frames = simulate_all(snr, params, seed=7)
    assert all(f.kind == "range" and f.z.ndim == 2 and f.z.shape[1] == 1 for f in frames)
    assert [len(f.truth.ids) for f in frames] == list(card)


def test_adapt_params():
    snr = get_scenario("snr")
    p = load_params("vo2017")
    assert p.snr_db is None
    assert snr.adapt_params(p).snr_db == -3.0
    assert snr.adapt_params(p).sigma_range == p.sigma_range
    p10 = load_params("vo2017", ["snr_db=-10"])
    assert snr.adapt_params(p10).snr_db == -10.0
    assert VO.adapt_params(p).birth == get_scenario("dpy5").adapt_params(p).birth  # Vo's regions


def test_scenario_birth_regions_replace_the_parameter_sets():
    p = load_params("vo2017")
    prox = get_scenario("proximity").adapt_params(p)
    assert len(prox.birth) == 1 and prox.birth[0].mean[0] == -900.0 and prox.birth[0].mean[2] == 600.0
    snr = get_scenario("snr").adapt_params(p)
    starts = get_scenario("snr").states()[get_scenario("snr").births - 1, np.arange(11)]
    assert len(snr.birth) == 11
    np.testing.assert_allclose([[b.mean[0], b.mean[2]] for b in snr.birth], starts[:, [0, 2]])
    vo = get_scenario("dpy5").adapt_params(p)
    assert [b.r for b in vo.birth] == [0.02, 0.02, 0.03, 0.03]
    assert [(b.mean[0], b.mean[2]) for b in vo.birth] == [(-1500, 250), (-250, 1000), (250, 750), (1000, 1500)]
    assert vo.birth[0].std == [50.0, 50.0, 50.0, 50.0, pytest.approx(np.deg2rad(6.0))]


def test_target_spec_validation():
    with pytest.raises(ValueError):
        TargetSpec("X", (0.0, 0.0, 0.0, 0.0), 1, 2)
    with pytest.raises(ValueError):
        TargetSpec("X", (0.0,) * 5, 5, 4)
    with pytest.raises(ValueError):
        Scenario("s", "", K=10, targets=(TargetSpec("X", (0.0,) * 5, 1, 11),))


# ------------------------------------------------------------------------------------
# generator
# ------------------------------------------------------------------------------------
def test_frame_fields():
    params = load_params("vo2017")
    frames = list(simulate(VO, params, seed=1, sensor="radar9"))
    assert [f.frame for f in frames] == list(range(1, 101))
    assert [f.stamp_ns for f in frames] == [k * 10**9 for k in range(1, 101)]
    assert all(f.sensor == "radar9" and f.kind == "bearing_range" for f in frames)
    assert all(f.z.shape[1] == 2 for f in frames)
    truth = VO.truth()
    for f, t in zip(frames, truth, strict=True):
        assert f.truth.ids == t.ids
        np.testing.assert_array_equal(f.truth.states, t.states)
    z = np.concatenate([f.z for f in frames])
    assert np.all((z[:, 0] >= -np.pi) & (z[:, 0] < np.pi))


def test_same_seed_same_frames_different_seed_different():
    params = load_params("vo2017")
    a = simulate_all(VO, params, seed=11)
    b = simulate_all(VO, params, seed=11)
    c = simulate_all(VO, params, seed=12)
    assert all(_frames_equal(x, y) for x, y in zip(a, b, strict=True))
    assert sum(not _frames_equal(x, y) for x, y in zip(a, c, strict=True)) == len(a)


def test_frame_alone_equals_frame_in_run():
    params = load_params("vo2017")
    run = simulate_all(VO, params, seed=5)
    for k in (1, 37, 64, 100):
        assert _frames_equal(simulate_frame(VO, params, 5, k), run[k - 1])
    late = simulate_all(VO, params, seed=5, start_frame=64)
    assert late[0].frame == 64 and len(late) == 37
    assert all(_frames_equal(x, y) for x, y in zip(late, run[63:], strict=True))


def test_determinism_pin():
    """First measurement of frame 1 of vo2017, seed 1 (catches changes of the random stream)."""
    f = simulate_frame(VO, load_params("vo2017"), seed=1, k=1)
    assert f.n_measurements == 12
    np.testing.assert_allclose(f.z[0], [-0.5320118006635921, 679.6565435190205], rtol=1e-12)
    # the stream itself
    assert measurement_frame_rng(1, 1).integers(0, 2**31) == np.random.default_rng(
        np.random.SeedSequence(1, spawn_key=(1,))
    ).integers(0, 2**31)


def test_clean_measurements_match_truth():
    params = load_params("vo2017", CLEAN)
    meas = params.measurement()
    sig = np.array([meas.sigma_bearing, meas.sigma_range])
    det = params.detection()
    for seed in (1, 2):
        for f in simulate(VO, params, seed):
            visible = f.truth.states[det.prob(f.truth.states) > 0]
            assert f.n_measurements == len(visible)
            if not len(visible):
                continue
            zp = meas.h(visible)
            res = f.z[:, None, :] - zp[None, :, :]
            res[..., 0] = wrap_angle(res[..., 0])
            nres = np.abs(res) / sig
            rows, cols = linear_sum_assignment(nres.max(axis=-1))
            assert nres[rows, cols].max() < 5.0


def _single_target(kind: str) -> Scenario:
    """A one-target straight-line scenario (no association needed for noise statistics)."""
    return Scenario(
        "one",
        "one target",
        K=100,
        kind=kind,
        targets=(TargetSpec("A", (-500.0, 5.0, 800.0, 2.0, 0.0), 1, 100),),
    )


def _residuals(scenario: Scenario, params, seeds) -> np.ndarray:
    meas = params.measurement(scenario.kind)
    out = []
    for seed in seeds:
        for f in simulate(scenario, params, seed):
            assert f.n_measurements == 1
            r = f.z - meas.h(f.truth.states)
            if scenario.kind == "bearing_range":
                r[:, 0] = wrap_angle(r[:, 0])
            out.append(r)
    return np.concatenate(out)


#: The measurement kinds of the statistical checks below (thousands of simulated scans each):
#: the fast subset checks ``bearing_range`` (its last column is the range); ``range`` is marked slow.
STAT_KINDS = ["bearing_range", pytest.param("range", marks=pytest.mark.slow)]


@functools.lru_cache(maxsize=None)
def _clean_residuals(kind: str, *overrides: str) -> np.ndarray:
    """The residuals of 30 seeds of :func:`_single_target` under the CLEAN parameters (and
    ``overrides``): computed once for the tests that read them (read-only)."""
    res = _residuals(_single_target(kind), load_params("vo2017", CLEAN + list(overrides)), range(30))
    res.flags.writeable = False
    return res


@pytest.mark.parametrize("kind", STAT_KINDS)
def test_detection_noise_std(kind):
    res = _clean_residuals(kind)  # 3000 samples: 1.3% s.e.
    sig = [np.deg2rad(2.0), 10.0] if kind == "bearing_range" else [10.0]
    np.testing.assert_allclose(res.std(axis=0), sig, rtol=0.05)
    assert np.all(np.abs(res.mean(axis=0)) < 4 * np.array(sig) / np.sqrt(len(res)))


@pytest.mark.parametrize("kind", STAT_KINDS)
def test_snr_scales_noise_variance(kind):
    nominal = _clean_residuals(kind).std(axis=0)
    low = _clean_residuals(kind, "snr_db=-10").std(axis=0)
    # variance x 10**(10/10) = 10, std x sqrt(10)
    np.testing.assert_allclose(low / nominal, np.sqrt(10.0), rtol=0.08)


def test_snr_scenario_uses_default_snr():
    snr = get_scenario("snr")
    params = load_params("vo2017", CLEAN)
    meas = snr.adapt_params(params).measurement("range")
    np.testing.assert_allclose(meas.sigma_range, 10.0 * np.sqrt(10 ** 0.3))
    res = []
    for f in (f for seed in range(10) for f in simulate(snr, params, seed)):
        # range-only: match sorted measurements to sorted predicted ranges when well separated
        zp = np.sort(meas.h(f.truth.states)[:, 0])
        z = np.sort(f.z[:, 0])
        assert len(z) == len(zp)
        if len(zp) > 1 and np.diff(zp).min() < 10 * meas.sigma_range:
            continue
        res.append(z - zp)
    res = np.concatenate(res)
    assert len(res) > 300
    assert 0.85 < res.std() / meas.sigma_range < 1.15


@pytest.mark.parametrize("kind", STAT_KINDS)
def test_clutter_statistics(kind):
    params = load_params("vo2017", ["p_detect=0"])
    frames = [f for seed in range(20) for f in simulate(_single_target(kind), params, seed)]
    counts = np.array([f.n_measurements for f in frames])
    rate = params.clutter_rate
    se = np.sqrt(rate / len(counts))
    assert abs(counts.mean() - rate) < 4 * se
    assert 0.8 < counts.var() / rate < 1.2  # Poisson dispersion
    z = np.concatenate([f.z for f in frames])
    r = z[:, -1]
    assert stats.kstest(r, "uniform", args=(0.0, params.range_max)).pvalue > 1e-3
    if kind == "bearing_range":
        assert stats.kstest(z[:, 0], "uniform", args=(-np.pi / 2, np.pi)).pvalue > 1e-3


def test_measurement_order_is_shuffled():
    """Target detections are not always first: order carries no information."""
    params = load_params("vo2017", ["p_detect=1", "clutter_rate=15"])
    sc = _single_target("bearing_range")
    meas = params.measurement()
    positions = []
    for f in simulate(sc, params, seed=9):
        d = np.abs(f.z[:, 1] - meas.h(f.truth.states)[0, 1])
        positions.append(int(np.argmin(d)) / max(f.n_measurements - 1, 1))
    positions = np.array(positions)
    assert 0.3 < positions.mean() < 0.7
    assert (positions == 0).mean() < 0.3


def test_snr_scenario_range_clutter_default_and_override():
    """The snr scenario sets 2 range-only clutter returns per scan unless the user set a rate;
    bearing-range clutter is untouched."""
    import msgspec

    from bnptrack.tracker.models.params import load_params

    sc = get_scenario("snr")
    p = sc.adapt_params(load_params("vo2017"))
    assert p.clutter("range").rate == 2.0
    assert p.clutter("bearing_range").rate == 15.0
    mine = sc.adapt_params(msgspec.structs.replace(load_params("vo2017"), range_clutter_rate=7.0))
    assert mine.clutter("range").rate == 7.0
    assert get_scenario("vo2017").adapt_params(load_params("vo2017")).clutter("range").rate == 15.0


# --------------------------------------------------------------------------- open_scenario


def test_open_scenario_applies_overrides_snr_and_scenario_defaults_once():
    """One function opens a scenario.  snr: the --set item, the scenario's
    -3 dB, 2 range clutter per scan and its 11 entry points; the record holds them."""
    from bnptrack.sources.scenarios import open_scenario

    o = open_scenario("snr", "vo2017", 1, ("p_detect=0.9",))
    assert o.scenario is get_scenario("snr")
    assert (o.params.p_detect, o.params.snr_db, o.params.range_clutter_rate) == (0.9, -3.0, 2.0)
    assert len(o.params.birth) == 11
    assert o.metadata == {"scenario": "snr", "params": "vo2017", "seed": "1", "snr_db": "-3.0",
                          "overrides": "p_detect=0.9"}
    # --snr wins over the scenario's default; the generated family: scene.* items build the scene
    o = open_scenario("random", "vo2017", 3, ("scene.n_objects=9", "clutter_rate=5"), snr_db=-2)
    assert (o.params.snr_db, o.params.clutter_rate, o.params.birth) == (-2.0, 5.0, [])
    assert len(o.scenario.targets) == 9 and o.scenario.seed == 3
    assert o.metadata == {"scenario": "random", "params": "vo2017", "seed": "3", "snr_db": "-2.0",
                          "overrides": "clutter_rate=5", "scene_seed": "3", "scene": "n_objects=9",
                          "crossings": "T8,T5,75;T1,T3,37;T6,T2,55"}
    with pytest.raises(ConfigError, match="scene"):
        open_scenario("vo2017", "vo2017", 1, ("scene.n_objects=9",))
