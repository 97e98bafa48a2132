"""Loud when it cannot work and the user's own-sensor log."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.writer import Writer

from bnptrack.pipeline.cli import main
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.tracker.types import Frame

HALF = np.deg2rad(45.0)


def _user_log(path, heading, send_pose, relative=True, seed=0):
    """A user's sensor at the origin facing ``heading``: 3 objects inside its +-45 deg field
    of view, T = 0.5 s, 0-3 clutter per scan, no /truth, no record.  ``relative``: bearings
    from the boresight (the contract); else from +y (a foreign convention)."""
    rng = np.random.default_rng(seed)
    starts = np.array([[600.0, 0.0], [900.0, np.deg2rad(-20.0)], [1200.0, np.deg2rad(25.0)]])  # range, bearing
    vel = np.array([[3.0, 4.0], [-5.0, 2.0], [0.0, -6.0]])  # m/s, sensor frame
    with McapLogWriter(path, None) as w:
        for k in range(1, 61):
            t = 0.5 * k
            pos = np.stack([starts[:, 0] * np.sin(starts[:, 1]), starts[:, 0] * np.cos(starts[:, 1])], 1) + vel * t
            b = np.arctan2(pos[:, 0], pos[:, 1]) + rng.normal(0, np.deg2rad(1.0), 3)
            r = np.hypot(pos[:, 0], pos[:, 1]) + rng.normal(0, 5.0, 3)
            nc = rng.integers(0, 4)
            cb, cr = rng.uniform(-HALF, HALF, nc), rng.uniform(0, 2000, nc)
            z = np.concatenate([np.stack([b, r], 1), np.stack([cb, cr], 1)])
            if not relative:
                z[:, 0] = (z[:, 0] + heading + np.pi) % (2 * np.pi) - np.pi
            w.write_frame(Frame(k, int(round(t * 1e9)), "radar0", "bearing_range", z[rng.permutation(len(z))],
                                pose=(0.0, 0.0, heading) if send_pose else None,
                                R=np.diag([np.deg2rad(1.0) ** 2, 25.0]) if send_pose else None))


def _track(log, *extra):
    return CliRunner().invoke(main, ["track", str(log), "--tracker", "ddp-mb", "--out", str(log) + ".out.mcap", *extra])


def test_foreign_log_with_pose_and_r_tracks_its_objects(tmp_path):
    log = tmp_path / "east.mcap"
    _user_log(log, np.deg2rad(90.0), send_pose=True)
    res = _track(log)
    assert res.exit_code == 0, res.output
    assert "final tracks      3" in res.output, res.output
    assert "warning" not in res.output


def test_east_facing_without_pose_warns_naming_the_cause(tmp_path):
    log = tmp_path / "east-nopose.mcap"
    _user_log(log, np.deg2rad(90.0), send_pose=False, relative=False)  # bearings from +y: 45-135 deg
    res = _track(log)
    assert res.exit_code == 0
    assert "warning:" in res.output and "fall outside its field of view" in res.output
    assert "sensor 'radar0'" in res.output and "[sensors.radar0]" in res.output and "pose" in res.output


def test_zero_tracks_from_nonempty_frames_warns(tmp_path):
    log = tmp_path / "north.mcap"
    _user_log(log, 0.0, send_pose=False)
    res = _track(log, "--set", "existence_threshold=1.0")  # nothing is ever reported
    assert res.exit_code == 0
    assert "final tracks      0" in res.output
    assert "warning: the run ended with 0 tracks from 60 frames with measurements" in res.output


def _ros_log(path):
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("sensor_msgs/PointCloud2", "ros2msg", b"")
        cid = w.register_channel("/radar/detections", "cdr", sid)
        for k in range(3):
            w.add_message(cid, log_time=k, publish_time=k, data=b"\x00\x01")
        w.finish()


@pytest.mark.parametrize("cmd", ["track", "replay"])
def test_log_without_measurements_exits_2_listing_channels(tmp_path, cmd):
    log = tmp_path / "ros.mcap"
    _ros_log(log)
    res = CliRunner().invoke(main, [cmd, str(log)])
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert "has no /measurements channel" in text
    assert "/radar/detections (sensor_msgs/PointCloud2, cdr, 3 messages)" in text
    assert "--topic /radar/detections=/measurements" in text


def test_topic_mapping_reads_a_renamed_channel(tmp_path):
    from mcap.writer import Writer as W

    from bnptrack.tracker.messages import encode

    log = tmp_path / "renamed.mcap"
    with open(log, "wb") as f:
        w = W(f)
        w.start()
        sid = w.register_schema("bnptrack.Measurements", "jsonschema", b"{}")
        cid = w.register_channel("/radar/detections", "json", sid)
        for k in range(1, 4):
            fr = Frame(k, k * 10**9, "radar0", "bearing_range", [[0.1 + 0.001 * k, 800.0 + 5 * k]])
            w.add_message(cid, log_time=k, publish_time=k, data=encode(fr))
        w.finish()
    res = _track(log, "--topic", "/radar/detections=/measurements")
    assert res.exit_code == 0, res.output
    assert "frames            3" in res.output


def _two_channel_log(path):
    """``/measurements`` (sensor ``own``, frames 1-3) and ``/radar/detections`` (sensor
    ``radar0``, frames 1-3, stamps a quarter-second later) in one log."""
    from mcap.writer import Writer as W

    from bnptrack.tracker.messages import encode

    with open(path, "wb") as f:
        w = W(f)
        w.start()
        sid = w.register_schema("bnptrack.Measurements", "jsonschema", b"{}")
        own, radar = w.register_channel("/measurements", "json", sid), w.register_channel("/radar/detections", "json", sid)
        for k in range(1, 4):
            for cid, sensor, t in ((own, "own", k * 10**9), (radar, "radar0", k * 10**9 + 25 * 10**7)):
                fr = Frame(k, t, sensor, "bearing_range", [[0.1 + 0.001 * k, 800.0 + 5 * k]])
                w.add_message(cid, log_time=t, publish_time=t, data=encode(fr))
        w.finish()
    return path


def test_a_channel_mapped_onto_measurements_stands_in_for_the_log_s_own(tmp_path):
    from bnptrack.sources.mcap_log import iter_frames

    log = _two_channel_log(tmp_path / "two.mcap")
    mapped = list(iter_frames(log, topic_map={"/radar/detections": "/measurements"}))
    assert [(f.frame, f.sensor) for f in mapped] == [(1, "radar0"), (2, "radar0"), (3, "radar0")]
    assert [f.sensor for f in iter_frames(log)] == ["own"] * 3
    res = _track(log, "--topic", "/radar/detections=/measurements")
    assert res.exit_code == 0, res.output
    assert "frames            3" in res.output


def test_info_lists_channels_sensors_time_and_record(tmp_path):
    log = tmp_path / "east.mcap"
    _user_log(log, np.deg2rad(90.0), send_pose=True)
    res = CliRunner().invoke(main, ["info", str(log)])
    assert res.exit_code == 0, res.output
    out = res.output
    assert "/measurements: schema bnptrack.Measurements (jsonschema), encoding json, 60 messages" in out
    assert "sensor            radar0: kind bearing_range, 60 frames, pose (0, 0, 90 deg)" in out
    assert "0.500 s to 30.000 s after t = 0 (span 29.5 s), 2 frames/s, dt median 500 ms" in out
    assert "record            none" in out
    sim = tmp_path / "vo.mcap"
    assert CliRunner().invoke(main, ["simulate", "--seed", "2", "--out", str(sim), "-q"]).exit_code == 0
    out = CliRunner().invoke(main, ["info", str(sim)]).output
    assert "record.scenario   vo2017" in out and "record.seed       2" in out and "/truth" in out
    assert "sensor            sim0: kind bearing_range, 100 frames\n" in out  # the default sensor: no note


def test_info_says_a_sensor_without_pose_needs_one(tmp_path):
    log = tmp_path / "unposed.mcap"
    _user_log(log, np.deg2rad(90.0), send_pose=False)
    out = CliRunner().invoke(main, ["info", str(log)]).output
    assert ("sensor            radar0: kind bearing_range, 60 frames, no pose in its frames: give --params a "
            "[sensors.radar0] table with x, y, heading_deg (else it is tracked as if at (0, 0) facing +y)\n") in out
