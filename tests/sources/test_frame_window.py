"""sources/frame_window.py: the frames a run reads (replay's source stage and offline track)."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sources.frame_window import WINDOW_KEYS, FrameWindow
from bnptrack.tracker.types import Frame


def _frames(stamps_s: list[float], first: int = 1) -> list[Frame]:
    return [Frame(first + i, int(t * 1e9), "s", "bearing_range", np.zeros((0, 2))) for i, t in enumerate(stamps_s)]


FRAMES = _frames([5.0, 6.0, 7.5, 9.0, 10.0, 12.0])  # log time 0, 1, 2.5, 4, 5, 7 s


def cut(**kw) -> list[int]:
    return [f.frame for f in FrameWindow(**kw).cut(FRAMES)]


def test_window_in_seconds_frames_and_count():
    assert cut() == [1, 2, 3, 4, 5, 6]
    assert cut(start_s=1.0, end_s=5.0) == [2, 3, 4, 5]  # both ends included
    assert cut(start_frame=2, end_s=2.5) == [2, 3]
    assert cut(frames=2) == [1, 2]
    assert cut(start_frame=3, frames=2) == [3, 4]  # the count is of the window's frames
    assert cut(start_s=6.0, frames=5) == [6]


def test_the_input_is_not_read_past_the_end():
    it = iter(FRAMES)
    assert [f.frame for f in FrameWindow(end_frame=2).cut(it)] == [1, 2]
    assert next(it).frame == 4  # frame 3 was read to see that it is past the end, no more
    it = iter(FRAMES)
    assert [f.frame for f in FrameWindow(frames=1).cut(it)] == [1]
    assert next(it).frame == 2


@pytest.mark.parametrize("bad, msg", [
    ({"start_s": 1.0, "start_frame": 2}, "x.start_s and x.start_frame: give the start in seconds or in frames, not both"),
    ({"start_s": 3.0, "end_s": 2.0}, "x.end_s = 2 is before x.start_s = 3"),
    ({"start_frame": 5, "end_frame": 4}, "x.end_frame = 4 is before x.start_frame = 5"),
])
def test_check_names_the_keys(bad, msg):
    with pytest.raises(ValueError) as err:
        FrameWindow(**bad).check("x.")
    assert str(err.value) == msg


def test_of_reads_the_same_fields_from_any_settings():
    from bnptrack.pipeline.config import SourceConfig

    assert WINDOW_KEYS == ("frames", "start_s", "end_s", "start_frame", "end_frame")
    assert FrameWindow.of(SourceConfig(frames=3, end_s=2.5)) == FrameWindow(frames=3, end_s=2.5)
