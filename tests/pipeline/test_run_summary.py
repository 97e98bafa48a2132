"""``sink.json`` as a typed :class:`RunSummary`: its bytes are those of the document it
replaces (same keys, same order, same layout), it reads back, and a file that lacks fields,
has more (the launcher's ``eos_conflict``), belongs to another run or is not JSON reads as
what it is."""

import json

import msgspec
import pytest

from bnptrack.pipeline.outcome import describe_missing
from bnptrack.pipeline.progress import describe_latency, describe_rejected
from bnptrack.pipeline.stages.summary import RunSummary, SummaryError, load_summary, read_summary

#: A sink.json document as the sink stage writes it: every key, in the order written.
DOC = {
    "run": "r1", "complete": True, "frames_written": 9, "tracks_written": 8, "last_seq": 8,
    "gaps": {"measurements": [], "truth": [], "tracks": [5]}, "output_complete": False,
    "missing": [{"topic": "/tracks", "seqs": [5], "why": "no /tracks from the tracker (gap)"}],
    "recovered_frames": 0, "source_error": "", "source_eos": {"last_seq": 8, "frames": 9}, "counters": {"received": 27, "rejected": 1, "duplicates": 2},
    "restarted": False, "rejected_by_topic": {"measurements": 1}, "dropped": 0, "zenoh_misses": 0,
    "files": ["/o/tracks.mcap", "/o/sink.json"], "scores": {
        "frames": 9, "frames_scored": 9, "ospa": 12.5, "ospa2": 20.25, "cardinality_error": 0.25, "tracks": 2,
        "names": ["T1.4", "T3.0"], "labels": 3, "last_ospa": 11.0, "c": 100.0, "p": 1.0, "ospa2_window": 10},
    "view": "bnptrack view /o/run.rrd", "throughput_fps": 9.75, "t_first_pub_ns": 1_000, "t_last_recv_ns": 2_000,
    "latency": {"timed_frames": 8, "excluded": {"from_caches": 0, "recovered": 0}},
}


def test_the_bytes_are_those_of_the_document():
    s = RunSummary.of(DOC)
    assert s.encode() == msgspec.json.format(msgspec.json.encode(DOC), indent=1)
    # every field in its declared order; the launcher's eos_conflict (last) only when it is set
    assert list(json.loads(s.encode())) == list(DOC) == list(RunSummary.__struct_fields__)[:-1]
    marked = msgspec.structs.replace(s, eos_conflict="a forged end of stream")
    assert list(json.loads(marked.encode())) == [*DOC, "eos_conflict"]


def test_it_reads_back(tmp_path):
    path = tmp_path / "sink.json"
    path.write_bytes(RunSummary.of(DOC).encode())
    s = read_summary(path, "r1")
    assert s == RunSummary.of(DOC)
    assert s.all_gaps() == [5] and s.frames_written == 9 and s.files[0] == "/o/tracks.mcap"
    assert s.scores.ospa2 == 20.25 and s.scores.names == ("T1.4", "T3.0")
    assert read_summary(path, "another-run") is None
    assert read_summary(tmp_path / "none.json") is None


def test_a_short_or_broken_file(tmp_path):
    short = tmp_path / "short.json"
    short.write_text('{"run": "r1", "complete": true, "eos_conflict": "a forged end of stream"}')
    s = read_summary(short, "r1")
    assert s.complete and s.frames_written == 0 and s.last_seq == -1 and s.files == [] and s.source_eos is None
    bad = tmp_path / "bad.json"
    bad.write_text('{"run": "r1", "frames_written": "nine"}')
    assert read_summary(bad) is None
    bad.write_text("{not json")
    assert read_summary(bad) is None
    with pytest.raises(msgspec.ValidationError, match="frames_written"):
        RunSummary.of({"frames_written": "nine"})


#: A sink.json as a person would write it by hand: some keys, in another order, one unknown.
HAND = """{
  "missing": [{"topic": "/truth", "seqs": [3, 4, 5], "why": "never received (gap)"}],
  "last_seq": 7,
  "run": "hand",
  "complete": true,
  "frames_written": 8,
  "counters": {"rejected": 2, "duplicates": 1, "latency_ms": {"n": 8, "p50": 1.5, "p99": 4.25}},
  "restarted": true,
  "eos_conflict": "a forged end of stream",
  "note": "a key no reader knows"
}"""


def test_a_hand_written_file_reads_typed_and_every_reader_agrees(tmp_path):
    path = tmp_path / "sink.json"
    path.write_text(HAND)
    s = load_summary(path)
    assert (s.run, s.complete, s.frames_written, s.last_seq, s.tracks_written) == ("hand", True, 8, 7, 0)
    assert s.eos_conflict == "a forged end of stream" and s.output_complete is False and s.files == []
    assert read_summary(path, "hand") == s
    assert describe_missing(s) == "/truth of 3 frame(s), seq 3-5: never received (gap)"
    assert describe_rejected(s) == "2 (duplicates dropped: 1); counted by the restarted sink since its restart"
    assert describe_latency(s) == "source -> sink p50 1.50 ms, p99 4.25 ms"
    assert load_summary(tmp_path / "absent.json") is None


@pytest.mark.parametrize("text, why", [
    ('{"run": "r1", "frames_written": "nine"}', "Expected `int`, got `str` - at `$.frames_written`"),
    ('{"run": "r1", "missing": {"topic": "/truth"}}', "Expected `array`, got `object` - at `$.missing`"),
    ('{"run": "r1", "complete": tru', "malformed"),
    ("", "Input data was truncated"),
])
def test_a_malformed_file_is_one_line_naming_the_file_and_the_field(tmp_path, text, why):
    path = tmp_path / "sink.json"
    path.write_text(text)
    with pytest.raises(SummaryError) as exc:
        load_summary(path)
    line = str(exc.value)
    assert line.startswith(f"{path}: not a run summary: ") and why in line and "\n" not in line
    assert read_summary(path) is None  # the sink and the supervisor: not this run's summary
