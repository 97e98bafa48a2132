"""The Python API's checks of what the caller passes (docs/python.md): each mistake is one
``ConfigError`` line naming the argument as written in the call."""

from __future__ import annotations

import numpy as np
import pytest

import bnptrack
from bnptrack.tracker.config import ConfigError


@pytest.mark.parametrize("call", [
    lambda: bnptrack.track([], scenario="vo2071"),
    lambda: bnptrack.make_tracker(scenario="vo2071"),
    lambda: bnptrack.simulate(scenario="vo2071"),
])
def test_an_unknown_scenario_is_an_error_with_the_close_name(call):
    with pytest.raises(ConfigError, match=r"\(scenario='vo2071'\): unknown scenario \(did you mean 'vo2017'\?\)"):
        call()


def test_a_truncated_log_raises_with_the_run_of_its_readable_frames(tmp_path):
    """The error keeps the estimates of the frames read before the damage (``exc.run``), the
    same as those of the intact log's first frames."""
    frames = bnptrack.simulate("vo2017", seed=1)[:20]
    log = bnptrack.write_log(tmp_path / "whole.mcap", frames, {"scenario": "vo2017", "params": "vo2017"})
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: int(log.stat().st_size * 0.7)])
    whole = bnptrack.track(log, seed=0)
    with pytest.raises(bnptrack.sources.mcap_log.McapLogError, match="truncated after frame") as caught:
        bnptrack.track(cut, seed=0)
    part = caught.value.run.estimates
    assert 0 < len(part) < len(frames)
    assert [[t.label for t in e.tracks] for e in part] == [[t.label for t in e.tracks] for e in whole.estimates[:len(part)]]


@pytest.mark.parametrize("call", [lambda p: bnptrack.track(p), lambda p: bnptrack.read_log(p)])
def test_a_missing_log_is_no_such_file(tmp_path, call):
    missing = tmp_path / "nope.mcap"
    with pytest.raises(ConfigError, match=f"no such file: {missing}$"):
        call(missing)


def test_write_log_and_simulate_replace_a_file_only_with_overwrite(tmp_path):
    frames = bnptrack.simulate("vo2017", seed=1)[:3]
    log = bnptrack.write_log(tmp_path / "a.mcap", frames)
    with pytest.raises(ConfigError, match=r"^write_log: .*a\.mcap exists: pass overwrite=True to replace it"):
        bnptrack.write_log(log, frames[:1])
    with pytest.raises(ConfigError, match=r"^simulate\(out=\.\.\.\): .*a\.mcap exists"):
        bnptrack.simulate("vo2017", seed=1, out=log)
    assert len(bnptrack.read_log(log).frames) == 3  # refused: untouched
    bnptrack.write_log(log, frames[:1], overwrite=True)
    assert len(bnptrack.read_log(log).frames) == 1


@pytest.mark.parametrize(("call", "message"), [
    (lambda: bnptrack.track([], overrides="p_detect=0.9"),
     r"^track\(overrides='p_detect=0\.9'\): expected a list of 'key=value' strings, got a str \(write \['p_detect=0\.9'\]\)$"),
    (lambda: bnptrack.make_tracker(overrides="p_detect=0.9"), r"^make_tracker\(overrides='p_detect=0\.9'\): expected a list"),
    (lambda: bnptrack.simulate(overrides="p_detect=0.9"), r"^simulate\(overrides='p_detect=0\.9'\): expected a list"),
    (lambda: bnptrack.load_params("vo2017", "p_detect=0.9"), r"^load_params\(overrides='p_detect=0\.9'\): expected a list"),
    (lambda: bnptrack.track("x.mcap", topics="/radar/scan"), r"^track\(topics='/radar/scan'\): expected a list of channel names"),
    (lambda: bnptrack.make_tracker(overrides=[0.9]), r"^make_tracker\(overrides=\[0\.9\]\): expected a list of 'key=value' strings$"),
    (lambda: bnptrack.simulate(seed=-1), r"^simulate\(seed=-1\): seed must be an integer >= 0$"),
    (lambda: bnptrack.track([], seed=1.5), r"^track\(seed=1\.5\): seed must be an integer >= 0$"),
    (lambda: bnptrack.track([], lag=True), r"^track\(lag=True\): lag must be an integer >= 0 \(scans\)$"),
    (lambda: bnptrack.track([], lag=2.0), r"^track\(lag=2\.0\): lag must be an integer >= 0 \(scans\)$"),
])
def test_a_str_for_a_list_and_a_bad_seed_name_the_argument(call, message):
    with pytest.raises(ConfigError, match=message):
        call()


def test_load_params_names_its_python_arguments():
    with pytest.raises(ConfigError, match=r"^overrides item 'p_detc=0\.9': unknown key 'p_detc' \(did you mean 'p_detect'\?\)"):
        bnptrack.load_params("vo2017", ["p_detc=0.9"])


def test_a_numpy_integer_is_a_seed():
    assert len(bnptrack.simulate("vo2017", seed=np.int64(1))) == 100


@pytest.mark.parametrize(("frames", "message"), [
    (None, r"^track\(frames=None\): expected a log's path or a list of bnptrack Frames \(bnptrack\.simulate gives one\), got NoneType$"),
    (5, r"^track\(frames=5\): expected a log's path or a list of bnptrack Frames .*, got int$"),
    (b"run.mcap", r"^track\(frames=b'run\.mcap'\): expected a log's path .*, got bytes$"),
    (["a", "b"], r"^track\(frames\): item 0 \('a', type str\) is not a bnptrack Frame \(bnptrack\.simulate and "),
    ((x for x in [1]), r"^track\(frames\): item 0 \(1, type int\) is not a bnptrack Frame"),
])
def test_frames_that_are_not_frames_are_named(frames, message):
    with pytest.raises(ConfigError, match=message):
        bnptrack.track(frames)


def test_a_log_read_whole_is_given_by_its_frames(tmp_path):
    log = bnptrack.write_log(tmp_path / "a.mcap", bnptrack.simulate("vo2017", seed=1)[:3])
    with pytest.raises(ConfigError, match=r"^track\(frames=<LogContents>\): give its \.frames, or the log's path$"):
        bnptrack.track(bnptrack.read_log(log))
    assert len(bnptrack.track(bnptrack.read_log(log).frames).estimates) == 3
    assert len(bnptrack.track(iter(bnptrack.read_log(log).frames)).estimates) == 3


def test_a_numpy_integer_is_a_lag():
    frames = bnptrack.simulate("vo2017", seed=1)[:6]
    run = bnptrack.track(frames, lag=np.int64(2))
    assert len(run.estimates) == 6 and len(run.online) == 6


def test_a_log_written_with_no_frames_says_so_without_a_topic_hint(tmp_path):
    from click.testing import CliRunner

    from bnptrack.pipeline.cli import main

    log = bnptrack.write_log(tmp_path / "none.mcap", [], {"scenario": "vo2017", "params": "vo2017"})
    message = f"{log} has no channels: the log has no frames, so there is nothing to track"
    with pytest.raises(ConfigError, match=f"^track\\('{log}'\\): {message}$"):
        bnptrack.track(log)
    res = CliRunner().invoke(main, ["track", str(log), "-q"])
    assert res.exit_code == 2 and res.output.strip() == f"Error: {message}"
    res = CliRunner().invoke(main, ["info", str(log)])
    assert res.exit_code == 0 and "frames            0 (the log has no channels)\n" in res.output


def test_a_log_without_measurements_names_the_topics_argument(tmp_path):
    from bnptrack.sinks.mcap_writer import McapLogWriter

    frames = bnptrack.simulate("vo2017", seed=1)[:2]
    run = bnptrack.track(frames)
    log = tmp_path / "tracks.mcap"
    with McapLogWriter(log, {}) as writer:
        for est in run.estimates:
            writer.write_tracks(est)
    with pytest.raises(ConfigError, match=r"has no /measurements channel, so there is nothing to track\. Its channels: "
                                          r"/tracks .*map it: topics=\['/radar/detections=/measurements'\]"):
        bnptrack.track(log)


@pytest.mark.parametrize(("text", "message"), [
    ('[sourc]\nlog = "x.mcap"\n', r": unknown key 'sourc' \(did you mean 'source'\?\)$"),
    ('[source]\nlgo = "x.mcap"\n', r": unknown key 'lgo' in \[source\] \(did you mean 'log'\?\)$"),
    ('[source]\nkind = "mcp"\n', r": Invalid enum value 'mcp', not one of mcap, synthetic \(did you mean 'mcap'\?\) "
                                 r"- at `\$\.source\.kind`$"),
    ('[source]\nkind = "mcap"\n[source.topics]\n"/a" = 5\n', r": Expected `str`, got `int` - at `\$\.source\.topics\.\"/a\"`$"),
])
def test_a_misspelt_pipeline_table_or_key_gets_the_close_name(tmp_path, text, message):
    from bnptrack.pipeline.config import load_pipeline

    path = tmp_path / "pipeline.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=f"^{path}{message}"):
        load_pipeline(path)


def test_a_misspelt_key_of_a_params_list_item_lists_the_known_keys(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text('extends = "vo2017"\n[[birth]]\nweight = 1\n')
    with pytest.raises(ConfigError, match=r": unknown key 'weight' in birth\[0\] \(known: r, mean, std\)$"):
        bnptrack.load_params(path)


def test_info_on_a_log_without_a_record_names_the_default_model(tmp_path):
    from click.testing import CliRunner

    from bnptrack.pipeline.cli import main

    log = bnptrack.write_log(tmp_path / "bare.mcap", bnptrack.simulate("vo2017", seed=1)[:2])
    res = CliRunner().invoke(main, ["info", str(log)])
    assert res.exit_code == 0, res.output
    assert ("record            none (no bnptrack.scenario metadata: track uses the vo2017 model unless "
            "--params says otherwise)") in res.output


def test_a_misspelt_sensor_in_overrides_names_the_overrides_item():
    frames = bnptrack.simulate("vo2017", seed=1)[:3]
    with pytest.raises(ConfigError, match=r"^overrides item 'sensors\.sm0\.x=5' declares sensor 'sm0', .* "
                                          r"\(did you mean overrides item 'sensors\.sim0\.x=5'\?\)$"):
        bnptrack.track(frames, overrides=["sensors.sm0.x=5"])
