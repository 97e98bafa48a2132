"""Tests of the ``bnptrack`` command line (pipeline/cli.py) and pipeline/offline.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.resolve import resolve_params, split_overrides
from bnptrack.sources.mcap_log import iter_frames, iter_tracks, read_log, read_metadata
from bnptrack.sources.scenarios import get_scenario, scenario_names
from bnptrack.tracker.config import ConfigError

# a fast tracker for tests: few Gibbs sweeps
FAST_SET = ["--set", "tracker.sweeps=8", "--set", "tracker.burn_in=2"]
FAST = ["--tracker", "ddp-mb", *FAST_SET]  # the single-level tracker


def invoke(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args])


def messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [
            (ch.topic, msg.log_time, bytes(msg.data))
            for _, ch, msg in make_reader(f).iter_messages(log_time_order=False)
        ]


@pytest.fixture(scope="module")
def vo_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("logs") / "vo2017-s1.mcap"
    res = invoke("simulate", "--scenario", "vo2017", "--params", "vo2017", "--seed", 1, "--out", out)
    assert res.exit_code == 0, res.output
    return out


@pytest.fixture(scope="module")
def vo_tracks(vo_log, tmp_path_factory):
    out = tmp_path_factory.mktemp("tracks") / "vo2017-s1-ddp.mcap"
    res = invoke("track", vo_log, "--tracker", "ddp-mb", *FAST_SET, "--out", out)
    return res, out


# --------------------------------------------------------------------------- help


@pytest.mark.parametrize(
    "args, expected",
    [
        ([], ["simulate", "track", "schema", "Example"]),
        (["simulate"], ["--scenario", "--params", "--set", "--snr", "--seed", "--out", "--quiet", "Example"]),
        (["track"], ["LOG", "--tracker", "--config", "--params", "--set", "--seed", "--out", "--quiet", "Example"]),
        (["schema"], ["TOPIC", "/tracks", "Example"]),
    ],
)
def test_help_mentions_options(args, expected):
    res = invoke(*args, "--help")
    assert res.exit_code == 0, res.output
    for word in expected:
        assert word in res.output, word


@pytest.mark.slow  # the command line in a process of its own
def test_python_dash_m_pipeline():
    res = subprocess.run(
        [sys.executable, "-m", "bnptrack", "--help"], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr
    assert "simulate" in res.stdout and "track" in res.stdout


@pytest.mark.slow  # the command line in a process of its own
def test_error_is_one_line_on_stderr(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "bnptrack", "simulate", "--set", "p_detect=2", "--out", str(tmp_path / "x.mcap")],
        capture_output=True, text=True, timeout=60,
    )
    assert res.returncode == 2
    assert res.stdout == ""
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error:") and "p_detect" in lines[0]


# --------------------------------------------------------------------------- simulate


@pytest.mark.parametrize("scenario", scenario_names())
def test_simulate_every_scenario(scenario, tmp_path):
    out = tmp_path / f"{scenario}.mcap"
    res = invoke("simulate", "--scenario", scenario, "--params", "vo2017", "--seed", 3, "--out", out)
    assert res.exit_code == 0, res.output
    frames = list(iter_frames(out))
    sc = get_scenario(scenario, seed=3)  # a generated scene: drawn from the run seed
    assert len(frames) == sc.K  # every scan of the scene (100 but for groups-py's 50)
    assert [f.frame for f in frames] == list(range(1, sc.K + 1))
    assert all(f.truth is not None for f in frames)
    assert all(f.kind == sc.kind for f in frames)
    assert sum(len(f.truth.ids) for f in frames) == int(sc.cardinality().sum())
    meta = read_metadata(out)
    assert meta["scenario"] == scenario
    assert meta["params"] == "vo2017"
    assert meta["seed"] == "3"
    if scenario == "snr":  # the scenario's -3 dB default is recorded
        assert float(meta["snr_db"]) == -3.0
    else:
        assert "snr_db" not in meta
    assert "overrides" not in meta
    n_meas = sum(f.n_measurements for f in frames)
    assert f"{n_meas}" in res.output
    assert str(out) in res.output
    assert f"target-scans      {int(sc.cardinality().sum())}" in res.output


def test_simulate_summary_vo2017(vo_log):
    res = invoke("simulate", "--scenario", "vo2017", "--seed", 1, "--out", vo_log.with_name("again.mcap"))
    assert res.exit_code == 0
    for word in ("scenario", "params", "seed", "frames", "measurements", "per frame", "target-scans", "645", "bytes"):
        assert word in res.output, word


def test_simulate_same_seed_same_messages(tmp_path):
    a, b, c = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "c.mcap"
    for out, seed in ((a, 7), (b, 7), (c, 8)):
        res = invoke("simulate", "--scenario", "proximity", "--seed", seed, "--out", out, "--quiet")
        assert res.exit_code == 0, res.output
        assert res.output == ""
    assert messages(a) == messages(b)
    assert len(messages(a)) == 200
    assert messages(a) != messages(c)


def test_simulate_default_out_and_metadata_extras(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = invoke("simulate", "--scenario", "dpy5", "--seed", 4, "--snr", -5, "--set", "clutter_rate=5", "-q")
    assert res.exit_code == 0, res.output
    out = tmp_path / "recordings" / "dpy5-s4.mcap"
    assert out.exists()
    meta = read_metadata(out)
    assert meta == {
        "scenario": "dpy5", "params": "vo2017", "seed": "4", "snr_db": "-5.0", "overrides": "clutter_rate=5",
    }
    # tracking such a log picks the same model parameters back up
    choice = resolve_params(None, meta)
    assert choice.params.snr_db == -5.0 and choice.params.clutter_rate == 5.0


def test_simulate_bad_override_exit_2(tmp_path):
    res = invoke("simulate", "--set", "p_detect=2", "--out", tmp_path / "x.mcap")
    assert res.exit_code == 2
    assert "p_detect" in res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)


def test_simulate_unknown_params_file_exit_2(tmp_path):
    res = invoke("simulate", "--params", tmp_path / "missing.toml", "--out", tmp_path / "x.mcap")
    assert res.exit_code == 2
    assert "missing.toml" in res.output


def test_simulate_params_file(tmp_path):
    toml = tmp_path / "mine.toml"
    toml.write_text('name = "mine"\nclutter_rate = 0.0\np_detect = 1.0\n')
    out = tmp_path / "x.mcap"
    res = invoke("simulate", "--scenario", "dpy5", "--params", toml, "--out", out, "-q")
    assert res.exit_code == 0, res.output
    frames = list(iter_frames(out))
    # no clutter, P_D = 1 inside the field: one measurement per visible target
    assert sum(f.n_measurements for f in frames) <= sum(len(f.truth.ids) for f in frames)
    assert read_metadata(out)["params"] == str(toml)


# --------------------------------------------------------------------------- track


def test_track_writes_tracks(vo_log, vo_tracks):
    res, out = vo_tracks
    assert res.exit_code == 0, res.output
    assert "OSPA" in res.output
    for word in ("tracker", "frames", "final tracks", "ms per frame", "median", "p95", str(out)):
        assert word in res.output, word
    assert "from the log's bnptrack.scenario record" in res.output
    frames = list(iter_frames(out))
    tracks = list(iter_tracks(out))
    assert len(frames) == len(tracks) == 100
    inputs = list(iter_frames(vo_log))
    for f_in, f_out, est in zip(inputs, frames, tracks):
        assert est.frame == f_out.frame == f_in.frame
        assert len(est.assignments) == f_in.n_measurements == len(est.assignment_prob)
        assert {a for a in est.assignments if a is not None} <= set(est.labels)
        assert (f_out.z == f_in.z).all()
        assert f_out.truth is not None and f_out.truth.ids == f_in.truth.ids
        assert "ms" in est.diagnostics
    meta = read_metadata(out)
    assert meta["scenario"] == "vo2017" and meta["seed"] == "1"
    assert meta["tracker"] == "ddp-mb" and meta["tracker_seed"] == "0"
    # one /tracks message per frame on the channel
    assert sum(1 for topic, _, _ in messages(out) if topic == "/tracks") == 100


def test_track_default_out_and_dpyp(tmp_path):
    log = tmp_path / "d.mcap"
    assert invoke("simulate", "--scenario", "dpy5", "--seed", 2, "--out", log, "-q").exit_code == 0
    res = invoke("track", log, "--tracker", "dpyp-mb", *FAST_SET, "--seed", 5, "--end", "10f", "--quiet")
    assert res.exit_code == 0, res.output
    assert res.output == ""
    out = tmp_path / "d-dpyp-mb.tracks.mcap"
    assert len(list(iter_tracks(out))) == 10
    assert read_metadata(out)["tracker_seed"] == "5"


def test_track_same_seed_same_tracks(vo_log, vo_tracks, tmp_path):
    _, first = vo_tracks
    out = tmp_path / "again.mcap"
    assert invoke("track", vo_log, *FAST, "--out", out, "-q").exit_code == 0
    strip = lambda est: ([t.label for t in est.tracks], [t.state.tolist() for t in est.tracks], est.assignments)
    assert [strip(e) for e in iter_tracks(out)] == [strip(e) for e in iter_tracks(first)]


def test_track_params_from_log_metadata(tmp_path):
    log = tmp_path / "paper.mcap"
    assert invoke("simulate", "--scenario", "dpy5", "--params", "paper", "--out", log, "-q").exit_code == 0
    assert read_metadata(log)["params"] == "paper"
    res = invoke("track", log, *FAST, "--end", "10f", "--out", tmp_path / "t.mcap")
    assert res.exit_code == 0, res.output
    line = next(l for l in res.output.splitlines() if l.startswith("params"))
    assert "paper" in line and "from the log" in line
    # an explicit --params wins
    res = invoke("track", log, *FAST, "--end", "10f", "--params", "vo2017", "--out", tmp_path / "t2.mcap")
    line = next(l for l in res.output.splitlines() if l.startswith("params"))
    assert "vo2017" in line and "--params" in line


def test_track_log_without_metadata_uses_default(vo_log, tmp_path):
    from bnptrack.sinks.mcap_writer import McapLogWriter

    bare = tmp_path / "bare.mcap"
    with McapLogWriter(bare) as w:  # no metadata record, no truth
        for f in list(iter_frames(vo_log))[:10]:
            w.write_frame(type(f)(f.frame, f.stamp_ns, f.sensor, f.kind, f.z))
    res = invoke("track", bare, *FAST, "--out", tmp_path / "t.mcap")
    assert res.exit_code == 0, res.output
    assert "vo2017 (default" in res.output
    assert "no /truth" in res.output


def test_track_truncated_log(vo_log, tmp_path):
    data = vo_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    out = tmp_path / "cut-tracks.mcap"
    res = invoke("track", cut, *FAST, "--out", out)
    assert res.exit_code == 2
    assert "Traceback" not in res.output
    err_lines = [l for l in res.output.splitlines() if l.startswith("Error:")]
    assert len(err_lines) == 1 and str(cut) in err_lines[0] and "truncated" in err_lines[0]
    got = read_log(out)  # the output itself is complete and valid
    assert got.error is None
    assert 10 < len(got.frames) < 100
    assert len(got.tracks) == len(got.frames)
    assert [e.frame for e in got.tracks] == list(range(1, len(got.frames) + 1))
    assert f"processed and wrote the {len(got.frames)} readable frame(s)" in err_lines[0]


def test_track_unknown_set_key(vo_log, tmp_path):
    res = invoke("track", vo_log, "--set", "no_such_key=3", "--out", tmp_path / "t.mcap")
    assert res.exit_code == 2
    assert "no_such_key" in res.output
    res = invoke("track", vo_log, "--set", "tracker.p_detect=0.5", "--out", tmp_path / "t.mcap")
    assert res.exit_code == 2
    assert "p_detect" in res.output


def test_track_bad_config_and_same_out(vo_log, tmp_path):
    res = invoke("track", vo_log, "--config", "nope", "--out", tmp_path / "t.mcap")
    assert res.exit_code == 2 and "nope" in res.output
    bad = tmp_path / "bad.toml"
    bad.write_text("sweeps = 0\n")
    res = invoke("track", vo_log, "--config", bad, "--out", tmp_path / "t.mcap")
    assert res.exit_code == 2 and "bad.toml" in res.output
    res = invoke("track", vo_log, "--out", vo_log)
    assert res.exit_code == 2 and "overwrite" in res.output
    res = invoke("track", tmp_path / "missing.mcap")
    assert res.exit_code == 2 and "missing.mcap" in res.output


def test_track_config_file(vo_log, tmp_path):
    cfg = tmp_path / "fast.toml"
    cfg.write_text("sweeps = 6\nburn_in = 1\n")
    res = invoke("track", vo_log, "--tracker", "ddp-mb", "--config", cfg, "--end", "10f", "--out", tmp_path / "t.mcap")
    assert res.exit_code == 0, res.output
    assert "fast.toml" in res.output


def test_split_overrides_routing():
    p, t = split_overrides(["p_detect=0.9", "sweeps=8", "params.clutter_rate=3", "tracker.alpha=0.2"])
    assert p == ("p_detect=0.9", "clutter_rate=3")
    assert t == ("sweeps=8", "alpha=0.2")
    with pytest.raises(ConfigError, match="bogus"):
        split_overrides(["bogus=1"])
    with pytest.raises(ConfigError, match="key=value"):
        split_overrides(["novalue"])


# --------------------------------------------------------------------------- schema


@pytest.mark.parametrize("topic", ["/tracks", "/measurements", "truth"])
def test_schema_prints_json(topic):
    res = invoke("schema", topic)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert "$defs" in doc


def test_schema_tracks_fields():
    doc = json.loads(invoke("schema", "/tracks").output)
    props = doc["$defs"]["TracksMsg"]["properties"]
    assert {"v", "run", "frame", "stamp_ns", "tracks", "assignments", "assignment_prob"} <= set(props)


def test_schema_unknown_topic():
    res = invoke("schema", "/nope")
    assert res.exit_code == 2 and "/nope" in res.output
    res = invoke("schema", "/track")
    assert res.exit_code == 2 and "unknown topic '/track' (did you mean '/tracks'?)" in res.output


def test_an_unknown_tracker_name_gets_a_suggestion():
    from bnptrack.tracker.registry import kind

    with pytest.raises(ValueError, match=r"^unknown tracker 'ddpp' \(did you mean 'ddp'\?\); valid trackers: ddp, "):
        kind("ddpp")


def test_resolve_params_applies_the_logs_scenario_defaults():
    """A log simulated from a scenario is tracked with that scenario's defaults (birth regions,
    SNR, range clutter), as ``simulate`` and ``experiment`` use them: proximity's birth region is
    its path's entry point, not the parameter set's; snr's -3 dB and 2 range-clutter per scan."""
    prox = resolve_params(None, {"scenario": "proximity", "params": "vo2017", "seed": "1"})
    assert [(b.mean[0], b.mean[2]) for b in prox.params.birth] == [(-900.0, 600.0)]
    assert "scenario proximity: 1 birth regions" in prox.reason
    snr = resolve_params("vo2017", {"scenario": "snr", "params": "paper", "seed": "1"})
    assert snr.params.snr_db == -3.0 and snr.params.range_clutter_rate == 2.0
    plain = resolve_params(None, {"params": "vo2017"})
    assert plain.params.snr_db is None and plain.params.range_clutter_rate is None


@pytest.mark.slow
def test_track_finds_objects_anywhere_in_a_log_without_a_record(tmp_path):
    """A user's own log: objects born anywhere (a random scene, seed 7), written with no
    bnptrack.scenario record, tracked with the defaults and no flags.  Measured: mean OSPA
    31.2 m, 986 reported track-scans for 1044 object-scans; before births anywhere (the default
    set carried Vo's four birth regions, H weighed the rest 0.1) 68.5 m with 4 final tracks."""
    from bnptrack.sinks.mcap_writer import McapLogWriter
    from bnptrack.sources.synthetic import simulate_all
    from bnptrack.tracker.models.params import load_params

    sc = get_scenario("random", seed=7)
    frames = simulate_all(sc, sc.adapt_params(load_params("vo2017")), 7)
    log = tmp_path / "own.mcap"
    with McapLogWriter(log, None) as w:
        for f in frames:
            w.write_frame(f)
    res = invoke("track", str(log), "--out", str(tmp_path / "t.mcap"))
    assert res.exit_code == 0, res.output
    assert "no bnptrack.scenario record" in res.output
    ospa = float(res.output.split("mean OSPA")[1].split()[0])
    assert ospa < 40.0, res.output
    tracks = [len(t.tracks) for t in iter_tracks(tmp_path / "t.mcap")]
    truth = [len(f.truth.ids) for f in frames]
    assert abs(sum(tracks) - sum(truth)) < 0.15 * sum(truth)


# --------------------------------------------------------------------------- resolver


def test_tracker_setup_resolves_once_and_writes_the_output_record():
    """params from the record (with the scenario's defaults), the preset, the --set items
    (routed to params and settings), the tracker and the output record, in one call."""
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.tracker.bnp import TRACKER_PRESETS

    meta = {"scenario": "snr", "params": "vo2017", "seed": "4", "snr_db": "-5.0"}
    s = tracker_setup("ddp-mb", config="ddp-mb-snr", overrides=("p_detect=0.8", "sweeps=7"), metadata=meta, seed=3)
    assert (s.params.p_detect, s.params.snr_db, s.params.range_clutter_rate) == (0.8, -5.0, 2.0)
    assert s.config.sweeps == 7 and s.config.burn_in == TRACKER_PRESETS["ddp-mb-snr"].burn_in
    assert s.tracker.name == "ddp-mb" and s.tracker.params == s.params
    assert s.metadata == {**meta, "tracker": "ddp-mb", "tracker_seed": "3", "tracker_params": "vo2017",
                          "tracker_config": "ddp-mb-snr", "tracker_overrides": "p_detect=0.8;sweeps=7"}
    assert s.describe_config() == "preset ddp-mb-snr; --set sweeps=7"
    assert s.describe_params().startswith("vo2017 (from the log's bnptrack.scenario record; scenario snr")
    assert meta == {"scenario": "snr", "params": "vo2017", "seed": "4", "snr_db": "-5.0"}  # not mutated


def test_tracker_setup_takes_resolved_params_as_given():
    """Experiments pass the simulation's parameters: used unchanged, no record needed."""
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.tracker.models.params import load_params

    p = load_params("vo2017", ["clutter_rate=7"])
    s = tracker_setup("glmb", params=p)
    assert s.params is p and s.tracker.name == "glmb" and s.choice.source == "given"
    assert s.metadata == {"tracker": "glmb", "tracker_seed": "0", "tracker_params": "given",
                          "tracker_config": "glmb"}


def test_split_overrides_without_a_settings_class_knows_every_registered_tracker():
    """No tracker's settings class is the default: a field of the two-level trackers'
    GroupConfig routes to the tracker settings, but not when the tracker is a BNP one."""
    from bnptrack.tracker.bnp import BnpConfig

    assert split_overrides(["within_std=3", "max_hypotheses=9"]) == ((), ("within_std=3", "max_hypotheses=9"))
    with pytest.raises(ConfigError, match="within_std"):
        split_overrides(["within_std=3"], BnpConfig)


def test_choices_come_from_the_registries():
    from bnptrack.pipeline.cli.offline_commands import track
    from bnptrack.pipeline.cli.pipeline_commands import stage
    from bnptrack.pipeline.cli.tools import experiment
    from bnptrack.pipeline.experiments import EXPERIMENTS
    from bnptrack.tracker.registry import TRACKERS

    assert set(main.commands) == {"simulate", "track", "info", "export", "view", "experiment", "schema",
                                  "launch", "replay", "stage", "router", "monitor"}
    assert list(experiment.params[0].type.choices) == list(EXPERIMENTS)
    assert list(stage.params[0].type.choices) == ["source", "tracker", "sink"]
    assert list(next(p for p in track.params if p.name == "tracker_name").type.choices) == list(TRACKERS)
    res = invoke("track", "--help")
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    for name in ("ddp-groups", "ddp-snr", "ddp-proximity", "GroupConfig", "GlmbConfig"):
        assert name in flat.replace("- ", "-"), name
