"""The two-level tracker's group level predicts over the same time as its object level: the
stamps' difference (tracker.types.frame_dt), not frame numbers x T."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bnptrack.api import make_tracker
from bnptrack.tracker.types import Frame


def _frame(k: int, stamp_ns: int) -> Frame:
    return Frame(frame=k, stamp_ns=stamp_ns, sensor="sim0", kind="bearing_range", z=np.zeros((0, 2)))


def test_scan_periods_come_from_the_stamps():
    tr = make_tracker("ddp", params="vo2017")  # T = 1 s
    state = replace(tr.initial_state(), frame=3, stamp_ns=3_000_000_000)
    assert tr.periods_since(state, _frame(5, 4_500_000_000)) == 1.5  # 1.5 s later, two frame numbers on
    assert tr.periods_since(state, _frame(4, 6_000_000_000)) == 3.0  # a gap without a dropped number
    regular = tr.periods_since(state, _frame(5, 5_000_000_000))
    assert regular == 2 and isinstance(regular, int)  # regular frames: the same numbers as before
    assert tr.periods_since(tr.initial_state(), _frame(1, 1_000_000_000)) == 1
