"""ROS 2 and Foxglove MCAP logs in, the same tracks out.

The logs are made here with the libraries' writers and the real message definitions
(tests/robotlogs.py) from the same simulated measurements as a bnptrack JSON log; tracking
them gives the JSON log's ``/tracks`` exactly (the timing diagnostic ``ms`` aside)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

import robotlogs as rl
from bnptrack.api import simulate
from bnptrack.api import track as api_track
from bnptrack.pipeline.cli import main
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.mcap_log import iter_frames
from bnptrack.sources.read_radar import bearing_of_azimuth
from bnptrack.sources.tf_static import StaticTransforms
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.types import Frame

N_FRAMES = 40
RADAR_SIM = """extends = "vo2017"
[sensors.radar0]
kind = "bearing_range"
x = -300.0
y = 900.0
heading_deg = 90.0
"""
XY_SIM = """extends = "vo2017"
[sensors.lidar]
kind = "xy"
sigma_xy = 10.0
"""
NOISE = 'extends = "vo2017"\nsigma_range = 10.0\nsigma_xy = 10.0\n'
#: the radar's pose in the JSON log's params, as /tf_static gives it: map -> base_link -> radar0
TF = [("map", "base_link", -300.0, 0.0, 0.0), ("base_link", "radar0", 0.0, 900.0, 0.0)]


def _plain(frames, n=N_FRAMES):
    """The frames without pose and truth, their values made float32 (a RadarScan's fields)."""
    return [Frame(f.frame, f.stamp_ns, f.sensor, f.kind, f.z.astype(np.float32).astype(np.float64))
            for f in frames[:n]]


def _json_log(path: Path, frames) -> Path:
    with McapLogWriter(path) as w:
        for f in frames:
            w.write_frame(f)
    return path


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("robot")
    (d / "radar_sim.toml").write_text(RADAR_SIM)
    (d / "xy_sim.toml").write_text(XY_SIM)
    (d / "noise.toml").write_text(NOISE)
    radar = _plain(simulate("vo2017", 4, params=str(d / "radar_sim.toml")))
    xy = _plain(simulate("vo2017", 5, params=str(d / "xy_sim.toml")))
    items = [("/tf_static", "tf2_msgs/msg/TFMessage", rl.tf_static(TF), 1)]
    items += rl.ros2_items(radar, "/radar/scan", "radar_msgs/msg/RadarScan", rl.radar_scan)
    return {
        "dir": d, "radar": radar, "xy": xy,
        "radar_json": _json_log(d / "radar.json.mcap", radar),
        "xy_json": _json_log(d / "xy.json.mcap", xy),
        "ros": rl.write_ros2(d / "ros.mcap", items),
        "foxglove": rl.write_foxglove_protobuf(d / "foxglove.mcap", xy),
    }


def _tracks(path: Path) -> list[dict]:
    out = []
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(log_time_order=False):
            if ch.topic == "/tracks":
                d = json.loads(msg.data)
                d["diagnostics"].pop("ms")
                out.append(d)
    return out


def _track(*args: str) -> None:
    res = CliRunner().invoke(main, ["track", *args, "-q"])
    assert res.exit_code == 0, res.output


def _same_frames(got, want):
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert (g.frame, g.stamp_ns, g.sensor, g.kind) == (w.frame, w.stamp_ns, w.sensor, w.kind)
        assert np.array_equal(g.z, w.z)


# --------------------------------------------------------------------------- tracks


@pytest.fixture(scope="module")
def radar_runs(logs):
    """``bnptrack track`` of the JSON log (its params give the radar's pose) and of the ROS 2
    log (/tf_static gives it; the params only the noise), the latter with ``--sink foxglove``."""
    d = logs["dir"]
    _track(str(logs["radar_json"]), "--params", str(d / "radar_sim.toml"), "--out", str(d / "a.mcap"))
    _track(str(logs["ros"]), "--topic", "/radar/scan", "--params", str(d / "noise.toml"),
           "--out", str(d / "b.mcap"), "--sink", "foxglove")
    return d / "a.mcap", d / "b.mcap"


def test_ros2_radar_scan_with_tf_static_tracks_like_the_json_log(radar_runs):
    want, got = _tracks(radar_runs[0]), _tracks(radar_runs[1])
    assert len(got) == N_FRAMES and sum(len(t["tracks"]) for t in want) > 20
    assert got == want


def test_foxglove_point_cloud_tracks_like_the_json_log(logs):
    d = logs["dir"]
    _track(str(logs["xy_json"]), "--params", str(d / "noise.toml"), "--out", str(d / "c.mcap"))
    _track(str(logs["foxglove"]), "--topic", "/lidar/points", "--params", str(d / "noise.toml"),
           "--out", str(d / "e.mcap"))
    want, got = _tracks(d / "c.mcap"), _tracks(d / "e.mcap")
    assert len(got) == N_FRAMES and sum(len(t["tracks"]) for t in want) > 20
    assert got == want


def test_the_python_api_takes_topics(logs):
    run = api_track(logs["ros"], params=str(logs["dir"] / "noise.toml"), topics=["/radar/scan"])
    assert len(run.estimates) == N_FRAMES
    with pytest.raises(ConfigError, match=r"has no channel /nope; trackable channels: /radar/scan "):
        api_track(logs["ros"], topics=["/nope"])


# --------------------------------------------------------------------------- frames


def test_radar_frames_carry_the_tf_static_pose(logs):
    got = list(iter_frames(logs["ros"], {"/radar/scan": "/measurements"}))
    _same_frames(got, logs["radar"])
    assert {f.pose for f in got} == {(-300.0, 900.0, math.pi / 2)}  # yaw 0: boresight +x


def test_every_xy_message_type_reads_the_same_frames(logs, tmp_path):
    xy = logs["xy"]
    pc2 = rl.write_ros2(tmp_path / "pc2.mcap", rl.ros2_items(xy, "/points", "sensor_msgs/msg/PointCloud2", rl.pointcloud2))
    poses = rl.write_ros2(tmp_path / "poses.mcap", rl.ros2_items(xy, "/poses", "geometry_msgs/msg/PoseArray", rl.pose_array))
    dets = rl.write_ros2(tmp_path / "dets.mcap",
                         rl.ros2_items(xy, "/dets", "vision_msgs/msg/Detection3DArray", rl.detection3d_array))
    fox_json = rl.write_foxglove_json(tmp_path / "fj.mcap", xy)
    for log, topic in ((pc2, "/points"), (poses, "/poses"), (dets, "/dets"), (fox_json, "/lidar/points"),
                       (logs["foxglove"], "/lidar/points")):
        got = list(iter_frames(log, {topic: "/measurements"}))
        _same_frames(got, xy)
        assert all(f.pose is None for f in got)  # no /tf_static: the params' [sensors.lidar]


def test_xy_rows_are_moved_to_the_world_by_tf_static(tmp_path):
    """Sensor 'cam' at (10, 20) with yaw 90 deg (facing world +y): a point 5 m ahead and 1 m to
    the left in its frame is at (10 - 1, 20 + 5) in the world."""
    f = Frame(1, 2_000_000_000, "cam", "xy", np.array([[5.0, 1.0]]))
    items = [("/tf_static", "tf2_msgs/msg/TFMessage", rl.tf_static([("map", "cam", 10.0, 20.0, math.pi / 2)]), 1)]
    items += rl.ros2_items([f], "/poses", "geometry_msgs/msg/PoseArray", rl.pose_array)
    (got,) = iter_frames(rl.write_ros2(tmp_path / "p.mcap", items), {"/poses": "/measurements"})
    assert np.allclose(got.z, [[9.0, 25.0]], atol=1e-12, rtol=0)
    assert got.pose == (10.0, 20.0, 0.0)  # heading 0: facing +y (the quaternion's rounding snapped)


def test_several_topics_are_merged_by_time_into_numbered_frames(logs, tmp_path):
    radar = logs["radar"][:5]
    cam = [Frame(0, f.stamp_ns + 500_000_000, "cam", "xy", f_xy.z) for f, f_xy in zip(radar, logs["xy"][:5])]
    items = rl.ros2_items(cam, "/cam", "geometry_msgs/msg/PoseArray", rl.pose_array)  # written first
    items += rl.ros2_items(radar, "/radar/scan", "radar_msgs/msg/RadarScan", rl.radar_scan)
    log = rl.write_ros2(tmp_path / "two.mcap", items)
    got = list(iter_frames(log, {"/radar/scan": "/measurements", "/cam": "/measurements"}))
    assert [f.frame for f in got] == list(range(1, 11))
    assert [f.sensor for f in got] == ["radar0", "cam"] * 5
    assert [f.stamp_ns for f in got] == sorted(f.stamp_ns for f in got)
    assert np.array_equal(got[1].z, cam[0].z) and np.array_equal(got[0].z, radar[0].z)


# --------------------------------------------------------------------------- conventions


def test_bearing_is_minus_the_rep103_azimuth():
    """A target 100 m ahead and 100 m to the left of the radar: REP 103 azimuth +pi/4
    (anticlockwise), bnptrack bearing -pi/4 (atan2(px, py) for the sensor facing +y at the
    origin and the target at (-100, 100))."""
    assert bearing_of_azimuth(np.array([math.pi / 4]))[0] == math.atan2(-100.0, 100.0)
    assert bearing_of_azimuth(np.array([-3.5]))[0] == pytest.approx(3.5 - 2 * math.pi)


def test_tf_static_chain_gives_pose_and_heading():
    tf = StaticTransforms()
    tf.add(_tf_msg(rl.tf_static([("map", "base", 100.0, 0.0, math.pi / 2), ("base", "radar", 10.0, 0.0, 0.0)])))
    pose = tf.pose("radar")  # base faces +y, so the radar is 10 m along +y from it
    assert (pose.x, pose.y, pose.heading()) == (100.0, 10.0, 0.0)
    assert tf.pose("map") is None and tf.pose("unknown") is None


def _tf_msg(d):
    """A TFMessage dict as attributes (what the CDR decoder gives)."""
    from types import SimpleNamespace

    def ns(o):
        return SimpleNamespace(**{k: ns(v) for k, v in o.items()}) if isinstance(o, dict) else \
            [ns(v) for v in o] if isinstance(o, list) else o
    return ns(d)


# --------------------------------------------------------------------------- info, errors


def test_info_names_both_channels_as_trackable(logs):
    for log, line in ((logs["ros"], "/radar/scan: schema radar_msgs/msg/RadarScan (ros2msg), encoding cdr, "
                                    f"{N_FRAMES} messages; trackable (bearing_range): --topic /radar/scan"),
                      (logs["foxglove"], "/lidar/points: schema foxglove.PointCloud (protobuf), encoding protobuf, "
                                         f"{N_FRAMES} messages; trackable (xy): --topic /lidar/points")):
        res = CliRunner().invoke(main, ["info", str(log)])
        assert res.exit_code == 0, res.output
        assert line in res.output


def test_a_foreign_type_is_a_one_line_error_listing_the_trackable_channels(logs, tmp_path):
    items = [("/chatter", "std_msgs/msg/String", {"data": "hello"}, 10)]
    items += rl.ros2_items(logs["radar"][:3], "/radar/scan", "radar_msgs/msg/RadarScan", rl.radar_scan)
    log = rl.write_ros2(tmp_path / "mixed.mcap", items)
    out = tmp_path / "out.mcap"
    for args in (["--topic", "/chatter"], []):
        res = CliRunner().invoke(main, ["track", str(log), *args, "--out", str(out)])
        assert res.exit_code == 2
        last = res.output.strip().splitlines()[-1]
        assert last.endswith("trackable channels: /radar/scan (radar_msgs/msg/RadarScan -> bearing_range: "
                             "--topic /radar/scan)") or last.endswith(
            "Trackable channels: /radar/scan (radar_msgs/msg/RadarScan -> bearing_range: --topic /radar/scan)")
        assert not out.exists()
    res = CliRunner().invoke(main, ["track", str(log), "--topic", "/chatter", "--out", str(out)])
    assert "channel /chatter carries std_msgs/msg/String (cdr), which bnptrack cannot track" in res.output


# --------------------------------------------------------------------------- the foxglove sink


def _time_to_proto(obj):
    """Foxglove's JSON times ``{"sec", "nsec"}`` in protobuf's JSON form (the rest unchanged)."""
    if isinstance(obj, dict):
        if set(obj) == {"sec", "nsec"}:
            return f"{obj['sec'] + obj['nsec'] / 1e9:.9f}s"
        return {k: _time_to_proto(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_time_to_proto(v) for v in obj]
    return obj


def test_the_foxglove_sink_writes_scene_updates_beside_the_tracks(radar_runs):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from bnptrack.tracker.types import display_name
    from google.protobuf.json_format import ParseDict
    from google.protobuf.timestamp_pb2 import Timestamp

    path = radar_runs[1]
    tracks, scenes = {}, {}
    with open(path, "rb") as f:
        for schema, ch, msg in make_reader(f).iter_messages(log_time_order=False):
            if ch.topic == "/tracks":
                tracks[msg.log_time] = json.loads(msg.data)["tracks"]
            elif ch.topic == "/tracks/scene":
                assert (schema.name, schema.encoding, ch.message_encoding) == ("foxglove.SceneUpdate", "jsonschema", "json")
                d = json.loads(msg.data)
                for e in d["entities"] + d["deletions"]:  # Timestamp fields: protobuf's JSON form
                    ts = Timestamp(seconds=e["timestamp"]["sec"], nanos=e["timestamp"]["nsec"])
                    e["timestamp"] = ts.ToJsonString()
                scenes[msg.log_time] = ParseDict(_time_to_proto(d), SceneUpdate())  # unknown fields fail
    assert set(scenes) == set(tracks) and len(scenes) == N_FRAMES
    for stamp, scene in scenes.items():
        assert [e.id for e in scene.entities] == [t["label"] for t in tracks[stamp]]
        assert [e.texts[0].text for e in scene.entities] == [display_name(t["label"]) for t in tracks[stamp]]
        for e, t in zip(scene.entities, tracks[stamp]):
            assert (e.spheres[0].pose.position.x, e.spheres[0].pose.position.y) == (t["state"][0], t["state"][2])
            vx, vy = t["state"][1], t["state"][3]
            assert e.arrows[0].shaft_length + e.arrows[0].head_length == pytest.approx(math.hypot(vx, vy))
            cov = np.array(t["covariance"]).reshape(5, 5)[np.ix_([0, 2], [0, 2])]
            axes = sorted([e.spheres[1].size.x, e.spheres[1].size.y])
            assert axes == pytest.approx(sorted(4 * np.sqrt(np.linalg.eigvalsh(cov))))
        assert scene.deletions[0].type == 1  # ALL: a track that ended disappears


def test_radar_rows_are_checked_at_the_edge():
    """Non-finite returns are dropped, an azimuth beyond pi is wrapped, a negative range is an
    error naming the return."""
    from types import SimpleNamespace as NS

    from bnptrack.sources.read_radar import RadarScanReader

    def msg(*returns):
        return NS(header=NS(stamp=NS(sec=1, nanosec=5), frame_id="r"),
                  returns=[NS(azimuth=a, range=r) for a, r in returns])

    scan = RadarScanReader().scan(msg((0.5, 10.0), (float("nan"), 20.0), (-3.5, 30.0)))
    assert scan.stamp_ns == 1_000_000_005 and scan.frame_id == "r"
    assert np.allclose(scan.z, [[-0.5, 10.0], [3.5 - 2 * math.pi, 30.0]], rtol=0, atol=1e-15)
    assert RadarScanReader().scan(msg()).z.shape == (0, 2)
    with pytest.raises(ValueError, match="return 1 has a negative range -2.0"):
        RadarScanReader().scan(msg((0.5, 10.0), (0.1, -2.0)))


def test_a_bad_ros_message_is_named_by_its_channel_s_count(logs, tmp_path):
    """The error counts the channel's own messages (the file's count, /tf_static included, is
    the McapLogError's) and gives the reader's reason without a Python class name."""
    from bnptrack.sources.mcap_log import McapLogError, iter_frames

    radar = logs["radar"][:8]
    scans = [rl.radar_scan(f) for f in radar]
    scans[5]["returns"][0]["range"] = -5.0
    items = [("/tf_static", "tf2_msgs/msg/TFMessage", rl.tf_static(TF), 1)]
    items += [("/radar/scan", "radar_msgs/msg/RadarScan", m, f.stamp_ns + rl.LOG_DELAY_NS) for f, m in zip(radar, scans)]
    path = rl.write_ros2(tmp_path / "bad.mcap", items)
    with pytest.raises(McapLogError) as err:
        list(iter_frames(path, {"/radar/scan": "/measurements"}))
    text = str(err.value)
    assert "/radar/scan's message 6: return 0 has a negative range -5.0" in text, text
    assert "ValueError" not in text


def test_a_message_stamped_far_before_those_read_earlier_warns(logs, tmp_path):
    """Frames follow the stamps; one stamped 18 periods early is named in a warning, while a
    log whose channels interleave within a period is ordered silently."""
    import warnings

    from bnptrack.sources.mcap_log import iter_frames

    radar = logs["radar"][:20]
    items = [("/tf_static", "tf2_msgs/msg/TFMessage", rl.tf_static(TF), 1)]
    for i, f in enumerate(radar):
        msg = rl.radar_scan(f)
        if i == 19:  # stamped like the first message: 18 periods before the one read before it
            msg["header"] = rl.header(radar[0].stamp_ns - 1, f.sensor)
        items.append(("/radar/scan", "radar_msgs/msg/RadarScan", msg, f.stamp_ns + rl.LOG_DELAY_NS))
    path = rl.write_ros2(tmp_path / "early.mcap", items)
    with pytest.warns(UserWarning) as caught:
        frames = list(iter_frames(path, {"/radar/scan": "/measurements"}))
    assert frames[0].stamp_ns < radar[0].stamp_ns  # ordered by its stamp: the first frame
    texts = [str(w.message) for w in caught]
    assert len(texts) == 1 and "/radar/scan's message 20 is stamped 18 s before a message read earlier" in texts[0]
    near = [radar[i] for i in (0, 2, 1, 3, 4, 5, 6)]  # two neighbours out of file order
    path = rl.write_ros2(tmp_path / "near.mcap", items[:1] + [
        ("/radar/scan", "radar_msgs/msg/RadarScan", rl.radar_scan(f), 10 + j) for j, f in enumerate(near)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = list(iter_frames(path, {"/radar/scan": "/measurements"}))
    assert [f.stamp_ns for f in got] == [f.stamp_ns for f in radar[:7]]


# --------------------------------------------------------------------------- the pipeline


def test_the_pipeline_replays_a_ros2_log_like_track_with_the_foxglove_sink(logs, tmp_path):
    """``source.topics = {"/radar/scan" = "/measurements"}`` and ``sink.outputs = ["foxglove"]``
    (in memory): the /tracks of ``bnptrack track --topic /radar/scan``, and the scene channel
    beside them in the same tracks.mcap."""
    from bnptrack.pipeline.membus import MemoryNetwork
    from bnptrack.pipeline.stages import EXIT_OK
    from testkit import mem_cfg, run_memory_pipeline

    noise = str(logs["dir"] / "noise.toml")
    cfg = mem_cfg(tmp_path, frames=12, **{"source.kind": "'mcap'", "source.log": repr(str(logs["ros"])),
                                           "source.topics": '{"/radar/scan" = "/measurements"}',
                                           "tracker.params": repr(noise), "sink.outputs": '["foxglove"]'})
    assert run_memory_pipeline(cfg, MemoryNetwork()) == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    off = tmp_path / "track.mcap"
    _track(str(logs["ros"]), "--topic", "/radar/scan", "--params", noise, "--tracker", "ddp-mb", "--set", "sweeps=8",
           "--set", "burn_in=2", "--end", "12f", "--out", str(off))
    got = Path(cfg.out) / "tracks.mcap"
    piped = [{**t, "run": ""} for t in _tracks(got)]  # the pipeline names its run
    assert piped == _tracks(off) and len(piped) == 12
    with open(got, "rb") as f:
        scene = [m for _, ch, m in make_reader(f).iter_messages(log_time_order=False) if ch.topic == "/tracks/scene"]
    assert len(scene) == 12
