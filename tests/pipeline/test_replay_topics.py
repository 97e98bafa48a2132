"""``replay --topic`` and ``source.topics``: a log whose
channels are named by a foreign sensor replays to the /tracks ``track --topic`` gives on it;
the mapping is a key of the pipeline file, checked at the edge with the errors of ``track``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.config import SourceConfig, load_pipeline, parse_topic_item
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import EXIT_OK, SUMMARY_NAME, source_frames
from bnptrack.sources.mcap_log import iter_frames, read_log
from bnptrack.tracker.config import ConfigError

from testkit import REPO_ROOT, mem_cfg, rename_channels, run_memory_pipeline, strip

VO2017 = REPO_ROOT / "recordings" / "vo2017-s1.mcap"
RENAMES = {"/measurements": "/radar/detections", "/truth": "/gt"}
MAPPING = {"/radar/detections": "/measurements", "/gt": "/truth"}
TOPIC_ARGS = ["--topic", "/radar/detections=/measurements", "--topic", "/gt=/truth"]


@pytest.fixture(scope="module")
def foreign_log(tmp_path_factory) -> Path:
    """The first 12 frames of vo2017-s1 with /measurements on /radar/detections, /truth on /gt."""
    return rename_channels(VO2017, tmp_path_factory.mktemp("logs") / "radar.mcap", RENAMES, n=12)


def _mcap_cfg(tmp_path: Path, log: Path, topics: dict[str, str] | None = None, **extra: str):
    sets = {"source.kind": "'mcap'", "source.log": repr(str(log)), "source.frames": "0", **extra}
    if topics is not None:
        sets["source.topics"] = "{" + ", ".join(f'"{k}" = "{v}"' for k, v in topics.items()) + "}"
    return mem_cfg(tmp_path, **sets)


# --------------------------------------------------------------------------- the key


def test_parse_topic_item_and_the_source_topics_key():
    assert parse_topic_item("/radar/detections=/measurements") == ("/radar/detections", "/measurements")
    assert parse_topic_item("/gt=/truth") == ("/gt", "/truth")
    assert parse_topic_item("/radar/scan") == ("/radar/scan", "/measurements")  # kind from the schema
    for bad in ("=/measurements", "/radar=/tracks", "/radar=measurements"):
        with pytest.raises(ValueError, match=r"expected SRC=/measurements \(or SRC=/truth\)"):
            parse_topic_item(bad)
    cfg = load_pipeline(None, ["source.kind='mcap'", 'source.topics={"/radar/detections" = "/measurements"}'])
    assert cfg.source.topics == {"/radar/detections": "/measurements"}
    with pytest.raises(ConfigError) as exc:  # one line naming the key and the item
        load_pipeline(None, ["source.kind='mcap'", 'source.topics={"/radar" = "/tracks"}'])
    assert "source.topics: '/radar=/tracks': expected SRC=/measurements (or SRC=/truth)" in str(exc.value)
    assert "\n" not in str(exc.value)
    with pytest.raises(ConfigError, match="source.topics: maps the channels of an MCAP log: it needs "
                                          "source.kind = 'mcap'"):
        load_pipeline(None, ['source.topics={"/radar" = "/measurements"}'])  # synthetic source
    assert SourceConfig().topics == {}


def test_track_and_replay_give_the_same_topic_error(foreign_log, tmp_path):
    runner = CliRunner()
    outs = []
    for cmd in ("track", "replay"):
        res = runner.invoke(main, [cmd, str(foreign_log), "--topic", "/radar/detections=/tracks",
                                   "--out", str(tmp_path / cmd)])
        assert res.exit_code == 2
        outs.append(res.output.splitlines()[-1])
        assert not (tmp_path / cmd).exists()
    assert outs[0] == outs[1] == ("Error: Invalid value for --topic: '/radar/detections=/tracks': "
                                  "expected SRC=/measurements (or SRC=/truth)")


def test_launch_of_an_unmapped_foreign_log_is_refused_listing_its_channels(foreign_log, tmp_path):
    """``launch`` with an MCAP source: the check of ``track`` (the channels, how to map one)
    before any stage starts, naming the pipeline file's key."""
    out = tmp_path / "r"
    res = CliRunner().invoke(main, ["launch", "--set", "source.kind='mcap'", "--set",
                                    f"source.log='{foreign_log}'", "--out", str(out), "-q"])
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert "has no /measurements channel" in text
    assert "/radar/detections (bnptrack.Measurements, json, 12 messages)" in text
    assert "--topic /radar/detections=/measurements" in text
    assert 'source.topics = {"SRC" = "/measurements"}' in text
    assert not out.exists()


def test_source_frames_read_the_mapped_channels(foreign_log, tmp_path):
    meta, frames = source_frames(_mcap_cfg(tmp_path, foreign_log, MAPPING))
    got, want = list(frames), list(iter_frames(VO2017))[:12]
    assert meta == {"scenario": "vo2017", "params": "vo2017", "seed": "1"}
    assert [f.frame for f in got] == list(range(1, 13))
    for a, b in zip(got, want):
        assert a.z.tolist() == b.z.tolist() and a.truth.ids == b.truth.ids
    # /measurements only: the frames come without truth
    _, frames = source_frames(_mcap_cfg(tmp_path, foreign_log, {"/radar/detections": "/measurements"}))
    assert [f.truth for f in frames] == [None] * 12


# --------------------------------------------------------------------------- replay == track


def test_memory_pipeline_with_source_topics_equals_track_topic(foreign_log, tmp_path):
    """The pipeline (in memory) over the foreign log with ``source.topics`` records the
    frames and the /tracks that ``bnptrack track --topic`` writes for it."""
    cfg = _mcap_cfg(tmp_path, foreign_log, MAPPING)
    assert run_memory_pipeline(cfg, MemoryNetwork()) == {"sink": EXIT_OK, "tracker": EXIT_OK, "source": EXIT_OK}
    off = tmp_path / "track.mcap"
    res = CliRunner().invoke(main, ["track", str(foreign_log), *TOPIC_ARGS, "--tracker", "ddp-mb", "--set", "sweeps=8",
                                    "--set", "burn_in=2", "--out", str(off), "-q"])
    assert res.exit_code == 0, res.output
    got, want = read_log(Path(cfg.out) / "tracks.mcap"), read_log(off)
    assert [f.frame for f in got.frames] == [f.frame for f in want.frames] == list(range(1, 13))
    assert all(a.truth is not None and a.truth.ids == b.truth.ids for a, b in zip(got.frames, want.frames))
    assert len(got.tracks) == 12 and [strip(e) for e in got.tracks] == [strip(e) for e in want.tracks]
    scores = json.loads((Path(cfg.out) / SUMMARY_NAME).read_text())["scores"]
    assert scores["frames_scored"] == 12  # the mapped /gt arrived as the frames' truth


# --------------------------------------------------------------------------- what the sink decodes


def test_sink_decodes_frames_only_for_a_consumer(tmp_path, monkeypatch):
    """With ``sink.score = false`` and only the MCAP sink (it writes the payloads as received),
    the sink stage converts no frame to numpy and scores nothing; its outputs (tracks.mcap,
    sink.json's scores and counters) equal those of a run that decodes every frame."""
    import dataclasses

    import bnptrack.pipeline.stages.sink_write as sink_stage
    from bnptrack.sinks.sink import SINKS

    calls = []
    real = sink_stage.to_frame
    monkeypatch.setattr(sink_stage, "to_frame", lambda *a: calls.append(1) or real(*a))
    runs = {}
    for decoded in (False, True):
        monkeypatch.setitem(SINKS, "mcap", dataclasses.replace(SINKS["mcap"], decoded=decoded))
        cfg = mem_cfg(tmp_path / str(decoded), frames=10, **{"sink.score": "false"})
        assert run_memory_pipeline(cfg, MemoryNetwork())["sink"] == EXIT_OK
        runs[decoded] = (read_log(Path(cfg.out) / "tracks.mcap"),
                         json.loads((Path(cfg.out) / SUMMARY_NAME).read_text()))
        assert len(calls) == (10 if decoded else 0)
    (log_a, sum_a), (log_b, sum_b) = runs[False], runs[True]
    assert [f.frame for f in log_a.frames] == [f.frame for f in log_b.frames] == list(range(1, 11))
    assert all(a.z.tolist() == b.z.tolist() and a.truth.ids == b.truth.ids for a, b in zip(log_a.frames, log_b.frames))
    assert [strip(e) for e in log_a.tracks] == [strip(e) for e in log_b.tracks]
    assert sum_a["scores"] == sum_b["scores"] and sum_a["scores"]["frames"] == 10
    assert sum_a["scores"]["tracks"] == len(log_a.tracks[-1].tracks) and sum_a["scores"]["labels"] >= 1
    assert (sum_a["frames_written"], sum_a["tracks_written"]) == (sum_b["frames_written"], sum_b["tracks_written"]) == (10, 10)
