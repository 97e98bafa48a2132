"""The tracker stage's pure core (:class:`pipeline.stages.tracker_core.TrackerCore`): frames
released in sequence order become Step / Skip / Reject actions, and the position of the run
moves past a tracked frame only when the stage says its tracks are out; a frame that does not
follow the last one is first checked against the publisher's copy (Verify), and a run of
frames that agree with each other resynchronises the stream.  No bus, no clock,
no tracker."""

from types import SimpleNamespace

import numpy as np

from bnptrack.pipeline.stages.delivery import GAP, Sequencer
from bnptrack.pipeline.stages.tracker_core import Reject, Skip, Step, TrackerCore, Verify
from bnptrack.tracker.messages import from_frame
from bnptrack.tracker.types import Frame, FrameBounds

S = 10**9


def acc(frame: int, stamp_s: float | None = None) -> SimpleNamespace:
    """A received ``/measurements`` sample as the core reads it (``msg``, ``payload``)."""
    stamp = int((frame if stamp_s is None else stamp_s) * S)
    z = np.array([[0.1, 500.0 + frame]])
    return SimpleNamespace(msg=from_frame(Frame(frame, stamp, "radar", "bearing_range", z)), payload=f"p{frame}".encode())


def core(window: int = 3, resync: int = 10) -> TrackerCore:
    return TrackerCore(Sequencer(window, 0, "measurements"), FrameBounds(5, 30.0, resync))


def test_frames_released_in_order_are_steps_and_the_position_waits_for_their_tracks():
    c = core()
    a1, a0 = acc(2), acc(1)
    assert c.push(1, a1) == ("accepted", [])  # held until seq 0
    status, released = c.push(0, a0)
    assert status == "accepted" and [s for s, _ in released] == [0, 1]
    act = c.decide(*released[0])
    assert isinstance(act, Step) and act.seq == 0 and act.item is a0
    assert (act.frame.frame, act.frame.stamp_ns, act.frame.z.tolist()) == (1, S, [[0.1, 501.0]])
    assert c.last_seq == -1  # not tracked yet: a snapshot now resumes before it
    c.stepped(0, act.frame)
    assert (c.last_seq, c.last_frame, c.last_stamp_ns) == (0, 1, S)
    act = c.decide(*released[1])
    c.stepped(1, act.frame)
    assert (c.last_seq, c.last_frame) == (1, 2)
    assert c.push(1, a1) == ("duplicate", [])


def test_a_gap_is_skipped_and_moves_the_position_but_not_the_frame():
    c = core(window=2)
    c.push(0, acc(1))
    c.stepped(0, c.decide(0, acc(1)).frame)
    status, released = c.push(4, acc(5))  # seq 1 falls out of the window of 2: a gap
    assert released[0] == (1, GAP)
    assert c.decide(*released[0]) == Skip(1)
    assert (c.last_seq, c.last_frame) == (1, 1)


def test_a_frame_out_of_bounds_is_rejected_before_the_tracker_sees_it():
    c = core()
    c.stepped(0, c.decide(0, acc(1)).frame)
    jump = acc(1 + 6)
    assert c.decide(1, jump) == Verify(1, jump)  # first: is it the publisher's copy?
    assert c.rejected_seqs == [] and c.last_seq == 0
    assert c.decide(1, jump, own=True) == Reject(1, b"p7", "frame 7 jumps 6 frames after frame 1 "
                                                         "(more than max_frame_gap = 5)")
    back = acc(3, stamp_s=0.5)
    assert c.decide(2, back, own=True).why == f"frame 3: time stamp {S // 2} ns is before that of frame 1 ({S} ns)"
    assert c.rejected_seqs == [1, 2] and (c.last_seq, c.last_frame) == (2, 1)
    assert isinstance(c.decide(3, acc(4)), Step)  # the bounds still count from frame 1


def test_resume_continues_from_a_snapshot_position():
    c = core()
    seq = Sequencer(3, 8, "measurements")
    seq.restore_gaps([5])
    c.resume(seq, 7, 9, 9 * S, [6])
    assert (c.last_seq, c.last_frame, c.last_stamp_ns, c.rejected_seqs) == (7, 9, 9 * S, [6])
    assert c.push(5, acc(6))[0] == "late"  # its gap was declared before the snapshot
    assert isinstance(c.decide(8, acc(10)), Step)
    assert isinstance(c.decide(8, acc(9), own=True), Reject)  # not after the last frame


def test_a_copy_under_the_seq_that_follows_replaces_a_foreign_one():
    c = core()
    c.stepped(0, c.decide(0, acc(1)).frame)
    foreign, own = acc(40), acc(2)
    assert c.decide(1, foreign) == Verify(1, foreign)
    act = c.decide(1, own, own=True)  # the publisher's copy of seq 1
    assert isinstance(act, Step) and act.item is own and not act.fresh and c.rejected_seqs == []


def test_frames_that_agree_after_a_jump_resynchronise_the_stream():
    c = core(resync=2)
    c.stepped(0, c.decide(0, acc(1)).frame)
    acts = [c.decide(s, acc(100 + s), own=True) for s in (1, 2)]
    assert [type(a) for a in acts] == [Reject, Reject]
    assert c.gate_state() == (2, 102, 102 * S)
    act = c.decide(3, acc(103), own=True)  # the third in a row that agree: a new segment
    assert isinstance(act, Step) and act.fresh and act.frame.frame == 103
    assert c.gate_state() == (2, 102, 102 * S)  # not tracked yet: a snapshot keeps the run
    c.stepped(3, act.frame)
    assert c.gate_state() == (0, 102, 102 * S) and (c.last_seq, c.last_frame) == (3, 103)
    nxt = c.decide(4, acc(104))
    assert isinstance(nxt, Step) and not nxt.fresh


def test_resume_restores_the_run_of_skipped_frames():
    c = core(resync=2)
    c.resume(Sequencer(3, 5, "measurements"), 4, 1, S, [3, 4], gate=(2, 51, 51 * S))
    act = c.decide(5, acc(52), own=True)
    assert isinstance(act, Step) and act.fresh
