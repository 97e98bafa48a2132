"""``bnptrack track --lag N`` and ``bnptrack.track(..., lag=N)``: the fixed-lag output of
tracker.lag recorded and scored in place of the online one, which stays available."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from mcap.reader import make_reader

import bnptrack
from bnptrack.tracker.lag import FixedLag, run_lagged
from bnptrack.tracker.state import run


def test_api_lag_publishes_every_frame_and_keeps_the_online_estimates():
    frames = bnptrack.simulate("vo2017", seed=4)[:25]
    online = bnptrack.track(frames, tracker="ddp-mb", seed=1)
    lagged = bnptrack.track(frames, tracker="ddp-mb", seed=1, lag=2)
    assert online.online == [] and len(lagged.online) == len(lagged.estimates) == 25
    for a, b in zip(online.estimates, lagged.online):  # the same tracker run underneath
        assert a.labels == b.labels
        np.testing.assert_array_equal(a.positions, b.positions)
    assert [e.frame for e in lagged.estimates] == [f.frame for f in frames]
    assert all(e.lag == 2 and "lag" not in e.diagnostics for e in lagged.estimates)
    for a, b in zip(lagged.online, lagged.estimates):  # a frame's ms: its online step plus the layer's
        assert b.diagnostics["ms"] > a.diagnostics["ms"]
        assert {k: v for k, v in b.diagnostics.items() if k != "ms"} == {
            k: v for k, v in a.diagnostics.items() if k != "ms"}
    # what the API returns is the layer over the tracker, frame for frame
    tracker = bnptrack.make_tracker("ddp-mb")
    direct = [e for _f, e, _s in run_lagged(FixedLag(tracker, tracker.params, 2), frames, 1)]
    assert [e.labels for e in direct] == [e.labels for e in lagged.estimates]
    assert lagged.mean_ospa < online.mean_ospa  # hindsight and smoothing help on this scene


def test_api_lag_zero_is_the_online_run():
    frames = bnptrack.simulate("vo2017", seed=4)[:10]
    tracker = bnptrack.make_tracker("ddp-mb")
    plain = [e for _f, e, _s in run(tracker, frames, 1)]
    zero = bnptrack.track(frames, tracker="ddp-mb", seed=1, lag=0).estimates
    for a, b in zip(plain, zero):
        assert a.labels == b.labels and b.lag == 0 and "lag" not in b.diagnostics
        np.testing.assert_array_equal(a.positions, b.positions)
    with pytest.raises(ValueError, match="lag must be an integer >= 0"):
        bnptrack.track(frames, lag=-1)


@pytest.mark.slow
def test_cli_track_lag_writes_lagged_tracks(tmp_path):
    log = tmp_path / "s5.mcap"
    bnptrack.simulate("vo2017", seed=5, out=log)
    out = tmp_path / "tracks.mcap"
    subprocess.run([sys.executable, "-m", "bnptrack", "track", str(log), "--tracker", "ddp-mb", "--seed", "2",
                    "--lag", "3", "--out", str(out), "-q"], check=True, capture_output=True)
    written = bnptrack.read_log(out).tracks
    api = bnptrack.track(log, tracker="ddp-mb", seed=2, lag=3)
    assert len(written) == 100 and all(e.lag == 3 for e in written)
    for a, b in zip(api.estimates, written):
        assert a.labels == b.labels
    # the online estimates beside them, frame for frame
    with open(out, "rb") as fh:
        online = [json.loads(m.data) for _s, _c, m in make_reader(fh).iter_messages(topics=["/tracks_online"])]
    assert [m["frame"] for m in online] == [e.frame for e in api.online]
    assert [[t["label"] for t in m["tracks"]] for m in online] == [list(e.labels) for e in api.online]
    assert any(m["tracks"] != [] for m in online) and all("lag" not in m for m in online)
    plain = tmp_path / "plain.mcap"
    subprocess.run([sys.executable, "-m", "bnptrack", "track", str(log), "--tracker", "ddp-mb", "--seed", "2",
                    "--out", str(plain), "-q"], check=True, capture_output=True)
    with open(plain, "rb") as fh:
        assert "/tracks_online" not in {c.topic for c in make_reader(fh).get_summary().channels.values()}
    bad = subprocess.run([sys.executable, "-m", "bnptrack", "track", str(log), "--lag", "-1", "-q"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--lag" in bad.stderr


def test_a_lagged_ddp_run_resumed_from_a_snapshot_publishes_the_same():
    from bnptrack.tracker.lag import restore_lag, snapshot_lag
    from bnptrack.tracker.state import tracker_frame_rng

    frames = bnptrack.simulate("vo2017", seed=6)[:24]
    tracker = bnptrack.make_tracker("ddp")
    layer = FixedLag(tracker, tracker.params, 3)
    whole = [e for _f, e, _s in run_lagged(layer, frames, 5)]
    state, resumed = layer.initial_state(), []
    for i, f in enumerate(frames):
        if i == 12:  # a crash after frame 11: restart from the snapshot
            state = restore_lag(snapshot_lag(state), type(tracker.initial_state()))
        state, out = layer.step(state, f, tracker_frame_rng(5, f.frame))
        resumed += [] if out.lagged is None else [out.lagged]
    resumed += [e for _f, e in layer.flush(state)]
    assert len(resumed) == len(whole) == 24
    for a, b in zip(whole, resumed):
        assert a.labels == b.labels and a.assignments == b.assignments
        for ta, tb in zip(a.tracks, b.tracks):
            assert np.array_equal(ta.state, tb.state) and np.array_equal(ta.covariance, tb.covariance)
