"""Sensor geometry as data, Cartesian detections, several sensors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bnptrack.tracker.messages import TOPIC_MEASUREMENTS, decode, encode, to_frame
from bnptrack.sinks.metrics import ospa
from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import move_truth, simulate_all, simulate_sensors, truth_at_time
from bnptrack.tracker.bnp.base_measure import BaseDistribution
from bnptrack.tracker.bnp import make_tracker
from bnptrack.tracker.config import apply_overrides
from bnptrack.tracker.models.clutter import SectorClutter
from bnptrack.tracker.models.measurement import KINDS, BearingRange, Cartesian, RangeOnly
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.state import run
from bnptrack.tracker.types import Frame, Truth

POSE = (1500.0, -700.0, float(np.deg2rad(40.0)))


def _world(pose, b, r):
    """World position of bearing b (from the boresight) and range r seen from pose."""
    x, y, h = pose
    return np.array([x + r * np.sin(h + b), y + r * np.cos(h + b)])


def test_bearing_measured_from_the_boresight():
    m = BearingRange(np.deg2rad(2.0), 10.0, *POSE)
    p = _world(POSE, np.deg2rad(10.0), 800.0)
    x = np.array([[p[0], 3.0, p[1], -1.0, 0.0]])
    np.testing.assert_allclose(m.h(x), [[np.deg2rad(10.0), 800.0]], rtol=1e-12)
    pos, cov = m.to_cartesian(m.h(x))
    np.testing.assert_allclose(pos[0], p, rtol=1e-12)
    # the covariance rotates with the heading: the range axis lies along the line of sight
    u = (p - POSE[:2]) / 800.0
    assert u @ cov[0] @ u == pytest.approx(100.0, rel=1e-9)
    # behind the sensor the wrapped bearing is near +-180 deg
    q = _world(POSE, np.deg2rad(179.0), 500.0)
    assert abs(m.h(np.array([[q[0], 0, q[1], 0, 0]]))[0, 0]) == pytest.approx(np.deg2rad(179.0), rel=1e-9)


def test_default_sensor_is_todays():
    p = load_params("vo2017")
    assert p.measurement("bearing_range") == BearingRange(np.deg2rad(2.0), 10.0)
    assert p.measurement("range") == RangeOnly(10.0, half_fov=float(np.deg2rad(90.0)))
    c = p.clutter("bearing_range")
    assert c.low == (-np.pi / 2, 0.0) and c.high == (np.pi / 2, 2000.0)


def _sensor_params(tmp_path, body):
    f = tmp_path / "p.toml"
    f.write_text('name = "mine"\n' + body)
    return load_params(str(f))


def test_sensor_table_pose_fov_noise(tmp_path):
    p = _sensor_params(tmp_path, """
[sensors.radar0]
kind = "bearing_range"
x = 1500.0
y = -700.0
heading_deg = 40.0
range_min = 100.0
range_max = 1500.0
half_fov_deg = 45.0
sigma_range = 5.0
clutter_rate = 3.0
""")
    s = p.sensor("radar0", "bearing_range")
    assert (s.x, s.y) == (1500.0, -700.0) and s.heading == pytest.approx(np.deg2rad(40.0))
    assert s.half_fov == pytest.approx(np.pi / 4) and s.range_min == 100.0 and s.range_max == 1500.0
    assert s.sigma_range == 5.0 and s.sigma_bearing == pytest.approx(np.deg2rad(2.0))
    c = p.clutter("bearing_range", s)
    assert c.volume == pytest.approx((np.pi / 2) * 1400.0) and c.rate == 3.0
    d = p.detection("bearing_range", s)
    inside = _world(s.pose, np.deg2rad(30.0), 1000.0)
    wide = _world(s.pose, np.deg2rad(60.0), 1000.0)
    near = _world(s.pose, 0.0, 50.0)
    X = np.array([[inside[0], 0, inside[1], 0, 0], [wide[0], 0, wide[1], 0, 0], [near[0], 0, near[1], 0, 0]])
    np.testing.assert_array_equal(d.visible(X), [True, False, False])
    # survival: p_survival inside the sensor's field of view, p_survival_outside elsewhere
    np.testing.assert_allclose(p.survival(X, "bearing_range", s), [0.99, 0.7, 0.7])
    # a frame's pose and R win over the table
    f = Frame(1, 0, "radar0", "bearing_range", np.zeros((0, 2)), pose=(0.0, 0.0, 0.0), R=np.diag([1e-4, 4.0]))
    s2 = p.frame_sensor(f)
    assert s2.pose == (0.0, 0.0, 0.0) and p.measurement("bearing_range", s2).R[1, 1] == 4.0
    with pytest.raises(ValueError, match="declared kind 'bearing_range'"):
        p.sensor("radar0", "xy")


def test_xy_model_and_sector_clutter():
    m = Cartesian(10.0)
    x = np.array([[3.0, 1.0, -4.0, 2.0, 0.1]])
    np.testing.assert_array_equal(m.h(x), [[3.0, -4.0]])
    np.testing.assert_array_equal(m.jacobian(x)[0], [[1, 0, 0, 0, 0], [0, 0, 1, 0, 0]])
    assert m.logpdf(np.array([[3.0, -4.0]]), x)[0] == pytest.approx(-np.log(2 * np.pi * 100.0))
    assert KINDS["xy"].dim == 2 and KINDS["xy"].model is Cartesian and KINDS["xy"].wrapped == ()
    c = SectorClutter(5.0, 100.0, 1000.0, np.pi / 4, *POSE)
    assert c.volume == pytest.approx(np.pi / 4 * (1000.0**2 - 100.0**2))
    z = c.sample(np.random.default_rng(0))
    assert np.isfinite(c.logpdf(z)).all()
    assert c.logpdf(np.array([[0.0, 0.0]]))[0] == -np.inf
    # uniform in area: the mean squared range is (r1^2 + r2^2) / 2
    big = SectorClutter(20000.0, 100.0, 1000.0, np.pi / 4, *POSE).sample(np.random.default_rng(1))
    r2 = np.sum((big - np.array(POSE[:2])) ** 2, axis=1)
    assert r2.mean() == pytest.approx((100.0**2 + 1000.0**2) / 2, rel=0.02)


def test_birth_from_posed_sensor():
    base = BaseDistribution(np.zeros(0), np.zeros((0, 5)), np.zeros((0, 5, 5)), 1.0, 30.0, 0.05, np.pi / 2)
    z = np.array([[np.deg2rad(-20.0), 700.0]])
    mean, cov = base._uniform_posterior(BearingRange(np.deg2rad(2.0), 10.0, *POSE), z, "bearing_range")
    np.testing.assert_allclose(mean[0, [0, 2]], _world(POSE, np.deg2rad(-20.0), 700.0), rtol=1e-12)
    assert cov[0, 1, 1] == 900.0 and mean[0, 1] == 0.0
    mean, cov = base._uniform_posterior(Cartesian(10.0), np.array([[5.0, 6.0]]), "xy")
    np.testing.assert_array_equal(mean[0], [5.0, 0.0, 6.0, 0.0, 0.0])
    assert cov[0, 0, 0] == cov[0, 2, 2] == 100.0
    # range-only: on the boresight at the measured range
    mean, _ = base._uniform_posterior(RangeOnly(10.0, *POSE[:2], np.pi / 2, POSE[2]), np.array([[600.0]]), "range")
    np.testing.assert_allclose(mean[0, [0, 2]], _world(POSE, 0.0, 600.0), rtol=1e-12)


def test_codec_pose_r_xy_roundtrip():
    f = Frame(3, 3_000_000_000, "cam", "xy", [[10.0, -20.0], [1e3, 5.5]], pose=POSE, R=np.diag([4.0, 9.0]))
    raw = encode(f)
    obj = json.loads(raw)
    assert obj["v"] == 2 and obj["pose"] == list(POSE) and obj["R"] == [[4.0, 0.0], [0.0, 9.0]]
    g = to_frame(decode(TOPIC_MEASUREMENTS, raw))
    assert g.kind == "xy" and g.pose == POSE and np.array_equal(g.R, f.R) and np.array_equal(g.z, f.z)
    plain = json.loads(encode(Frame(3, 0, "r", "bearing_range", [[0.1, 5.0]])))
    assert plain["v"] == 1 and "pose" not in plain and "R" not in plain
    with pytest.raises(ValueError, match="R must be a finite 2x2"):
        Frame(1, 0, "c", "xy", [[0.0, 0.0]], R=np.eye(3))


def _posed_frames(n_frames, kind, pose, sigma_xy=10.0):
    """vo2017 seed 1 measured by a sensor at ``pose`` with the truth moved along."""
    from bnptrack.sources.synthetic import measurement_frame_rng, measure_with

    sc = get_scenario("vo2017")
    p = load_params("vo2017")
    p = apply_overrides(p, [f"sensors.s.kind='{kind}'", f"sensors.s.x={pose[0]}", f"sensors.s.y={pose[1]}",
                            f"sensors.s.heading_deg={np.rad2deg(pose[2])}", f"sigma_xy={sigma_xy}"])
    pa = sc.adapt_params(p)
    frames = []
    for k, tr in enumerate(sc.truth(1.0)[:n_frames], start=1):
        moved = move_truth(tr, pose)
        z, kd, ps = measure_with(measurement_frame_rng(1, k), moved, pa, "bearing_range", "s")
        frames.append(Frame(k, k * 10**9, "s", kd, z, moved, pose=ps))
    return frames, pa


def _mean_ospa(params, frames):
    tr = make_tracker("ddp-mb", params)
    d = []
    for f, est, _ in run(tr, frames, seed=2):
        d.append(ospa(f.truth.positions, est.positions).total)
    return float(np.mean(d[10:]))


@pytest.mark.parametrize("kind", ["bearing_range", "xy"])
def test_tracks_from_a_posed_sensor(kind):
    """The same scene seen from (1500, -700, 40 deg): same kind of accuracy as from the origin
    (bearing-range: the same measurements, so the same OSPA up to the moved birth regions)."""
    sc = get_scenario("vo2017")
    p = load_params("vo2017")
    anywhere = ["birth=[]", "birth_rate=0.1"]  # the scene's birth regions are not moved: births anywhere
    plain = _mean_ospa(apply_overrides(sc.adapt_params(p), anywhere), simulate_all(sc, p, 1)[:40])
    frames, pa = _posed_frames(40, kind, POSE)
    posed = _mean_ospa(apply_overrides(pa, anywhere), frames)
    assert posed < 1.25 * plain + 5.0, (posed, plain)
    assert posed < 40.0


def test_truth_at_time_and_move_truth():
    sc = get_scenario("vo2017")
    a, b = sc.truth(1.0)[9], truth_at_time(sc, 10.0)
    np.testing.assert_array_equal(a.states, b.states)
    half = truth_at_time(sc, 10.5)
    from bnptrack.tracker.models.motion import CoordinatedTurn
    np.testing.assert_allclose(half.states, CoordinatedTurn(T=0.5).f(a.states), rtol=1e-12)
    t = Truth(("a",), np.array([[0.0, 0.0, 100.0, 10.0, 0.01]]))
    m = move_truth(t, POSE)
    np.testing.assert_allclose(m.states[0, [0, 2]], _world(POSE, 0.0, 100.0), rtol=1e-12)
    np.testing.assert_allclose(m.states[0, [1, 3]], 10.0 * np.array([np.sin(POSE[2]), np.cos(POSE[2])]), rtol=1e-12)


def test_two_sensors_interleaved_share_one_state():
    sc = get_scenario("vo2017")
    p = apply_overrides(load_params("vo2017"), [
        "sensors.radar.kind='bearing_range'",
        "sensors.cam.kind='xy'", "sensors.cam.x=-1000.0", "sensors.cam.y=2500.0", "sensors.cam.heading_deg=150.0",
        "sensors.cam.range_max=2500.0", "sensors.cam.clutter_rate=5.0"])
    frames = list(simulate_sensors(sc, p, 1, ["radar", "cam"]))[:60]
    assert [f.sensor for f in frames[:4]] == ["radar", "cam", "radar", "cam"]
    assert [f.kind for f in frames[:2]] == ["bearing_range", "xy"] and frames[1].pose[0] == -1000.0
    assert frames[0].stamp_ns == frames[1].stamp_ns and [f.frame for f in frames[:3]] == [1, 2, 3]
    pa = apply_overrides(sc.adapt_params(p), ["birth=[]", "birth_rate=0.1"])  # regions are radar-centred
    tr = make_tracker("ddp-mb", pa)
    labels_by_sensor = {"radar": set(), "cam": set()}
    d = []
    for f, est, _ in run(tr, frames, seed=2):
        labels_by_sensor[f.sensor] |= set(est.labels)
        d.append(ospa(f.truth.positions, est.positions).total)
    # one shared state: the same labels are reported after frames of either sensor
    assert len(labels_by_sensor["radar"] & labels_by_sensor["cam"]) >= 3
    assert np.mean(d[20:]) < 40.0


@pytest.mark.slow  # 200 frames simulated and tracked; the fast subset keeps test_two_sensors_interleaved_share_one_state
def test_cli_simulates_and_tracks_two_sensors(tmp_path):
    """A parameter file with two [sensors.*] tables: `simulate` writes both sensors' frames
    interleaved (poses in the frames), `track` reads them back with the shared state."""
    from click.testing import CliRunner

    from bnptrack.pipeline.cli import main
    from bnptrack.sources.mcap_log import iter_frames

    params = tmp_path / "two.toml"
    params.write_text('name = "two"\n[sensors.radar]\nkind = "bearing_range"\n'
                      '[sensors.cam]\nkind = "xy"\nx = -1000.0\ny = 2500.0\nheading_deg = 150.0\n'
                      'range_max = 2500.0\nclutter_rate = 5.0\n')
    log = tmp_path / "two.mcap"
    res = CliRunner().invoke(main, ["simulate", "--params", str(params), "--seed", "1", "--out", str(log), "-q"])
    assert res.exit_code == 0, res.output
    frames = list(iter_frames(log))
    assert len(frames) == 200 and [f.sensor for f in frames[:2]] == ["radar", "cam"]
    assert frames[1].kind == "xy" and frames[1].pose == (-1000.0, 2500.0, pytest.approx(np.deg2rad(150.0)))
    res = CliRunner().invoke(main, ["track", str(log), "--tracker", "ddp", "--out", str(tmp_path / "t.mcap")])
    assert res.exit_code == 0, res.output
    ospa_m = float(res.output.split("mean OSPA")[1].split()[0])
    assert ospa_m < 20.0, res.output
