"""The examples of docs/formats.md that are a command's output are what the command gives now:
the messages of recordings/vo2017-s1.mcap and recordings/snr-s1.mcap, the frame-12 `/tracks`
message of `bnptrack track recordings/vo2017-s1.mcap --tracker ddp`, the truncated-file
session, the diagnostics table, and the scores of the README's `bnptrack launch` summary.  A
failure shows the values the docs should show."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from bnptrack.pipeline.cli import main
from bnptrack.sources.mcap_log import read_metadata

ROOT = Path(__file__).resolve().parents[2]
FORMATS = (ROOT / "docs" / "formats.md").read_text()
VO = ROOT / "recordings" / "vo2017-s1.mcap"


def _block_after(heading: str, lang: str = "json") -> str:
    """The first ```lang block after the paragraph that starts with ``heading``."""
    at = FORMATS.index(heading)
    return re.search(rf"```{lang}\n(.*?)```", FORMATS[at:], re.S).group(1)


def _message(path: Path, topic: str, frame: int) -> dict:
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(log_time_order=False):
            if ch.topic == topic:
                data = json.loads(msg.data)
                if data["frame"] == frame:
                    return data
    raise AssertionError(f"{path}: no {topic} message of frame {frame}")


def test_frame_1_messages_of_the_recordings():
    meas = _message(VO, "/measurements", 1)
    assert "(12 measurements; trimmed to 3)" in FORMATS and len(meas["z"]) == 12
    assert json.loads(_block_after("Example: frame 1 of `recordings/vo2017-s1.mcap` (12")) == \
        dict(meas, z=meas["z"][:3])
    assert json.loads(_block_after("Example: frame 1 of `recordings/vo2017-s1.mcap` (complete)")) == \
        _message(VO, "/truth", 1)
    snr = _message(ROOT / "recordings" / "snr-s1.mcap", "/measurements", 1)
    assert f"`recordings/snr-s1.mcap`, {len(snr['z'])} measurements; trimmed to 3)" in FORMATS
    assert json.loads(_block_after("A range-only scan (frame 1")) == dict(snr, z=snr["z"][:3])
    assert json.loads(_block_after("Example (`recordings/vo2017-s1.mcap`)")) == read_metadata(VO)


def test_frame_12_tracks_example(tmp_path):
    heading = "Example: frame 12 of a `bnptrack track recordings/vo2017-s1.mcap --tracker ddp` run"
    assert heading in FORMATS
    out = tmp_path / "ddp.mcap"
    res = CliRunner().invoke(main, ["track", str(VO), "--tracker", "ddp", "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    got = _message(out, "/tracks", 12)
    n_z = len(_message(out, "/measurements", 12)["z"])
    shown = dict(got, tracks=got["tracks"][:1], assignments=got["assignments"][:12],
                 assignment_prob=got["assignment_prob"][:12])
    doc = json.loads(_block_after(heading))
    doc["diagnostics"]["ms"] = shown["diagnostics"]["ms"]  # a wall-clock time
    assert doc == shown, "docs/formats.md should show:\n" + json.dumps(shown)
    prose = " ".join(FORMATS[FORMATS.index(heading):].split())
    assert f"run ({len(got['tracks'])} tracks and {n_z} measurements in the file;" in prose
    pmf = got["cardinality_pmf"]
    mean = sum(n * p for n, p in enumerate(pmf))
    assert f"has mean {mean:.2f} and its most probable value (MAP) is {pmf.index(max(pmf))}." in prose
    assert (f"the state holds {got['diagnostics']['n_clusters']:.0f} clusters (`n_clusters`) and the pmf "
            f"has {len(pmf)} entries") in " ".join(FORMATS.split())


def test_truncated_file_session(tmp_path, monkeypatch):
    lines = _block_after("It prints the summary, then reports the error", "console").splitlines()
    head = shlex.split(lines[0].strip().removeprefix("$ "))
    track = shlex.split(lines[1].strip().removeprefix("$ "))
    assert head[:2] == ["head", "-c"] and head[4:] == [">", "/tmp/cut.mcap"] and track[:2] == ["bnptrack", "track"]
    monkeypatch.chdir(ROOT)
    cut, cut_out = tmp_path / "cut.mcap", tmp_path / "cut-out.mcap"
    cut.write_bytes((ROOT / head[3]).read_bytes()[: int(head[2])])
    args = [str(cut) if a == "/tmp/cut.mcap" else str(cut_out) if a == "/tmp/cut-out.mcap" else a
            for a in track[1:]]
    res = CliRunner().invoke(main, args)
    shown = [line.strip() for line in lines[2:] if line.strip() not in ("...", "")]
    output = res.output.replace(str(cut_out), "/tmp/cut-out.mcap").replace(str(cut), "/tmp/cut.mcap")
    summary = [" ".join(line.split()) for line in output.splitlines()]
    assert " ".join(shown[0].split()) in summary, output  # the frames line
    assert shown[1] in output.splitlines(), output  # the error line
    assert shown[2:] == ["$ echo $?", str(res.exit_code)]


def _diagnostics_table() -> dict[str, tuple[set[str], str]]:
    """docs/formats.md's diagnostics table: key -> (trackers, "when")."""
    section = FORMATS[FORMATS.index("### Diagnostics"):FORMATS.index("### The cardinality distribution")]
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+) \| ([^|]+) \|", section, re.M)
    return {key: (set(re.findall(r"`([\w-]+)`", who)) or {"every tracker"}, when.strip())
            for key, who, when in rows}


# the runs that make every documented key appear: tracker -> (settings -> the "when" they stand for)
_OPTIONS = {
    "ddp": {("tracker.objects.learn_births=true",): "`learn_births` or `learn_birth_velocity` on",
            ("tracker.crossing_scans=3",): "`crossing_scans` > 0"},
    "dpyp": {("tracker.objects.learn_birth_velocity=true",): "`learn_births` or `learn_birth_velocity` on",
             ("tracker.crossing_scans=3",): "`crossing_scans` > 0"},
    "ddp-mb": {("tracker.learn_births=true",): "`learn_births` or `learn_birth_velocity` on"},
    "dpyp-mb": {("tracker.learn_birth_velocity=true",): "`learn_births` or `learn_birth_velocity` on"},
    "glmb": {},
}


@pytest.fixture(scope="module")
def short_frames():
    import bnptrack

    return bnptrack.simulate("vo2017", 1)[:4]


def _keys(frames, tracker: str, overrides: tuple[str, ...] = ()) -> set[str]:
    import bnptrack

    run = bnptrack.track(frames, tracker, scenario="vo2017", overrides=overrides)
    keys = {frozenset(e.diagnostics) for e in run.estimates}
    assert len(keys) == 1, f"{tracker}: the keys change from frame to frame"
    return set(next(iter(keys)))


@pytest.mark.parametrize("tracker", list(_OPTIONS))
def test_diagnostics_table_lists_the_keys_each_tracker_writes(short_frames, tracker):
    table = _diagnostics_table()
    mine = {k: when for k, (who, when) in table.items() if tracker in who or "every tracker" in who}
    assert _keys(short_frames, tracker) == {k for k, when in mine.items() if when == "always"}
    for overrides, when in _OPTIONS[tracker].items():
        assert _keys(short_frames, tracker, overrides) == \
            {k for k, w in mine.items() if w in ("always", when)}, overrides
    assert {w for w in mine.values()} <= {"always", *_OPTIONS[tracker].values()}


def test_diagnostics_table_covers_every_tracker(short_frames):
    from bnptrack.tracker.registry import TRACKERS

    aliases = {"ddp-groups": "ddp", "dpyp-groups": "dpyp"}
    assert set(TRACKERS) == set(_OPTIONS) | set(aliases)
    for alias, name in aliases.items():
        assert _keys(short_frames, alias) == _keys(short_frames, name)
    assert "aliases `ddp-groups` and `dpyp-groups` write what `ddp` and `dpyp` write" in " ".join(FORMATS.split())
    table = _diagnostics_table()
    assert {t for who, _ in table.values() for t in who} == set(_OPTIONS) | {"every tracker"}


def test_readme_launch_summary_scores():
    """The README's `bnptrack launch` summary: its default run (synthetic vo2017 seed 1 -> `ddp`
    seed 0) gives these scores; the same run through the Python API."""
    import numpy as np

    import bnptrack
    from bnptrack.sinks.metrics import ospa2_series

    readme = (ROOT / "README.md").read_text()
    block = re.search(r"`bnptrack launch --out [^`]+`.*?```console\n(.*?)```", readme, re.S).group(1)
    shown = dict(re.match(r"(\S.*?)\s{2,}(.*)$", line).groups() for line in block.splitlines())
    frames = bnptrack.simulate("vo2017", 1)
    run = bnptrack.track(frames, "ddp", scenario="vo2017")
    est = [{t.label: np.asarray(t.state)[[0, 2]] for t in e.tracks} for e in run.estimates]
    truth = [{i: s[[0, 2]] for i, s in zip(f.truth.ids, f.truth.states)} for f in frames]
    labels = {t.label for e in run.estimates for t in e.tracks}
    assert shown["frames"] == "100 (100 /tracks; gaps: none)"
    assert shown["mean OSPA"] == f"{run.mean_ospa:.2f} m (c=100, p=1, position; 100 frames)"
    assert shown["mean OSPA(2)"] == f"{np.mean(ospa2_series(est, truth, 10)):.2f} m (window 10 frames)"
    assert shown["mean card. error"] == f"{run.mean_cardinality_error:.2f}"
    last = run.estimates[-1].tracks
    assert shown["final tracks"] == f"{len(last)}: {' '.join(t.name for t in last)} ({len(labels)} labels in all)"
