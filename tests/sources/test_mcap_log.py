"""Tests for MCAP measurement logs (sources.mcap_log, the reader; sinks.mcap_writer, the writer)."""

from __future__ import annotations

import json
import shutil
import struct

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from bnptrack.sinks.mcap_writer import McapLogWriter
from bnptrack.sources.mcap_log import (
    METADATA_NAME,
    LogContents,
    McapLogError,
    iter_frames,
    iter_tracks,
    read_log,
    read_metadata,
)
from bnptrack.tracker.messages import TOPIC_MEASUREMENTS, TOPIC_TRACKS, TOPIC_TRUTH, CodecError, encode, from_truth
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, Truth

from testkit import REPO_ROOT

META = {"scenario": "vo2017", "params": "vo2017", "seed": "1"}


# --------------------------------------------------------------------------- helpers


def make_frames(seed=0, n=50, truth=True, kind="bearing_range") -> list[Frame]:
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n):
        m = int(rng.integers(0, 40))
        if kind == "bearing_range":
            z = np.c_[rng.uniform(-np.pi, np.pi, m), rng.uniform(0.0, 2000.0, m)]
        else:
            z = rng.uniform(0.0, 2000.0, (m, 1))
        t = None
        if truth:
            nobj = int(rng.integers(0, 6))
            t = Truth(ids=tuple(f"obj{i}" for i in range(nobj)), states=rng.normal(0, 100, (nobj, 5)))
        frames.append(
            Frame(frame=k, stamp_ns=1_000_000_000 + k * 100_000_000, sensor="radar0", kind=kind, z=z, truth=t)
        )
    return frames


def make_estimate(rng, frame: Frame) -> Estimate:
    n = int(rng.integers(0, 4))
    tracks = []
    for i in range(n):
        a = rng.normal(size=(5, 5))
        tracks.append(TrackEstimate(f"t{i}", rng.normal(0, 100, 5), a @ a.T, float(rng.uniform())))
    labels = [f"t{i}" for i in range(n)] + [None]
    m = frame.n_measurements
    return Estimate(
        frame=frame.frame,
        stamp_ns=frame.stamp_ns,
        tracks=tuple(tracks),
        assignments=tuple(labels[int(j)] for j in rng.integers(0, n + 1, m)),
        assignment_prob=tuple(float(p) for p in rng.uniform(0, 1, m)),
        diagnostics={"alpha": 1.5, "ms": 0.25},
    )


def assert_frame_equal(a: Frame, b: Frame) -> None:
    assert (a.frame, a.stamp_ns, a.sensor, a.kind) == (b.frame, b.stamp_ns, b.sensor, b.kind)
    assert np.array_equal(a.z, b.z) and a.z.shape == b.z.shape
    if a.truth is None:
        assert b.truth is None
    else:
        assert b.truth is not None
        assert a.truth.ids == b.truth.ids
        assert np.array_equal(a.truth.states, b.truth.states)


def assert_estimate_equal(a: Estimate, b: Estimate) -> None:
    assert (a.frame, a.stamp_ns) == (b.frame, b.stamp_ns)
    assert [t.label for t in a.tracks] == [t.label for t in b.tracks]
    for s, t in zip(a.tracks, b.tracks):
        assert np.array_equal(s.state, t.state)
        assert np.array_equal(s.covariance, t.covariance)
        assert s.existence == t.existence
    assert a.assignments == b.assignments
    assert a.assignment_prob == b.assignment_prob
    assert a.diagnostics == b.diagnostics


def write_log(path, frames, metadata=META, estimates=None, **kw):
    with McapLogWriter(path, metadata, **kw) as w:
        for i, f in enumerate(frames):
            w.write_frame(f, run="run-1")
            if estimates is not None:
                w.write_tracks(estimates[i], run="run-1")
    return path


def raw_writer(fh, chunk_size=4096) -> Writer:
    w = Writer(fh, chunk_size=chunk_size, compression=CompressionType.NONE)
    w.start()
    return w


def data_section_end(data: bytes) -> int:
    """Byte offset where the summary section starts (the DataEnd record ends there)."""
    # Footer record: opcode(1) length(8) summary_start(8) summary_offset_start(8) crc(4); magic(8)
    footer = data[-8 - 29 : -8]
    assert footer[0] == 0x02
    return struct.unpack("<Q", footer[9:17])[0]


def read_prefix(path):
    """Frames read before the error, and the error (or None)."""
    got = []
    try:
        for f in iter_frames(path):
            got.append(f)
    except McapLogError as e:
        return got, e
    return got, None


# --------------------------------------------------------------------------- round trips


def test_round_trip_frames_truth_tracks_metadata(tmp_path):
    frames = make_frames(0)
    rng = np.random.default_rng(1)
    ests = [make_estimate(rng, f) for f in frames]
    path = write_log(tmp_path / "log.mcap", frames, estimates=ests)

    got = list(iter_frames(path))
    assert len(got) == len(frames)
    for a, b in zip(frames, got):
        assert_frame_equal(a, b)
    got_t = list(iter_tracks(path))
    assert len(got_t) == len(ests)
    for a, b in zip(ests, got_t):
        assert_estimate_equal(a, b)
    assert read_metadata(path) == META

    log = read_log(path)
    assert isinstance(log, LogContents)
    assert log.metadata == META and log.error is None
    assert len(log.frames) == 50 and len(log.tracks) == 50
    assert_frame_equal(frames[17], log.frames[17])


def test_round_trip_range_only_without_truth(tmp_path):
    frames = make_frames(2, n=10, truth=False, kind="range")
    path = write_log(tmp_path / "r.mcap", frames, metadata=None)
    got = list(iter_frames(path))
    assert len(got) == 10
    for a, b in zip(frames, got):
        assert_frame_equal(a, b)
    assert read_metadata(path) is None


def test_readable_by_standard_mcap_reader(tmp_path):
    frames = make_frames(3, n=20)
    rng = np.random.default_rng(4)
    path = write_log(tmp_path / "std.mcap", frames, estimates=[make_estimate(rng, f) for f in frames])
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        assert sorted(c.topic for c in summary.channels.values()) == sorted(
            [TOPIC_MEASUREMENTS, TOPIC_TRUTH, TOPIC_TRACKS]
        )
        assert summary.statistics.message_count == 60
        assert summary.statistics.chunk_count > 1  # small chunks
        counts = {}
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "json"
            assert schema is not None and schema.encoding == "jsonschema"
            json.loads(schema.data)
            obj = json.loads(message.data)
            assert message.log_time == message.publish_time == obj["stamp_ns"]
            assert obj["v"] == 1 and obj["run"] == "run-1"  # no version-2 field used
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        assert counts == {TOPIC_MEASUREMENTS: 20, TOPIC_TRUTH: 20, TOPIC_TRACKS: 20}
        metas = list(reader.iter_metadata())
        assert [(m.name, m.metadata) for m in metas] == [(METADATA_NAME, META)]


def test_truth_pairing_before_and_after(tmp_path):
    """Truth may precede or follow its measurements; a frame may have no truth."""
    frames = make_frames(5, n=8)
    path = tmp_path / "pair.mcap"
    with open(path, "wb") as fh:
        w = raw_writer(fh)
        w.register_schema("x", "jsonschema", b"{}")
        cm = w.register_channel(TOPIC_MEASUREMENTS, "json", 1)
        ct = w.register_channel(TOPIC_TRUTH, "json", 1)
        cx = w.register_channel("/other", "cdr", 0)
        for f in frames:
            m = encode(f)
            t = encode(from_truth(f.frame, f.stamp_ns, f.truth))
            w.add_message(cx, f.stamp_ns, b"\x00\x01not json", f.stamp_ns)
            if f.frame == 3:  # no truth for frame 3
                w.add_message(cm, f.stamp_ns, m, f.stamp_ns)
            elif f.frame % 2:
                w.add_message(ct, f.stamp_ns, t, f.stamp_ns)
                w.add_message(cm, f.stamp_ns, m, f.stamp_ns)
            else:
                w.add_message(cm, f.stamp_ns, m, f.stamp_ns)
                w.add_message(ct, f.stamp_ns, t, f.stamp_ns)
        w.finish()
    got = list(iter_frames(path))
    assert [g.frame for g in got] == list(range(8))
    for a, b in zip(frames, got):
        if a.frame == 3:
            assert b.truth is None
            assert np.array_equal(a.z, b.z)
        else:
            assert_frame_equal(a, b)


def test_file_from_elsewhere_without_metadata_or_truth(tmp_path):
    """Only /measurements with the five core fields, no schema, no metadata, no summary."""
    path = tmp_path / "other.mcap"
    rng = np.random.default_rng(6)
    expected = []
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=2048, use_summary_offsets=False, use_statistics=False,
                   repeat_channels=False, repeat_schemas=False)
        w.start()
        ch = w.register_channel(TOPIC_MEASUREMENTS, "json", 0)
        for k in range(5, 25):
            z = np.c_[rng.uniform(-3, 3, 4), rng.uniform(0, 50, 4)]
            expected.append((k, z))
            obj = {"frame": k, "stamp_ns": 10 * k, "sensor": "ext", "kind": "bearing_range", "z": z.tolist()}
            w.add_message(ch, 10 * k, json.dumps(obj).encode(), 10 * k)
        w.finish()
    got = list(iter_frames(path))
    assert [g.frame for g in got] == list(range(5, 25))
    for (k, z), g in zip(expected, got):
        assert np.array_equal(g.z, z) and g.truth is None and g.sensor == "ext"
    assert read_metadata(path) is None
    assert list(iter_tracks(path)) == []
    log = read_log(path)
    assert log.metadata is None and len(log.frames) == 20 and log.tracks == []


# --------------------------------------------------------------------------- damage


@pytest.mark.parametrize("fraction", [0.3, 0.5, 0.75, 0.9, 0.99])
def test_truncated_file_yields_prefix_then_raises(tmp_path, fraction):
    """Cut at a fraction of the data section (a cut in the summary loses no data: see below)."""
    frames = make_frames(7)
    full = write_log(tmp_path / "full.mcap", frames)
    data = full.read_bytes()
    cut = tmp_path / f"cut_{int(fraction * 100)}.mcap"
    cut.write_bytes(data[: int(data_section_end(data) * fraction)])

    got, err = read_prefix(cut)
    assert err is not None, "a truncated file must raise"
    assert 0 < len(got) < len(frames)
    for a, b in zip(frames, got):
        assert_frame_equal(a, b)
    assert err.kind == "truncated"
    assert err.last_frame == got[-1].frame
    msg = str(err)
    assert str(cut) in msg
    assert f"truncated after frame {got[-1].frame}" in msg
    assert "byte offset" in msg and "message" in msg
    # a crash-cut file still has its metadata (written first)
    assert read_metadata(cut) == META
    # non-strict read_log returns the same prefix and the error
    log = read_log(cut, strict=False)
    assert len(log.frames) == len(got) and isinstance(log.error, McapLogError)
    with pytest.raises(McapLogError):
        read_log(cut)


def test_cut_in_summary_section_reads_completely(tmp_path):
    """All messages precede DataEnd: a file whose summary/footer is cut still reads fully."""
    frames = make_frames(7)
    data = write_log(tmp_path / "full.mcap", frames).read_bytes()
    end = data_section_end(data)
    for cut_at in (end, end + (len(data) - end) // 2, len(data) - 3):
        cut = tmp_path / f"summary_cut_{cut_at}.mcap"
        cut.write_bytes(data[:cut_at])
        got = list(iter_frames(cut))
        assert len(got) == len(frames)
        assert read_metadata(cut) == META


@pytest.mark.parametrize("fraction", [0.0, 0.001, 0.01])
def test_truncated_before_first_frame(tmp_path, fraction):
    full = write_log(tmp_path / "full.mcap", make_frames(8, n=5))
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    got, err = read_prefix(cut)
    assert got == [] and err is not None and str(cut) in str(err)
    if fraction == 0.0:
        assert err.kind == "not_mcap" and str(err).endswith("not an MCAP file: the file is empty (0 bytes)")
    else:
        assert "before the first complete frame" in str(err)


def test_truncated_file_without_truth_keeps_last_frame(tmp_path):
    frames = make_frames(9, truth=False)
    data = write_log(tmp_path / "full.mcap", frames, metadata=None).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    got, err = read_prefix(cut)
    assert err is not None and len(got) > 0
    for a, b in zip(frames, got):
        assert_frame_equal(a, b)
    assert err.last_frame == got[-1].frame


def test_corrupt_chunk_raises_after_prefix(tmp_path):
    frames = make_frames(10)
    path = write_log(tmp_path / "full.mcap", frames)
    with open(path, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    victim = chunks[len(chunks) // 2]
    data = bytearray(path.read_bytes())
    pos = victim.chunk_start_offset + victim.chunk_length - 20  # inside the compressed payload
    data[pos : pos + 8] = b"\xde\xad\xbe\xef" * 2
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    got, err = read_prefix(bad)
    assert err is not None and err.kind == "corrupt"
    assert 0 < len(got) < len(frames)
    for a, b in zip(frames, got):
        assert_frame_equal(a, b)
    assert str(bad) in str(err) and f"after frame {got[-1].frame}" in str(err)


def test_not_an_mcap_file(tmp_path):
    p = tmp_path / "junk.mcap"
    p.write_bytes(b"this is not an mcap file at all" * 10)
    got, err = read_prefix(p)
    assert got == [] and err is not None and err.kind == "not_mcap"
    with pytest.raises(McapLogError):
        read_metadata(p)
    with pytest.raises(McapLogError):
        list(iter_frames(tmp_path / "missing.mcap"))


def test_an_empty_file_is_named_empty_not_a_log_without_channels(tmp_path):
    """A 0-byte file holds no record at all; the channel listing the commands check first
    does not say "no /measurements channel ... Its channels: none"."""
    from bnptrack.sources.mcap_log import log_channels

    p = tmp_path / "empty.mcap"
    p.write_bytes(b"")
    with pytest.raises(McapLogError, match=r"not an MCAP file: the file is empty \(0 bytes\)") as err:
        log_channels(p)
    assert str(p) in str(err.value) and err.value.kind == "not_mcap"


def test_unflushed_writer_crash_loses_little(tmp_path):
    """Copy the file while the writer is still open (as after a crash)."""
    frames = make_frames(11, n=23)
    path = tmp_path / "live.mcap"
    w = McapLogWriter(path, META, flush_every=5)
    try:
        for f in frames:
            w.write_frame(f)
        snap = tmp_path / "snap.mcap"
        shutil.copyfile(path, snap)
    finally:
        w.close()
    got, err = read_prefix(snap)
    assert err is not None and err.kind == "truncated"
    assert len(got) >= 20  # at most flush_every frames (plus the open chunk) lost
    for a, b in zip(frames, got):
        assert_frame_equal(a, b)
    assert len(list(iter_frames(path))) == 23


# --------------------------------------------------------------------------- invalid content


def test_a_frame_index_that_does_not_advance_is_read_and_left_to_the_frame_bounds(tmp_path):
    """The reader passes on a repeated or backward frame index with its own truth; the frame
    bounds of whoever tracks the frames skip it (tests/pipeline/test_hostile_logs.py)."""
    frames = make_frames(12, n=6)
    order = [frames[i] for i in (0, 1, 2, 3, 2, 4)]
    path = write_log(tmp_path / "nonmono.mcap", order)
    got, err = read_prefix(path)
    assert err is None
    assert [g.frame for g in got] == [0, 1, 2, 3, 2, 4]
    assert all(g.truth is not None and g.truth.ids == o.truth.ids for g, o in zip(got, order))


def test_repeated_frame_index_is_read_without_truth(tmp_path):
    frames = make_frames(13, n=4, truth=False)
    path = write_log(tmp_path / "dup.mcap", [frames[0], frames[1], frames[1]], metadata=None)
    got, err = read_prefix(path)
    assert err is None and [g.frame for g in got] == [0, 1, 1]


def _write_raw_measurements(path, payloads):
    with open(path, "wb") as fh:
        w = raw_writer(fh)
        w.add_metadata(METADATA_NAME, META)
        ch = w.register_channel(TOPIC_MEASUREMENTS, "json", 0)
        for k, data in enumerate(payloads):
            w.add_message(ch, k, data, k)
        w.finish()


@pytest.mark.parametrize(
    "bad_z, fragment",
    [
        (b"[[0.1, NaN]]", "non-finite"),
        (b"[[0.1, null]]", "$.z[0][1]"),
        (b"[[0.1, 1e999]]", "$.z[0][1]"),
        (b"[[0.1, -4.0]]", "range must be >= 0"),
        (b"[[0.1]]", "$.z[0]"),
    ],
)
def test_bad_measurement_in_file_names_topic_and_frame(tmp_path, bad_z, fragment):
    good = [
        b'{"frame": %d, "stamp_ns": %d, "sensor": "s", "kind": "bearing_range", "z": [[0.1, 5.0]]}' % (k, k)
        for k in range(5)
    ]
    bad = b'{"frame": 5, "stamp_ns": 5, "sensor": "s", "kind": "bearing_range", "z": ' + bad_z + b"}"
    path = tmp_path / "nan.mcap"
    _write_raw_measurements(path, good + [bad] + good[:1])
    got, err = read_prefix(path)
    assert [g.frame for g in got] == [0, 1, 2, 3, 4]
    assert err is not None and err.kind == "invalid"
    msg = str(err)
    assert str(path) in msg and "/measurements frame 5" in msg and fragment in msg and "\n" not in msg
    assert err.frame == 5 and err.last_frame == 4 and err.n_messages == 6


def test_wrong_schema_on_known_topic(tmp_path):
    path = tmp_path / "wrong.mcap"
    _write_raw_measurements(path, [b'{"frame": 0, "stamp_ns": 0, "objects": []}'])
    got, err = read_prefix(path)
    assert got == [] and err is not None and "/measurements frame 0" in str(err)

    path2 = tmp_path / "enc.mcap"
    with open(path2, "wb") as fh:
        w = raw_writer(fh)
        ch = w.register_channel(TOPIC_MEASUREMENTS, "cdr", 0)
        w.add_message(ch, 0, b"\x00\x01", 0)
        w.finish()
    got, err = read_prefix(path2)
    assert err is not None and "unsupported message encoding 'cdr'" in str(err)


def test_unsupported_version_in_file(tmp_path):
    path = tmp_path / "v2.mcap"
    _write_raw_measurements(
        path, [b'{"v": 3, "frame": 0, "stamp_ns": 0, "sensor": "s", "kind": "range", "z": [[1.0]], "new": 1}']
    )
    got, err = read_prefix(path)
    assert got == [] and "unsupported schema version 3" in str(err) and "/measurements frame 0" in str(err)


def test_writer_rejects_invalid_frame_without_writing_half(tmp_path):
    frames = make_frames(14, n=3)
    bad_truth = Truth(ids=("a",), states=np.array([[np.nan, 0, 0, 0, 0]]))
    bad = Frame(3, 0, "radar0", "bearing_range", np.zeros((0, 2)), bad_truth)
    path = tmp_path / "w.mcap"
    with McapLogWriter(path, META) as w:
        for f in frames:
            w.write_frame(f)
        with pytest.raises(CodecError):
            w.write_frame(bad)
    assert [f.frame for f in iter_frames(path)] == [0, 1, 2]
    with pytest.raises(ValueError):
        w.write_frame(frames[0])  # closed


# --------------------------------------------------------------------------- copy


def test_encoded_writes_equal_the_encoding_writes(tmp_path):
    """write_encoded_frame / write_encoded_tracks (the pipeline's sink: validated payloads
    as received) give the same messages, records and flushes as write_frame / write_tracks."""
    frames = make_frames(n=12)
    rng = np.random.default_rng(1)
    estimates = [make_estimate(rng, f) for f in frames]
    a = write_log(tmp_path / "a.mcap", frames, estimates=estimates)
    with McapLogWriter(tmp_path / "b.mcap", META) as w:
        for f, e in zip(frames, estimates):
            truth = None if f.truth is None else encode(from_truth(f.frame, f.stamp_ns, f.truth, "run-1"))
            w.write_encoded_frame(encode(f, "run-1"), truth, f.stamp_ns, f.frame)
            w.write_encoded_tracks(encode(e, "run-1"), e.stamp_ns, e.frame)
    assert (tmp_path / "b.mcap").read_bytes() == a.read_bytes()


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_reader_imports_neither_pipeline_nor_sinks():
    """sources.mcap_log is the reader only: importing it (and reading a log) pulls in nothing
    from pipeline/ or sinks/ (the writer is sinks.mcap_writer)."""
    import subprocess
    import sys

    root = REPO_ROOT
    code = ("import sys; from bnptrack.sources.mcap_log import iter_frames; "
            "n = sum(1 for _ in iter_frames('recordings/vo2017-s1.mcap')); assert n == 100, n; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('pipeline', 'sinks', 'zenoh', 'rerun')); "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=str(root))


def test_a_jumped_frame_number_keeps_the_later_frames_truth_in_either_order():
    """One frame numbered 10**9: the frames after it still pair with their truth, whether a
    log writes each frame's truth after its measurements (bnptrack's writer) or before."""
    from types import SimpleNamespace as Msg

    from bnptrack.sources.mcap_log import _FramePairer

    numbers = [1, 2, 10**9, 3, 4]
    for truth_first in (False, True):
        pairer, got = _FramePairer(), []
        for k in numbers:
            m, t = Msg(frame=k, what="m"), Msg(frame=k, what="t")
            for msg in ((t, m) if truth_first else (m, t)):
                add = pairer.add_truth if msg.what == "t" else pairer.add_measurements
                got += add(msg)
        got += pairer.finish(complete_only=False)
        assert [(a.frame, b is not None and b.frame) for a, b in got] == [(k, k) for k in numbers], truth_first
