"""The sink stage's pure core (:class:`pipeline.stages.sink_align.FrameAligner`): frames come
out in sequence order once every stream has released its item, out-of-bounds frames and
messages of another frame come out as data; a frame that does not follow the last one waits
for the publisher's copy (Verify).  No bus, no clock, no file."""

from types import SimpleNamespace

from bnptrack.pipeline.stages.delivery import GAP, NO_TRUTH
from bnptrack.pipeline.stages.sink_align import FrameAligner, Mismatch, Reject, Verify, Write
from bnptrack.tracker.types import FrameBounds

S = 10**9


def item(frame: int, stamp_ns: int | None = None, payload: bytes = b"") -> SimpleNamespace:
    """A received message as the aligner reads it: ``msg.frame``, ``msg.stamp_ns``, ``payload``."""
    return SimpleNamespace(msg=SimpleNamespace(frame=frame, stamp_ns=frame * S if stamp_ns is None else stamp_ns),
                           payload=payload or f"m{frame}".encode())


def aligner(tracks: bool = True) -> FrameAligner:
    streams = ["measurements", "truth"] + (["tracks"] if tracks else [])
    return FrameAligner(streams, FrameBounds(max_frame_gap=10, max_gap_s=60.0))


def test_a_frame_waits_for_every_stream_then_comes_out_in_order():
    a = aligner()
    m0, m1, t0, t1, k0, k1 = item(1), item(2), item(1), item(2), item(1), item(2)
    assert a.release("measurements", [(1, m1)]) == [] and a.release("truth", [(0, t0), (1, t1)]) == []
    assert a.drain() == []  # seq 0 has no measurements yet
    a.release("measurements", [(0, m0)])
    assert a.drain() == []  # nor tracks
    a.release("tracks", [(1, k1)])
    assert a.drain() == []
    a.release("tracks", [(0, k0)])
    assert a.drain() == [Write(0, m0, t0, k0), Write(1, m1, t1, k1)]
    assert a.next_write == 2 and a.drain() == []
    assert (a.last_frame, a.last_stamp_ns) == (2, 2 * S)


def test_without_a_tracks_stream_a_frame_has_no_tracks():
    a = aligner(tracks=False)
    m, t = item(5), NO_TRUTH
    a.release("measurements", [(0, m)])
    a.release("truth", [(0, t)])
    assert a.drain() == [Write(0, m, NO_TRUTH, None)]


def test_gaps_are_named_and_recorded_as_gaps():
    a = aligner()
    m1 = item(2)
    assert a.release("measurements", [(0, GAP), (1, m1)]) == [0]
    assert a.release("truth", [(0, GAP), (1, GAP)]) == [0, 1]
    assert a.release("tracks", [(0, GAP), (1, item(2))]) == [0]
    acts = a.drain()
    assert [type(x) for x in acts] == [Write, Write]
    assert (acts[0].meas, acts[0].truth, acts[0].tracks) == (GAP, GAP, GAP)
    assert acts[1].meas is m1 and acts[1].truth is GAP
    assert a.last_frame == 2  # a gap moves no frame bound


def test_a_frame_out_of_bounds_is_rejected_and_kept_out():
    a = aligner()
    frames = [item(1), item(2), item(2 + 11, payload=b"jump"), item(4)]
    for s, m in enumerate(frames):
        for stream in ("measurements", "truth", "tracks"):
            a.release(stream, [(s, m)])
    acts = a.drain()
    assert acts == [Write(0, frames[0], frames[0], frames[0]), Write(1, frames[1], frames[1], frames[1]),
                    Verify(2, frames[2])]
    assert a.drain() == [Verify(2, frames[2])]  # it waits for the publisher's copy
    a.verified(2, frames[2])  # the publisher's copy is the same
    acts = acts[:2] + a.drain()
    assert acts[2] == Reject(2, b"jump", "frame 13 jumps 11 frames after frame 2 (more than max_frame_gap = 10)")
    assert [type(x) for x in acts] == [Write, Write, Reject, Write]
    assert a.rejected_seqs == [2] and (a.last_frame, a.next_write) == (4, 4)


def test_a_message_of_another_frame_is_dropped_as_a_gap():
    a = aligner()
    m, t, k = item(7), item(8), item(7)
    a.release("measurements", [(0, m)])
    a.release("truth", [(0, t)])
    a.release("tracks", [(0, k)])
    assert a.drain() == [Mismatch(0, "truth", 8, 7), Write(0, m, GAP, k)]
    assert a.mismatched == {"truth": [0]}


def test_restart_at_continues_after_recovered_frames():
    a = aligner()
    a.restart_at(3, 30, 30 * S)
    m = item(29)  # not after the recovered frame 30
    for stream in ("measurements", "truth", "tracks"):
        a.release(stream, [(3, m)])
    assert a.drain() == [Verify(3, m)]
    a.verified(3, m)
    assert a.drain() == [Reject(3, m.payload, "frame 29 is not after the last processed frame 30")]


def test_the_publishers_copy_replaces_a_foreign_one_before_it_is_recorded():
    a = aligner(tracks=False)
    first, foreign, own = item(1), item(90, payload=b"foreign"), item(2)
    a.release("measurements", [(0, first), (1, foreign)])
    a.release("truth", [(0, NO_TRUTH), (1, NO_TRUTH)])
    assert a.drain() == [Write(0, first, NO_TRUTH, None), Verify(1, foreign)]
    a.verified(1, own)
    assert a.drain() == [Write(1, own, NO_TRUTH, None)]
    assert a.rejected_seqs == [] and a.last_frame == 2


def test_frames_that_agree_after_a_jump_are_recorded_from_the_resync_on():
    a = FrameAligner(["measurements", "truth"], FrameBounds(10, 60.0, resync_frames=2))
    frames = [item(1), item(500), item(501), item(502), item(503)]
    for s, m in enumerate(frames):
        a.release("measurements", [(s, m)])
        a.release("truth", [(s, NO_TRUTH)])
    acts = []
    while True:
        out = a.drain()
        acts += [x for x in out if not isinstance(x, Verify)]
        if not out or not isinstance(out[-1], Verify):
            break
        a.verified(out[-1].seq, out[-1].meas)
    assert [type(x) for x in acts] == [Write, Reject, Reject, Write, Write]
    assert a.rejected_seqs == [1, 2] and a.last_frame == 503
