"""A recording draws each sensor at its pose and each measurement where its sensor saw it: a
radar at (1500, -700) heading 40 deg declared in the parameters, and an ``xy`` lidar at
(3000, 1000) heading -30 deg whose frames carry their own pose (``benchmarks/posed_sensor_logs.py``).  Positions are read back from the ``.rrd``."""

from __future__ import annotations

import os

os.environ.setdefault("CI", "1")  # before `import rerun`: no analytics


import numpy as np  # noqa: E402
import pytest  # noqa: E402

from benchmarks.posed_sensor_logs import LIDAR, RADAR, posed_log  # noqa: E402
from bnptrack.sinks.rerun_sink import write_recording  # noqa: E402
from bnptrack.tracker.bnp import make_tracker  # noqa: E402
from bnptrack.tracker.config import apply_overrides  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402
from testkit import by_frame, read_rrd  # noqa: E402

N_FRAMES = 30






CASES = {
    "radar_params": ("bearing_range", RADAR, False),
    "lidar_frames": ("xy", LIDAR, True),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def recorded(request, tmp_path_factory):
    kind, pose, in_frames = CASES[request.param]
    frames, params = posed_log(kind, pose, pose_in_frames=in_frames, n_frames=N_FRAMES)
    estimates = [e for _f, e, _s in run(make_tracker("ddp-mb", params), frames, 0)]
    path = tmp_path_factory.mktemp("posed") / f"{request.param}.rrd"
    write_recording(path, frames, estimates, {"scenario": request.param}, params=params)
    return pose, frames, estimates, params, read_rrd(path)


def test_sensor_drawn_at_its_pose_and_nothing_at_the_default(recorded):
    pose, _frames, _estimates, _params, contents = recorded
    sensors = [p for p in contents if p.startswith("/world/sensors/")]
    assert sensors == ["/world/sensors/s"]
    assert "/world/sensor" not in contents
    dots = by_frame(contents["/world/sensors/s"], "Points2D:positions")
    assert dots and all(np.allclose(v[0], pose[:2], atol=1e-2) for v in dots.values())
    outline = np.asarray(next(iter(by_frame(contents["/world/sensors/s"], "LineStrips2D:strips").values()))[0])
    # the wedge's apex is the sensor, its far arc 2000 m away, centred on the heading
    np.testing.assert_allclose(outline[0], pose[:2], atol=1e-2)
    far = outline[1:-1] - pose[:2]
    np.testing.assert_allclose(np.hypot(*far.T), 2000.0, rtol=1e-5)
    mid = far[far.shape[0] // 2]
    assert np.arctan2(mid[0], mid[1]) == pytest.approx(pose[2], abs=1e-4)
    assert np.hypot(*outline.T).min() > 100.0  # no part of it at the default sensor's origin


def test_assigned_measurements_lie_on_their_tracks(recorded):
    """Each drawn measurement is the frame's sensor model's ``to_cartesian`` (the tracker's own
    model), and the assigned ones lie within a few sigma of their tracks."""
    _pose, frames, estimates, params, contents = recorded
    pts = by_frame(contents["/world/measurements"], "Points2D:positions")
    d2 = []
    for f, e in zip(frames, estimates):
        model = params.measurement(f.kind, params.frame_sensor(f))
        xy, mcov = model.to_cartesian(f.z)
        np.testing.assert_allclose(pts[f.frame], xy, rtol=1e-6, atol=0.05)
        tracks = {t.label: t for t in e.tracks}
        for m, lab in enumerate(e.assignments):
            if lab is None:
                continue
            t = tracks[lab]
            S = t.covariance[np.ix_([0, 2], [0, 2])] + mcov[m]
            r = np.asarray(pts[f.frame][m]) - t.position
            d2.append(float(r @ np.linalg.solve(S, r)))
    d2 = np.array(d2)
    assert d2.size > 2 * N_FRAMES  # the objects were tracked and their measurements assigned
    assert np.median(np.sqrt(d2)) < 2.0
    assert np.quantile(np.sqrt(d2), 0.95) < 4.0


def test_scene_covers_the_field_of_view_and_the_tracks(recorded):
    pose, _frames, estimates, _params, contents = recorded
    grid = np.asarray(contents["/world/grid"][-1].column("LineStrips2D:strips").to_pylist()[-1], dtype=float)
    lo, hi = grid.reshape(-1, 2).min(axis=0), grid.reshape(-1, 2).max(axis=0)
    outline = np.asarray(next(iter(by_frame(contents["/world/sensors/s"], "LineStrips2D:strips").values()))[0])
    tracks = np.concatenate([e.positions for e in estimates if e.tracks])
    for p in (outline, tracks):
        assert (p >= lo - 1e-6).all() and (p <= hi + 1e-6).all()


def test_several_sensors_each_with_its_colour_and_legend_entry(tmp_path):
    frames, params = posed_log("bearing_range", RADAR, pose_in_frames=False, n_frames=5)
    params = apply_overrides(params, ["sensors.lidar.kind='xy'", f"sensors.lidar.x={LIDAR[0]}",
                                      f"sensors.lidar.y={LIDAR[1]}"])
    estimates = [e for _f, e, _s in run(make_tracker("ddp-mb", params), frames[:5], 0)]
    path = tmp_path / "two.rrd"
    write_recording(path, frames[:5], estimates, {}, params=params)
    c = read_rrd(path)
    colours = {p: by_frame(c[p], "Points2D:colors")[1][0] for p in ("/world/sensors/s", "/world/sensors/lidar")}
    assert len(set(colours.values())) == 2
    lidar = by_frame(c["/world/sensors/lidar"], "Points2D:positions")[1][0]
    np.testing.assert_allclose(lidar, LIDAR[:2], atol=1e-2)
    legend = c["/world/legend/sensors"][-1]
    assert legend.column("Points2D:labels").to_pylist()[-1] == ["sensor s (bearing_range)", "sensor lidar (xy)"]
    assert sorted(legend.column("Points2D:colors").to_pylist()[-1]) == sorted(colours.values())


@pytest.mark.slow  # the recording in a child interpreter
def test_track_rrd_draws_the_params_sensor_pose(tmp_path):
    """``bnptrack track LOG --params FILE --rrd`` (the recording in a child process) resolves
    the sensor from the parameter file as the tracker does: assignment lines stay short."""
    from click.testing import CliRunner

    from benchmarks.posed_sensor_logs import params_toml
    from bnptrack import write_log
    from bnptrack.pipeline.cli import main

    frames, _params = posed_log("bearing_range", RADAR, pose_in_frames=False, n_frames=N_FRAMES)
    log, toml, rrd = tmp_path / "radar.mcap", tmp_path / "radar.toml", tmp_path / "r.rrd"
    write_log(log, frames)
    toml.write_text(params_toml("bearing_range", RADAR))
    res = CliRunner().invoke(main, ["track", str(log), "--params", str(toml), "--rrd", str(rrd),
                                    "--out", str(tmp_path / "t.mcap")])
    assert res.exit_code == 0, res.output
    c = read_rrd(rrd)
    assert [p for p in c if p.startswith("/world/sensors/")] == ["/world/sensors/s"]
    np.testing.assert_allclose(by_frame(c["/world/sensors/s"], "Points2D:positions")[1][0], RADAR[:2], atol=1e-2)
    lines = [np.asarray(seg, dtype=float) for v in by_frame(c["/world/assignments"], "LineStrips2D:strips").values()
             for seg in v]
    lengths = np.array([np.hypot(*(s[0] - s[1])) for s in lines])
    assert lengths.size > N_FRAMES and np.median(lengths) < 50.0 and lengths.max() < 300.0


def test_a_moving_sensor_is_drawn_at_each_frames_pose(tmp_path):
    """A pose that changes frame by frame: the sensor is drawn again at each new pose, and each
    frame's measurements go through that frame's pose."""
    from dataclasses import replace

    from bnptrack.tracker.models.params import load_params

    frames, _ = posed_log("bearing_range", RADAR, pose_in_frames=True, n_frames=6)
    poses = [(RADAR[0] + 100.0 * k, RADAR[1], RADAR[2]) for k in range(6)]
    # the same rows seen from a sensor that moved 100 m east per frame
    frames = [replace(f, pose=p) for f, p in zip(frames, poses)]
    params = load_params("vo2017")
    estimates = [e for _f, e, _s in run(make_tracker("ddp-mb", params), frames, 0)]
    path = tmp_path / "moving.rrd"
    write_recording(path, frames, estimates, {}, params=params)
    c = read_rrd(path)
    dots = by_frame(c["/world/sensors/s"], "Points2D:positions")
    assert sorted(dots) == [f.frame for f in frames]
    for f, p in zip(frames, poses):
        np.testing.assert_allclose(dots[f.frame][0], p[:2], atol=1e-2)
        want = params.measurement(f.kind, params.frame_sensor(f)).to_cartesian(f.z)[0]
        np.testing.assert_allclose(by_frame(c["/world/measurements"], "Points2D:positions")[f.frame], want, atol=0.05)
