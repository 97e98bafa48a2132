"""One display name per track, a pure function of its label, shown by every reader."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.sinks.foxglove_sink import track_display_name
from bnptrack.sinks.rerun_geometry import labels_shown
from bnptrack.tracker.types import TrackEstimate, display_name


@pytest.mark.parametrize("label, name", [("1.4", "T1.4"), ("26.0", "T26.0"), ("2.z4", "T2.z4"), ("t1", "t1"), ("a.b", "a.b"), ("1.a-b", "1.a-b"),
                                         ("12", "12"), ("1.", "1."), ("", "")])
def test_display_name_of_a_label(label, name):
    assert display_name(label) == name


def test_every_reader_shows_the_same_name():
    t = TrackEstimate("40.13", np.zeros(5), np.eye(5), 0.9)
    assert t.name == track_display_name(t) == display_name(t.label) == "T40.13"


def test_names_of_nearby_tracks_are_thinned_oldest_first():
    pos = np.array([[0.0, 0.0], [50.0, 10.0], [500.0, 0.0], [60.0, 300.0]])
    # track 1 is beside track 0 (within 100 m across, 50 m up): its name is hidden; the
    # others are far enough in x or in y
    assert labels_shown(pos, np.array([0, 1, 2, 3]), (100.0, 50.0)).tolist() == [True, False, True, True]
    # the older one keeps its name whichever comes first in the arrays
    assert labels_shown(pos, np.array([1, 0, 2, 3]), (100.0, 50.0)).tolist() == [False, True, True, True]
    assert labels_shown(np.zeros((0, 2)), np.zeros(0, dtype=int), (1.0, 1.0)).tolist() == []


def test_thinning_equals_the_pairwise_rule():
    """The grid search gives what testing every pair gives (random scenes, hand-written rule)."""
    rng = np.random.default_rng(7)
    for n in (1, 5, 50, 300):
        pos = rng.uniform(-2000.0, 2000.0, (n, 2))
        order = rng.permutation(n)
        box = (400.0, 240.0)
        want = np.zeros(n, dtype=bool)
        for i in order:
            d = np.abs(pos[want] - pos[i])
            want[i] = not ((d[:, 0] < box[0]) & (d[:, 1] < box[1])).any()
        np.testing.assert_array_equal(labels_shown(pos, order, box), want)


def test_glmb_labels_have_the_documented_forms():
    """docs/glmb.md: ``<birth frame>.<birth region>`` (static birth) or ``<birth frame>.z<j>``
    (adaptive birth from measurement j of the previous processed frame), shown as ``T`` + label."""
    import re

    import bnptrack

    frames = bnptrack.simulate("vo2017", seed=2)[:20]
    run = bnptrack.track(frames, tracker="glmb", seed=0)
    n_regions = len(bnptrack.load_params("vo2017").birth)
    labels = {t.label: t.name for e in run.estimates for t in e.tracks}
    n_meas = {f.frame: f.n_measurements for f in frames}
    assert any(".z" in x for x in labels)
    for label, name in labels.items():
        m = re.fullmatch(r"(\d+)\.(z?)(\d+)", label)
        assert m is not None, label
        born, adaptive, index = int(m[1]), m[2] == "z", int(m[3])
        assert born in n_meas and name == f"T{label}"
        if adaptive:  # a measurement of the frame before the birth frame
            assert index < n_meas[born - 1]
        else:
            assert index < n_regions
