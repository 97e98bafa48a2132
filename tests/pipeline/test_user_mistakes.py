"""A user's own mistakes are loud: an error before tracking where the result cannot be right, a
one-line warning naming the fix otherwise (tracker/input_checks.py, pipeline.offline)."""

from __future__ import annotations

import json
import os
import re
import stat
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.writer import Writer

from bnptrack.pipeline.cli import main
from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.tracker.types import Frame


def _log(path, sensor="radar1", dt_ns=500_000_000, pose=None, n=30, relative_heading=0.0):
    """Two objects seen by a bearing-range sensor at the origin (bearings from +y plus
    ``relative_heading``), one scan every ``dt_ns`` nanoseconds."""
    rng = np.random.default_rng(4)
    with McapLogWriter(path, None) as w:
        for k in range(1, n + 1):
            t = 0.5 * k
            pos = np.array([[100 + 3 * t, 800 + 4 * t], [-200 - 5 * t, 1200 + 2 * t]])
            b = np.arctan2(pos[:, 0], pos[:, 1]) + relative_heading + rng.normal(0, 0.01, 2)
            z = np.stack([(b + np.pi) % (2 * np.pi) - np.pi, np.hypot(pos[:, 0], pos[:, 1])], 1)
            w.write_frame(Frame(k, k * dt_ns, sensor, "bearing_range", z, pose=pose))
    return path


def _params(tmp_path, heading_deg="0.0"):
    p = tmp_path / "radar.toml"
    p.write_text(f'extends = "vo2017"\n[sensors.radar1]\nx = 0.0\ny = 0.0\nheading_deg = {heading_deg}\n')
    return p


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _one_line(output, needle):
    """The one output line holding ``needle`` (it must be there)."""
    lines = [line for line in output.splitlines() if needle in line]
    assert lines, output
    return lines[0]


# --------------------------------------------------------------------------- errors before tracking


def test_misspelt_sensor_in_the_log_is_an_error_naming_the_declared_name(tmp_path):
    log = _log(tmp_path / "typo.mcap", sensor="radarl")
    params = _params(tmp_path)
    res = _run("track", log, "--params", params, "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert line.startswith(f"Error: the log's sensor 'radarl' (frame 1) has no [sensors.radarl] table in {params}, "
                           "which declares [sensors.radar1]"), line
    assert "if the log misspells 'radar1', fix the name in the log" in line


def test_misspelt_table_in_the_params_file_names_the_file_and_the_table_to_rename(tmp_path):
    log = _log(tmp_path / "radar.mcap", sensor="radar0")
    params = tmp_path / "typo.toml"
    params.write_text('extends = "vo2017"\n[sensors.rader0]\nx = 0.0\ny = 0.0\nheading_deg = 0\n')
    res = _run("track", log, "--params", params, "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert line.startswith(f"Error: the log's sensor 'radar0' (frame 1) has no [sensors.radar0] table in {params}, "
                           "which declares [sensors.rader0]"), line
    assert "rename that table to [sensors.radar0] if it is this sensor" in line
    assert "did you mean 'rader0'" not in line


@pytest.mark.parametrize("command", ["track", "replay"])
def test_a_misspelt_sensor_of_a_set_item_names_the_item_and_the_close_sensor(tmp_path, command):
    log = _log(tmp_path / "radar.mcap", sensor="radar0")
    extra = ("--as-fast-as-possible",) if command == "replay" else ()
    res = _run(command, log, "--set", "sensors.radr0.x=1500", "--out", tmp_path / "t", *extra, "-q")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == (
        "Error: --set 'sensors.radr0.x=1500' declares sensor 'radr0', which the log does not have: the log's sensor "
        "'radar0' (frame 1) has no [sensors.radar0] table and no pose in its frames "
        "(did you mean --set 'sensors.radar0.x=1500'?)")


def test_unrelated_sensor_name_says_to_add_its_table(tmp_path):
    log = _log(tmp_path / "radar.mcap", sensor="lidar_front")
    res = _run("track", log, "--params", _params(tmp_path), "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 2, res.output
    assert "add a [sensors.lidar_front] table with x, y, heading_deg" in _one_line(res.output, "Error:")


def test_misspelt_sensor_is_refused_by_replay_before_any_process(tmp_path):
    log = _log(tmp_path / "typo.mcap", sensor="radarl")
    out = tmp_path / "r"
    res = _run("replay", log, "--params", _params(tmp_path), "--out", out, "--as-fast-as-possible", "-q")
    assert res.exit_code == 2, res.output
    assert "if the log misspells 'radar1', fix the name in the log" in _one_line(res.output, "Error:")
    assert not out.exists()


def test_a_sensor_with_its_own_pose_needs_no_table(tmp_path):
    log = _log(tmp_path / "posed.mcap", sensor="radar2", pose=(0.0, 0.0, 0.0))
    res = _run("track", log, "--params", _params(tmp_path), "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 0, res.output
    assert "warning" not in res.output


def _foreign_payload_log(path):
    """A channel /radar whose JSON is some other message type."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("radar.Detections", "jsonschema", b"{}")
        cid = w.register_channel("/radar", "json", sid)
        for k in range(1, 11):
            data = json.dumps({"stamp": k * 0.1, "targets": [[1.0, 2.0]]}).encode()
            w.add_message(cid, log_time=k * 10**8, publish_time=k * 10**8, sequence=k, data=data)
        w.finish()
    return path


@pytest.mark.parametrize("cmd", ["track", "replay", "launch"])
def test_undecodable_topic_is_refused_while_options_are_checked(tmp_path, cmd):
    log = _foreign_payload_log(tmp_path / "radar.mcap")
    out = tmp_path / "out"
    if cmd == "launch":
        args = ["launch", "--set", "source.kind='mcap'", "--set", f"source.log='{log}'", "--set",
                'source.topics={"/radar" = "/measurements"}', "--out", out, "-q"]
    else:
        args = [cmd, log, "--topic", "/radar=/measurements", "--out", out, "-q"]
        args += ["--as-fast-as-possible"] if cmd == "replay" else []
    res = _run(*args)
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert "channel /radar (--topic /radar=/measurements) does not decode as bnptrack measurements" in line
    assert "unknown field `stamp`" in line
    assert not out.exists()  # nothing started, nothing written


def test_a_tracks_channel_mapped_onto_measurements_is_named_for_what_it_holds(tmp_path):
    import bnptrack

    log = bnptrack.simulate("vo2017", 1)[:4]
    run = bnptrack.track(log, "ddp-mb")
    tracks = tmp_path / "tracks.mcap"
    from bnptrack.sinks.mcap_writer import McapLogWriter

    with McapLogWriter(tracks, None) as w:
        for f, e in zip(log, run.estimates):
            w.write_frame(f)
            w.write_tracks(e)
    res = _run("track", tracks, "--topic", "/tracks=/measurements", "--out", tmp_path / "out.mcap", "-q")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == (f"Error: {tracks}: channel /tracks holds bnptrack /tracks messages, "
                                               "not measurements: --topic /tracks=/measurements cannot be tracked")
    assert not (tmp_path / "out.mcap").exists()


# --------------------------------------------------------------------------- --set typos


def test_bare_set_key_typo_suggests_the_model_parameter(tmp_path):
    log = _log(tmp_path / "a.mcap")
    res = _run("track", log, "--set", "p_detcet=0.9", "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 2
    assert "unknown key 'p_detcet' (did you mean 'p_detect'?)" in res.output


@pytest.mark.parametrize("cmd", ["track", "launch"])
def test_prefixed_set_key_typo_names_the_key_as_typed(tmp_path, cmd):
    log = _log(tmp_path / "a.mcap")
    args = ["track", log] if cmd == "track" else ["launch"]
    res = _run(*args, "--set", "tracker.sweps=10", "--out", tmp_path / "o", "-q")
    assert res.exit_code == 2
    line = _one_line(res.output, "Error:")
    assert line.startswith("Error: --set 'tracker.sweps=10': unknown key 'tracker.sweps' (did you mean 'tracker.sweeps'?)")


# --------------------------------------------------------------------------- warnings


def test_stamps_in_milliseconds_warn_naming_the_unit(tmp_path):
    log = _log(tmp_path / "ms.mcap", sensor="radar0", dt_ns=500)  # 0.5 s written as 500 "ns"
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 0, res.output
    line = _one_line(res.output, "warning: sensor 'radar0': the median spacing")
    assert "500 ns between scans" in line
    assert "they look like milliseconds (the spacing would be 0.5 s): multiply them by 1e+06" in line


@pytest.mark.parametrize("dt_ns, warned", [(1_000_000, True), (1_999_999, True), (2_000_000, False), (10_000_000, False)])
def test_microsecond_stamps_of_a_1_hz_sensor_warn_at_the_boundary(tmp_path, dt_ns, warned):
    log = _log(tmp_path / "us.mcap", sensor="radar0", dt_ns=dt_ns, n=5)
    res = _run("info", log)
    assert res.exit_code == 0, res.output
    assert ("warning: sensor 'radar0': the median spacing" in res.output) is warned, res.output
    if dt_ns == 1_000_000:
        assert "they look like microseconds (the spacing would be 1 s): multiply them by 1000" in res.output


def test_stamps_far_apart_warn_naming_the_unit(tmp_path):
    log = _log(tmp_path / "us.mcap", sensor="radar0", dt_ns=500_000 * 10**9)  # 0.5 s in us, times 1e9
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    line = _one_line(res.output, "warning: sensor 'radar0': the median spacing")
    assert "139 h between scans" in line and "microseconds converted as seconds" in line
    assert "divide them by 1e+06" in line


def test_pose_heading_in_degrees_warns(tmp_path):
    log = _log(tmp_path / "deg.mcap", sensor="radar0", pose=(0.0, 0.0, 40.0))
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    line = _one_line(res.output, "warning: sensor 'radar0': frame 1 has pose heading 40, outside [-2pi, 2pi]")
    assert "if 40 is degrees, send 0.698132" in line
    assert res.output.count("has pose heading") == 1  # once, not once per frame


def test_heading_deg_in_radians_warns(tmp_path):
    log = _log(tmp_path / "a.mcap", relative_heading=-0.698)
    res = _run("track", log, "--params", _params(tmp_path, "0.698"), "--out", tmp_path / "t.mcap", "-q")
    line = _one_line(res.output, "warning: [sensors.radar1] heading_deg = 0.698 looks like radians (39.99 deg)")
    assert "write heading_deg = 39.99" in line


def test_a_sensor_with_no_pose_anywhere_warns_once_naming_the_table(tmp_path):
    log = _log(tmp_path / "own.mcap", sensor="radar0")  # bearing-range: the field of view cannot tell
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 0, res.output
    line = _one_line(res.output, "warning: sensor 'radar0' has no pose")
    assert "tracked as if at (0, 0) facing +y (the default sensor)" in line
    assert "add a [sensors.radar0] table with x, y, heading_deg to your params file" in line
    assert res.output.count("has no pose") == 1


def test_an_xy_sensor_with_no_pose_is_told_its_points_stay_where_they_are(tmp_path):
    log = tmp_path / "lidar.mcap"
    with McapLogWriter(log, None) as w:
        for k in range(1, 6):
            w.write_frame(Frame(k, k * 500_000_000, "lidar", "xy", [[100.0 + 3 * k, 800.0], [-200.0, 1200.0 - 2 * k]]))
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 0, res.output
    line = _one_line(res.output, "warning: sensor 'lidar' has no pose")
    assert ("its detections are world positions, but its field of view and clutter region are the default "
            "sensor's (at (0, 0) facing +y); add a [sensors.lidar] table") in line
    assert "tracked as if" not in line


@pytest.mark.parametrize("sensor", ["sim0", ""])
def test_the_default_sensor_name_needs_no_pose(tmp_path, sensor):
    log = _log(tmp_path / "sim.mcap", sensor=sensor)
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 0 and "warning" not in res.output, res.output


def test_a_simulated_log_gives_no_warning(tmp_path):
    log = tmp_path / "sim.mcap"
    assert _run("simulate", "--scenario", "proximity", "--seed", "3", "--out", log, "-q").exit_code == 0
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 0 and "warning" not in res.output, res.output


def test_whole_degrees_and_nanosecond_stamps_give_no_warning(tmp_path):
    log = _log(tmp_path / "a.mcap", relative_heading=-np.deg2rad(5.0))
    res = _run("track", log, "--params", _params(tmp_path, "5"), "--out", tmp_path / "t.mcap", "-q")
    assert res.exit_code == 0 and "warning" not in res.output, res.output


def test_no_pose_outside_the_field_of_view_shows_the_table_to_add(tmp_path):
    log = _log(tmp_path / "south.mcap", sensor="radar0", relative_heading=np.deg2rad(135.0))
    res = _run("track", log, "--out", tmp_path / "t.mcap", "-q")
    line = _one_line(res.output, "fall outside its field of view")
    assert "sensor 'radar0'" in line
    # the table to add, with the boresight the bearings point to (135 deg plus the objects' own
    # bearings, -9 to +8 deg from the sensor's boresight)
    table = re.search(r"\[sensors\.radar0\] x = <m> y = <m> heading_deg = (-?\d+) ", line)
    assert table is not None, line
    assert 130 <= int(table.group(1)) <= 140


# --------------------------------------------------------------------------- Python


def test_python_raises_the_warnings_through_warnings_warn(tmp_path):
    import bnptrack
    from bnptrack.tracker.input_checks import InputWarning

    log = _log(tmp_path / "east-ms.mcap", sensor="radar0", dt_ns=500, relative_heading=np.deg2rad(135.0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = bnptrack.track(log, "ddp-mb", params="vo2017")
    texts = [str(w.message) for w in caught if issubclass(w.category, InputWarning)]
    assert any("they look like milliseconds" in t for t in texts), texts
    assert any("fall outside its field of view" in t for t in texts), texts
    assert all(w in texts for w in run.warnings)


def test_python_run_lists_the_input_warnings_it_raised(tmp_path):
    import bnptrack
    from bnptrack.tracker.input_checks import InputWarning

    log = _log(tmp_path / "ms.mcap", sensor="radar1", dt_ns=500)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = bnptrack.track(log, "ddp-mb", params=str(_params(tmp_path)))
    texts = [str(w.message) for w in caught if issubclass(w.category, InputWarning)]
    assert any("they look like milliseconds" in t for t in texts), texts
    assert run.warnings == tuple(texts)


def test_python_warnings_point_at_the_caller_s_line(tmp_path):
    """Attributed to the line that called bnptrack (not a line inside it), Python's default
    filter shows a warning again for another call of the user's own code."""
    import bnptrack
    from bnptrack.tracker.input_checks import InputWarning

    log = _log(tmp_path / "ms.mcap", sensor="radar1", dt_ns=500, n=5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        bnptrack.track(log, "ddp-mb", params=str(_params(tmp_path)))
        bnptrack.track(log, "ddp-mb", params=str(_params(tmp_path)))
    ours = [w for w in caught if issubclass(w.category, InputWarning)]
    assert len(ours) == 2 and {w.filename for w in ours} == {__file__}, [(w.filename, w.lineno) for w in ours]


def test_python_misspelt_sensor_raises_config_error(tmp_path):
    import bnptrack
    from bnptrack.tracker.config import ConfigError

    log = _log(tmp_path / "typo.mcap", sensor="radarl")
    with pytest.raises(ConfigError, match="if the log misspells 'radar1'"):
        bnptrack.track(log, "ddp-mb", params=str(_params(tmp_path)))


# --------------------------------------------------------------------------- --topic


@pytest.mark.parametrize("cmd", ["track", "replay", "info"])
def test_a_missing_topic_lists_the_log_s_own_measurements_with_their_topic(tmp_path, cmd):
    log = _log(tmp_path / "own.mcap", sensor="sim0", n=5)
    out = tmp_path / "out"
    args = [cmd, log, "--topic", "/radar/scan"] + (["--out", out, "-q"] if cmd != "info" else [])
    res = _run(*args + (["--as-fast-as-possible"] if cmd == "replay" else []))
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert line.startswith(f"Error: {log} has no channel /radar/scan; trackable channels: /measurements "
                           "(bnptrack measurements, read by default: --topic /measurements or no --topic)"), line


# --------------------------------------------------------------------------- usage errors


@pytest.mark.parametrize("args, expected", [
    (["track", "LOG", "--tracker", "ddpp"], "Error: Invalid value for '--tracker': 'ddpp' is not one of"),
    (["track", "LOG", "--lag", "-1"], "Error: Invalid value for '--lag': -1 is not in the range x>=0."),
    (["track"], "Error: Missing argument 'LOG'."),
])
def test_a_usage_error_is_one_line(tmp_path, args, expected):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    res = _run(*[log if a == "LOG" else a for a in args])
    assert res.exit_code == 2
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(expected), res.output


def test_a_choice_typo_gets_the_closest_choice(tmp_path):
    res = _run("track", _log(tmp_path / "a.mcap", sensor="sim0", n=3), "--tracker", "ddpp")
    assert "(did you mean 'ddp'?)" in res.output


def test_an_unknown_set_key_lists_the_close_keys_only(tmp_path):
    res = _run("track", _log(tmp_path / "a.mcap", sensor="sim0", n=3), "--set", "p_detcet=0.9", "--out",
               tmp_path / "t.mcap")
    line = _one_line(res.output, "Error:")
    assert "(did you mean 'p_detect'" in line and "docs/models.md" in line
    assert "sigma_turn_deg" not in line and len(line) < 300, line


# --------------------------------------------------------------------------- Python names its arguments


def test_python_errors_name_the_arguments_not_the_flags(tmp_path):
    import bnptrack
    from bnptrack.tracker.config import ConfigError

    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    with pytest.raises(ConfigError, match=r"^overrides item 'p_detcet=0.9': unknown key 'p_detcet'") as e:
        bnptrack.track(log, overrides=["p_detcet=0.9"])
    assert "--set" not in str(e.value)
    with pytest.raises(ConfigError, match=r"^overrides item 'sweeps': expected key=value"):
        bnptrack.make_tracker("ddp", overrides=["sweeps"])
    with pytest.raises(ConfigError, match=r"^params='nope': not a built-in set"):
        bnptrack.track(log, params="nope")
    with pytest.raises(ConfigError, match=r"^overrides item 'p_detect=2.0': expected `float` <= 1.0$"):
        bnptrack.track(log, overrides=["p_detect=2.0"])


@pytest.mark.parametrize("item, message", [
    ("p_detect=1.5", "--set 'p_detect=1.5': expected `float` <= 1.0"),
    ("p_detect=abc", "--set 'p_detect=abc': expected `float`, got `str`"),
    ("tracker.sweeps=-1", "--set 'tracker.sweeps=-1': expected `int` >= 1"),
    ("objects.sweeps=0", "--set 'objects.sweeps=0': expected `int` >= 1"),
])
def test_a_bad_set_value_names_its_item(tmp_path, item, message):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    res = _run("track", log, "--set", "sweeps=3", "--set", item,
               "--out", tmp_path / "out", "-q")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == f"Error: {message}"


def test_simulate_names_its_arguments_not_the_flags():
    import bnptrack
    from bnptrack.tracker.config import ConfigError

    with pytest.raises(ConfigError, match=r"^params='nope': not a built-in set"):
        bnptrack.simulate(params="nope")
    with pytest.raises(ConfigError, match=r"^overrides item 'p_detcet=0.9': unknown key 'p_detcet' \(did you mean 'p_detect'\?\)"):
        bnptrack.simulate(overrides=["p_detcet=0.9"])
    with pytest.raises(ConfigError, match=r"^overrides item 'scene.n_objectz=3': unknown key 'scene.n_objectz' "
                                          r"\(did you mean 'scene.n_objects'"):
        bnptrack.simulate("random", overrides=["scene.n_objectz=3"])


def test_a_nested_key_is_suggested_in_full():
    from bnptrack.tracker.config import ConfigError

    import bnptrack
    with pytest.raises(ConfigError, match=r"unknown key 'objects.sweps' \(did you mean 'objects.sweeps'\?\)"):
        bnptrack.make_tracker("ddp", overrides=["objects.sweps=2"])


# --------------------------------------------------------------------------- wrong file types


@pytest.mark.parametrize("content", [b"hello\n", b"\x89PNG\r\n\x1a\n" + bytes(40)])
@pytest.mark.parametrize("cmd", ["track", "info"])
def test_a_file_without_the_mcap_magic_is_not_an_mcap_file(tmp_path, content, cmd):
    f = tmp_path / "notes.txt"
    f.write_bytes(content)
    res = _run(cmd, f, *(["--out", tmp_path / "t.mcap"] if cmd == "track" else []))
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert "not an MCAP file: it starts with" in line and "truncated" not in line, line


def test_export_of_a_recording_is_not_an_mcap_file_and_says_what_it_is(tmp_path):
    rrd = tmp_path / "run.rrd"
    rrd.write_bytes(b"RRF2\x00)\x00\x00" + bytes(64))
    res = _run("export", rrd, "--csv", tmp_path / "t.csv")
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert line.startswith(f"Error: {rrd}: not an MCAP file: it starts with b'RRF2"), line
    assert line.endswith("(a Rerun recording: `bnptrack view` opens it)"), line
    assert not (tmp_path / "t.csv").exists()


def test_view_of_an_mcap_log_says_it_expects_a_recording(tmp_path):
    log = _log(tmp_path / "run.mcap", sensor="sim0", n=3)
    res = _run("view", log, "--screenshot", tmp_path / "s.png")
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert "is an MCAP log; view expects a Rerun .rrd recording" in line
    assert "`bnptrack track LOG --rrd FILE.rrd`" in line
    assert not (tmp_path / "s.png").exists()


def test_a_screenshot_of_a_recording_cut_short_warns_and_names_the_repair(tmp_path, monkeypatch):
    """The viewer renders the frames it can read (the real viewer: tests/sinks/test_rerun_sink.py)."""
    import bnptrack.pipeline.view as view

    cut = tmp_path / "run.rrd"
    cut.write_bytes(b"RRF2\x00)\x00\x00" + bytes(64))  # no footer: its writer stopped before the end
    rendered = []
    monkeypatch.setattr(view, "screenshot", lambda rrd, out, **kw: rendered.append((rrd, out)) or out)
    res = _run("view", cut, "--screenshot", tmp_path / "s.png")
    assert res.exit_code == 0, res.output
    assert rendered == [(cut, tmp_path / "s.png")]
    assert _one_line(res.output, "warning:") == (
        f"warning: {cut} is incomplete: it has no footer (its writer stopped before the end, e.g. a crash, or is "
        f"still writing); `bnptrack view {cut} --repair FIXED.rrd` keeps its complete frames")


def test_the_viewer_opens_a_recording_without_footer_with_a_warning(tmp_path, monkeypatch):
    """A window shows what the viewer reads of a recording still being written."""
    import bnptrack.pipeline.view as view

    growing = tmp_path / "run.rrd"
    growing.write_bytes(b"RRF2\x00)\x00\x00" + bytes(64))
    opened = []
    monkeypatch.setattr(view, "open_viewer", lambda path, web=False: opened.append(path) or 0)
    res = CliRunner().invoke(main, ["view", str(growing)])
    assert res.exit_code == 0, res.output
    assert opened == [growing]
    assert res.stderr.startswith(f"warning: {growing} is incomplete: it has no footer"), res.stderr


def test_view_of_an_empty_file_says_it_is_empty_at_once(tmp_path):
    empty = tmp_path / "run.rrd"
    empty.write_bytes(b"")
    res = _run("view", empty, "--screenshot", tmp_path / "s.png")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == (f"Error: {empty} is empty (0 bytes): not a Rerun recording; view expects "
                                               "a Rerun .rrd recording, e.g. from `bnptrack track LOG --rrd FILE.rrd`")
    assert not (tmp_path / "s.png").exists()


@pytest.mark.parametrize("target, fragment", [
    ("rec.rrd", "the picture is a PNG; give a file name ending in .png"),
    ("shot.jpg", "the picture is a PNG; give a file name ending in .png"),
    ("notes.png", "the file exists and is not a PNG; choose another name or remove it"),
    ("rec.png", "the picture would overwrite the recording it renders"),
])
def test_a_screenshot_never_replaces_the_recording_or_a_file_other_than_a_png(tmp_path, target, fragment):
    """Refused before the viewer starts; the file named keeps its bytes."""
    body = b"RRF2\x00)\x00\x00" + bytes(64) + b"RRF2FOOT\x01\x00\x00\x00"  # a complete recording's ends
    (tmp_path / "rec.rrd").write_bytes(body)
    (tmp_path / "rec.png").write_bytes(body)  # a recording under a .png name
    (tmp_path / "notes.png").write_bytes(b"my notes")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    rec = tmp_path / ("rec.png" if target == "rec.png" else "rec.rrd")
    res = _run("view", rec, "--screenshot", tmp_path / target)
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == f"Error: --screenshot {tmp_path / target}: {fragment}"
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize("size, fragment", [
    ("1600by900", "'1600by900': expected WIDTHxHEIGHT, e.g. 1600x900"),
    ("32x900", "'32x900': at least 64x64"),
    ("100000x900", "'100000x900': at most 8192 pixels a side (the renderer's largest picture)"),
])
def test_a_screenshot_size_out_of_range_is_refused_before_the_viewer_starts(tmp_path, size, fragment):
    rec = tmp_path / "rec.rrd"
    rec.write_bytes(b"RRF2\x00)\x00\x00" + bytes(64) + b"RRF2FOOT\x01\x00\x00\x00")
    res = _run("view", rec, "--screenshot", tmp_path / "s.png", "--size", size)
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == f"Error: Invalid value for --size: {fragment}"
    assert not (tmp_path / "s.png").exists()


def test_an_existing_recording_names_the_option_that_chose_it(tmp_path):
    from bnptrack.pipeline.output_paths import refuse_existing

    rrd, mcap = tmp_path / "r.rrd", tmp_path / "t.mcap"
    rrd.write_bytes(b"RRF2")
    with pytest.raises(ValueError, match=r"r\.rrd exists: give --overwrite to replace it, or another --rrd$"):
        refuse_existing({"mcap": mcap, "rerun": rrd}, False)
    mcap.write_bytes(b"x")
    with pytest.raises(ValueError, match=r"t\.mcap exist: give --overwrite to replace them, or another --out or --rrd$"):
        refuse_existing({"mcap": mcap, "rerun": rrd}, False)
    refuse_existing({"mcap": mcap, "rerun": rrd}, True)  # --overwrite


@pytest.mark.parametrize("args", [["replay", "--rate", "inf"], ["replay", "--rate", "nan"],
                                  ["track", "--max-gap-s", "nan"], ["replay", "--timeout", "inf"]])
def test_a_number_option_must_be_finite(tmp_path, args):
    log = _log(tmp_path / "run.mcap", sensor="sim0", n=3)
    command, option, value = args
    res = _run(command, log, option, value, "--out", tmp_path / "out")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == f"Error: Invalid value for '{option}': '{value}' is not a finite number"
    assert not (tmp_path / "out").exists()


def test_info_warns_of_stamps_in_milliseconds_as_track_does(tmp_path):
    log = _log(tmp_path / "ms.mcap", sensor="radar0", dt_ns=500)
    res = _run("info", log)
    assert res.exit_code == 0, res.output
    line = _one_line(res.output, "warning: sensor 'radar0': the median spacing")
    assert "they look like milliseconds (the spacing would be 0.5 s): multiply them by 1e+06" in line


def test_info_of_nanosecond_stamps_gives_no_warning(tmp_path):
    res = _run("info", _log(tmp_path / "ns.mcap", sensor="radar0"))
    assert res.exit_code == 0 and "warning" not in res.output, res.output


# --------------------------------------------------------------------------- existing outputs


@pytest.mark.parametrize("item, message", [
    ("source.kind=mcp", "Error: --set 'source.kind=mcp': invalid enum value 'mcp', not one of mcap, synthetic "
                        "(did you mean 'mcap'?)"),
    ("source.scenario=randm", "Error: source.scenario: unknown scenario 'randm' (did you mean 'random'?); valid "
                              "scenarios: vo2017, dpy5, proximity, snr, random, random-cv, groups, groups-pl, groups-py"),
])
def test_a_misspelt_source_value_of_launch_gets_the_close_one(tmp_path, item, message):
    out = tmp_path / "run"
    res = _run("launch", "--set", item, "--set", f"out={out}")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == message
    assert not out.exists()


@pytest.mark.parametrize("args", [("--set", "sigma_range=2000"), ("--scenario", "snr", "--snr", "-1000")])
def test_simulate_writes_a_log_with_a_large_range_noise(tmp_path, args):
    out = tmp_path / "noisy.mcap"
    res = _run("simulate", "--seed", "1", *args, "--out", out, "-q")
    assert res.exit_code == 0, res.output
    assert _run("info", out).exit_code == 0


def test_simulate_refuses_an_existing_out_without_overwrite(tmp_path):
    out = tmp_path / "sim.mcap"
    out.write_bytes(b"mine")
    res = _run("simulate", "--seed", "2", "--out", out, "-q")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == f"Error: {out} exists: give --overwrite to replace it, or another --out"
    assert out.read_bytes() == b"mine"
    assert _run("simulate", "--seed", "2", "--out", out, "-q", "--overwrite").exit_code == 0
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n"


def test_export_refuses_an_existing_table_without_overwrite(tmp_path):
    log = tmp_path / "sim.mcap"
    assert _run("simulate", "--scenario", "dpy5", "--seed", "2", "--out", log, "-q").exit_code == 0
    run = tmp_path / "run.mcap"
    assert _run("track", log, "--tracker", "ddp-mb", "--out", run, "-q", "--set", "source.end_frame=5").exit_code == 0
    csv = tmp_path / "t.csv"
    assert _run("export", run, "--csv", csv).exit_code == 0
    before = csv.read_bytes()
    res = _run("export", run, "--csv", csv)
    assert res.exit_code == 2, res.output
    metrics = tmp_path / "t.metrics.csv"
    assert metrics.exists()
    assert _one_line(res.output, "Error:") == (f"Error: {csv} and {metrics} exist: give --overwrite to replace "
                                               "them, or another --csv / --parquet file")
    assert csv.read_bytes() == before
    assert _run("export", run, "--csv", csv, "--overwrite").exit_code == 0


def test_export_refuses_a_metrics_table_onto_the_run(tmp_path):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    run = tmp_path / "r.metrics.mcap"
    assert _run("track", log, "--tracker", "ddp-mb", "--out", run, "-q").exit_code == 0
    before = run.read_bytes()
    res = _run("export", run, "--csv", tmp_path / "r.mcap", "--overwrite")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == (f"Error: --csv {tmp_path / 'r.mcap'}: its metrics table {run} would "
                                               f"overwrite the run {run}")
    assert run.read_bytes() == before


@pytest.mark.parametrize(("args", "message"), [
    (["--csv", "{d}/t.metrics.csv"], "--csv {d}/t.metrics.csv: that is the name of the metrics table beside a track "
     "table; give the track table's name ({d}/t.csv writes {d}/t.csv and {d}/t.metrics.csv)"),
    (["--csv", "{d}/run.mcap", "--overwrite"], "--csv {d}/run.mcap: the table would overwrite the run {d}/run.mcap"),
    (["--csv", "{d}/a.csv", "--parquet", "{d}/a.csv"], "--parquet {d}/a.csv: the same file as --csv's table"),
    (["--csv", "{d}/a.parquet", "--parquet", "{d}/a.parquet"], "--parquet {d}/a.parquet: the same file as --csv's table"),
    (["--csv", "{d}/t.PARQUET"], "--csv {d}/t.PARQUET: a Parquet file's name; give --parquet {d}/t.PARQUET to write "
     "Parquet, or a name that does not end in .parquet"),
])
def test_export_refuses_tables_that_replace_the_run_or_each_other(tmp_path, args, message):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    run = tmp_path / "run.mcap"
    assert _run("track", log, "--tracker", "ddp-mb", "--out", run, "-q").exit_code == 0
    before = run.read_bytes()
    res = _run("export", run, *[a.format(d=tmp_path) for a in args])
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == "Error: " + message.format(d=tmp_path)
    assert run.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap", "run.mcap"]


# --------------------------------------------------------------------------- a log given as a settings file


@pytest.mark.parametrize("option", ["--params", "--config"])
def test_a_log_given_as_a_settings_file_is_named(tmp_path, option):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    res = _run("track", log, option, log, "--out", tmp_path / "out", "-q")
    assert res.exit_code == 2, res.output
    line = _one_line(res.output, "Error:")
    assert line == f"Error: {log}: not a TOML file (binary data; it is an MCAP log)"


def test_a_log_given_as_a_pipeline_file_is_named(tmp_path):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    res = _run("launch", log, "--out", tmp_path / "out", "-q")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == f"Error: {log}: not a TOML file (binary data; it is an MCAP log)"


def test_binary_data_and_a_folder_as_a_params_file(tmp_path):
    from bnptrack.tracker.config import ConfigError, read_toml

    blob = tmp_path / "x.toml"
    blob.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(40))
    with pytest.raises(ConfigError, match=r"x.toml: not a TOML file \(binary data\)$"):
        read_toml(blob)
    with pytest.raises(ConfigError, match=r": a folder, not a TOML file$"):
        read_toml(tmp_path)


def test_a_simulation_that_fails_leaves_no_partial_log(tmp_path, monkeypatch):
    """The log is renamed into place at the end: a failure mid-run leaves nothing (and an
    existing log given with --overwrite as it was)."""
    from bnptrack.pipeline import offline

    real = offline.simulate

    def failing(*args):
        for k, frame in enumerate(real(*args)):
            if k == 5:
                raise ValueError("frame 5: a failure in the simulator")
            yield frame

    monkeypatch.setattr(offline, "simulate", failing)
    out = tmp_path / "s.mcap"
    res = _run("simulate", "--seed", "1", "--out", out)
    assert res.exit_code == 2 and "a failure in the simulator" in res.output
    assert list(tmp_path.iterdir()) == []
    out.write_bytes(b"an earlier log")
    res = _run("simulate", "--seed", "1", "--out", out, "--overwrite")
    assert res.exit_code == 2
    assert out.read_bytes() == b"an earlier log" and list(tmp_path.iterdir()) == [out]
    assert _run("simulate", "--scenario", "random", "--set", "scene.n_objects=10001", "--out", out,
                "--overwrite").output.strip().endswith(
        "--set 'scene.n_objects=10001': n_objects must be in [0, 10000] (a /truth message holds at most 10000 objects)")


def test_running_out_of_memory_is_one_line_naming_the_settings_that_ask_for_it(tmp_path, monkeypatch):
    from bnptrack.pipeline import offline

    def too_big(*args, **kwargs):
        return np.empty((10**15, 2))  # numpy's MemoryError: "Unable to allocate ..."

    monkeypatch.setattr(offline, "track_frames", too_big)
    log = _log(tmp_path / "run.mcap", sensor="sim0", n=3)
    res = _run("track", log, "--out", tmp_path / "t.mcap")
    assert res.exit_code == 1, res.output
    line = _one_line(res.output, "Error:")
    assert line.startswith("Error: out of memory (Unable to allocate "), line
    assert line.endswith("a setting far beyond what the scene needs (e.g. clutter_rate, sweeps, scene.n_objects) "
                         "asks for more than this machine has"), line


@pytest.mark.parametrize("error", [np.linalg.LinAlgError("Singular matrix"), OverflowError("Singular matrix"),
                                   FloatingPointError("Singular matrix")])
def test_a_numerical_failure_is_an_internal_error_not_a_user_error(tmp_path, monkeypatch, error):
    """numpy's LinAlgError (a ValueError) or an overflow inside a run is reported as bnptrack's
    own failure on one line, exit 1, asking for a report: not as a mistake of the user's (exit
    2), nor as a traceback."""
    from bnptrack.pipeline import offline

    def singular(*args, **kwargs):
        raise error

    monkeypatch.setattr(offline, "track_frames", singular)
    log = _log(tmp_path / "run.mcap", sensor="sim0", n=3)
    res = _run("track", log, "--out", tmp_path / "t.mcap")
    assert res.exit_code == 1, res.output
    assert _one_line(res.output, "Error:") == (
        f"Error: numerical failure inside bnptrack ({type(error).__name__}: Singular matrix); BNPTRACK_DEBUG=1 shows the "
        "traceback: please report it with the command")


def test_info_on_a_truncated_log_describes_its_frames_then_exits_2(tmp_path):
    whole = _log(tmp_path / "whole.mcap", sensor="sim0", n=30)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    res = _run("info", cut)
    assert res.exit_code == 2, res.output
    frames = int(_one_line(res.output, "frames").split()[1])
    assert 0 < frames < 30
    line = _one_line(res.output, "Error:")
    assert line.startswith(f"Error: {cut}: truncated after frame {frames} "), line
    assert line.endswith("-- the lines above describe the frames before it"), line
    assert _run("info", whole).exit_code == 0


def test_info_with_a_bnptrack_channel_mapped_as_measurements_names_it(tmp_path):
    log = tmp_path / "sim.mcap"
    assert _run("simulate", "--seed", "2", "--out", log, "-q").exit_code == 0
    res = _run("info", log, "--topic", "/truth")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == (f"Error: {log}: channel /truth holds bnptrack /truth messages, not "
                                               "measurements: --topic /truth=/measurements cannot be tracked")


# --------------------------------------------------------------------------- output options


def test_a_printed_view_command_quotes_a_path_with_spaces(tmp_path):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    folder = tmp_path / "dir with space"
    folder.mkdir()
    rrd = folder / "my run.rrd"
    res = _run("track", log, "--tracker", "ddp-mb", "--out", folder / "my run.mcap", "--rrd", rrd)
    assert res.exit_code == 0, res.output
    assert _one_line(res.output, "recording").endswith(f"bytes; bnptrack view '{rrd}')")


def test_sink_json_view_command_quotes_the_run_folder():
    from types import SimpleNamespace

    from bnptrack.pipeline.stages.sink_write import SinkWriting

    sink = SimpleNamespace(ctx=SimpleNamespace(out=Path("run one")), sink_cfg=SimpleNamespace(rrd_name="run.rrd"),
                           files=[str(Path("run one") / "run.rrd")])
    assert SinkWriting._view_command(sink) == "bnptrack view 'run one/run.rrd'"
    plain = SimpleNamespace(ctx=SimpleNamespace(out=Path("/o")), sink_cfg=sink.sink_cfg, files=["/o/run.rrd"])
    assert SinkWriting._view_command(plain) == "bnptrack view /o/run.rrd"


@pytest.mark.parametrize(("args", "option"), [
    (["launch", "--out", ""], "--out"),
    (["launch", "--run", ""], "--run"),
    (["simulate", "--out", ""], "--out"),
    (["simulate", "--params", ""], "--params"),
    (["track", "{log}", "--out", ""], "--out"),
    (["track", "{log}", "--rrd", ""], "--rrd"),
    (["track", "{log}", "--params", ""], "--params"),
    (["track", "{log}", "--config", ""], "--config"),
    (["export", "{log}", "--csv", ""], "--csv"),
    (["export", "{log}", "--parquet", ""], "--parquet"),
    (["replay", "{log}", "--params", ""], "--params"),
    (["replay", "{log}", "--out", ""], "--out"),
    (["stage", "sink", "--name", ""], "--name"),
    (["track", "{log}", "--connect", ""], "--connect"),
    (["replay", "{log}", "--connect", ""], "--connect"),
])
def test_an_empty_name_is_refused_naming_the_option(tmp_path, monkeypatch, args, option):
    what = {"--connect": "URL", "--run": "run id"}.get(option, "name")
    _refused_before_writing(tmp_path, monkeypatch, args, f"Error: empty {option}: give a {what}, or leave the option out")


def test_an_empty_required_name_is_refused_without_suggesting_to_leave_it_out():
    res = _run("monitor", "--run", "")
    assert res.exit_code == 2, res.output
    assert res.output.strip() == "Error: empty --run: give a run id"


def test_an_rrd_that_is_the_input_log_names_rrd(tmp_path):
    log = _log(tmp_path / "copy.mcap", sensor="sim0", n=3)
    before = log.read_bytes()
    res = _run("track", log, "--out", tmp_path / "x1.mcap", "--rrd", log, "--overwrite")
    assert res.exit_code == 2, res.output
    assert res.output.strip() == f"Error: --rrd {log}: the output would overwrite the input log {log}"
    assert log.read_bytes() == before


def test_outputs_on_one_file_name_both_options_before_anything_is_printed(tmp_path):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    same = tmp_path / "same.mcap"
    res = _run("track", log, "--out", same, "--rrd", same)
    assert res.exit_code == 2, res.output
    assert res.output.strip() == f"Error: --rrd {same}: the same file as --out; give each output its own name"
    assert not same.exists()


@pytest.mark.parametrize("cmd", ["track", "replay"])
@pytest.mark.parametrize(("args", "window"), [
    (["--start", "200s"], "--start 200s"),
    (["--start", "40f", "--end", "50f"], "--start 40f, --end 50f"),
    (["--start", "1s", "--set", "source.start_s=200"], "source.start_s = 200"),
])
def test_an_empty_window_names_the_options_as_typed(tmp_path, cmd, args, window):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    res = _run(cmd, log, "--out", tmp_path / "out", "-q", *args)
    assert res.exit_code == 2, res.output
    assert res.output.strip() == (f"Error: {log}: no frame in the window {window}; `bnptrack info LOG` lists a "
                                  "log's frames and times")


@pytest.mark.parametrize("cmd", [["launch"], ["stage", "sink"], ["monitor"]])
def test_a_bad_run_id_names_run_as_typed(cmd):
    res = _run(*cmd, "--run", "bad/run")
    assert res.exit_code == 2, res.output
    assert res.output.strip() == ("Error: --run 'bad/run': letters, digits, '_', '.', '-' (first a letter or digit), "
                                  "at most 128 characters (a run id is one Zenoh key chunk)")


@pytest.mark.parametrize(("args", "option"), [
    (["simulate", "--out", "{name}"], "--out"),
    (["track", "{log}", "--out", "{name}"], "--out"),
    (["track", "{log}", "--out", "t.mcap", "--rrd", "{name}"], "--rrd"),
    (["export", "{log}", "--csv", "{name}"], "--csv"),
    (["launch", "--out", "{name}"], "--out"),
])
def test_an_output_under_a_file_says_the_file_is_no_folder(tmp_path, monkeypatch, args, option):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    (tmp_path / "vo.mcap").write_bytes(b"mine")
    monkeypatch.chdir(tmp_path)
    res = _run(*[a.format(log=log, name="vo.mcap/x.mcap") for a in args])
    assert res.exit_code == 2, res.output
    assert res.output.strip() == f"Error: {option} vo.mcap/x.mcap: cannot create it: vo.mcap is a file, not a folder"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap", "vo.mcap"]


@pytest.mark.parametrize(("args", "option"), [
    (["simulate", "--out", "{name}"], "--out"),
    (["track", "{log}", "--out", "{tmp}/t.mcap", "--rrd", "{name}"], "--rrd"),
    (["export", "{log}", "--parquet", "{name}"], "--parquet"),
    (["launch", "--out", "{folder}"], "--out"),
])
def test_an_output_where_no_file_can_be_made_says_so_without_the_temporary_name(tmp_path, args, option):
    if not Path("/proc/self").exists():
        pytest.skip("needs /proc, a folder in which no file can be created")
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    res = _run(*[a.format(log=log, tmp=tmp_path, name="/proc/x.mcap", folder="/proc/x") for a in args])
    assert res.exit_code == 2, res.output
    target = "/proc/x" if args[0] == "launch" else "/proc/x.mcap"
    assert res.output.strip() == f"Error: {option} {target}: cannot write there (/proc: No such file or directory)"


@pytest.mark.parametrize(("args", "message"), [
    (["--csv", "out.parquet"], "--csv out.parquet: a Parquet file's name; give --parquet out.parquet to write Parquet, "
     "or a name that does not end in .parquet"),
    (["--parquet", "p2.csv"], "--parquet p2.csv: a CSV file's name; give --csv p2.csv to write CSV, or a name that "
     "does not end in .csv"),
])
def test_export_refuses_a_table_named_for_the_other_format(tmp_path, monkeypatch, args, message):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    monkeypatch.chdir(tmp_path)
    res = _run("export", log, *args)
    assert res.exit_code == 2, res.output
    assert res.output.strip() == f"Error: {message}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap"]


def test_export_keeps_other_unusual_suffixes(tmp_path):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    run = tmp_path / "run.mcap"
    assert _run("track", log, "--tracker", "ddp-mb", "--out", run, "-q").exit_code == 0
    res = _run("export", run, "--csv", tmp_path / "t.txt")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "t.txt").read_text().startswith("frame,")


@pytest.mark.parametrize(("args", "option"), [
    (["export", "{log}", "--csv", "newdir/"], "--csv"),
    (["export", "{log}", "--parquet", "newdir/"], "--parquet"),
    (["simulate", "--out", "newdir/"], "--out"),
    (["track", "{log}", "--out", "newdir/"], "--out"),
    (["track", "{log}", "--rrd", "newdir/"], "--rrd"),
])
def test_a_file_option_ending_in_a_separator_names_a_folder(tmp_path, monkeypatch, args, option):
    _refused_before_writing(tmp_path, monkeypatch, args, f"Error: {option} newdir/: names a folder; give a file name")


def _refused_before_writing(tmp_path, monkeypatch, args, line):
    """``args`` (``{log}``: a small log in ``tmp_path``) exit 2 with ``line`` alone, writing nothing."""
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    monkeypatch.chdir(tmp_path)
    res = _run(*[a.format(log=log) for a in args])
    assert res.exit_code == 2, res.output
    assert res.output.strip() == line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap"]


def test_a_set_item_a_struct_check_refuses_is_named():
    """A check of the settings' own (not a type's) that names its key first is blamed on the
    --set item that set that key."""
    from bnptrack.pipeline.config import load_pipeline

    with pytest.raises(ValueError) as ei:
        load_pipeline(None, ['run="bad/x"'])
    assert str(ei.value) == ("--set 'run=\"bad/x\"': letters, digits, '_', '.', '-' (first a letter or digit), "
                             "at most 128 characters (a run id is one Zenoh key chunk)")


def test_simulate_never_renames_its_log_onto_a_device_or_a_pipe(tmp_path):
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    res = _run("simulate", "--seed", "1", "--out", pipe, "--overwrite", "-q")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:") == f"Error: --out {pipe}: not a regular file (a device or a pipe); give a file name"
    assert stat.S_ISFIFO(pipe.stat().st_mode)


def test_an_existing_file_that_can_be_written_passes_in_a_folder_that_takes_no_new_file(tmp_path, monkeypatch):
    """A file written in place (track, export) needs the file writable, not its folder; a file
    replaced by a rename (simulate) needs the folder."""
    from bnptrack.pipeline import output_paths

    def no_new_file(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    existing = tmp_path / "kept.mcap"
    existing.write_bytes(b"x")
    monkeypatch.setattr(output_paths.tempfile, "TemporaryFile", no_new_file)
    output_paths.check_writable(existing, "--out")
    with pytest.raises(ValueError, match=rf"^--out {re.escape(str(existing))}: cannot write there \("):
        output_paths.check_writable(existing, "--out", renamed=True)
    with pytest.raises(ValueError, match=r"^--out .*new\.mcap: cannot write there \("):
        output_paths.check_writable(tmp_path / "new.mcap", "--out")


def test_track_names_a_settings_mistake_before_an_existing_output(tmp_path):
    log = _log(tmp_path / "a.mcap", sensor="sim0", n=3)
    out = tmp_path / "t.mcap"
    out.write_bytes(b"an earlier run")
    res = _run("track", log, "--out", out, "--set", "p_detc=0.9")
    assert res.exit_code == 2, res.output
    assert _one_line(res.output, "Error:").startswith("Error: --set 'p_detc=0.9': unknown key 'p_detc' (did you mean 'p_detect'?)")
    res = _run("track", log, "--out", out)
    assert res.exit_code == 2 and _one_line(res.output, "Error:").startswith(f"Error: {out} exists")
    assert out.read_bytes() == b"an earlier run"
