"""Ctrl-C (SIGINT) or SIGTERM during ``bnptrack track``: the run ends as if the log ended at
that frame (every output a complete file that any MCAP reader reads, a lagged run's window
published), the summary is printed, exit code 130; a second signal interrupts at once."""

from __future__ import annotations

import signal

import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from bnptrack.pipeline import offline
from bnptrack.pipeline.cli import main
from bnptrack.pipeline.stop_request import StopOnSignal
from bnptrack.sources.mcap_log import iter_frames, iter_tracks

from testkit import REPO_ROOT

LOG = REPO_ROOT / "recordings" / "vo2017-s1.mcap"


def _signalling_frames(sig: int, after: int):
    """``iter_frames`` that raises ``sig`` in this process when asked for the frame after
    frame ``after`` (as a user's Ctrl-C between two frames)."""
    def frames(path, topic_map=None):
        for f in iter_frames(path, topic_map or {}):
            if f.frame == after + 1:
                signal.raise_signal(sig)
            yield f
    return frames


def test_the_first_signal_ends_the_items_and_a_second_interrupts():
    before = signal.getsignal(signal.SIGTERM)
    seen = []
    with StopOnSignal() as stop:
        for k in stop.until_stopped(range(10)):
            seen.append(k)
            if k == 3:
                signal.raise_signal(signal.SIGTERM)
        assert stop.signal_name == "SIGTERM" and stop.cut_short
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
    assert seen == [0, 1, 2, 3]
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize("sig, lag", [(signal.SIGINT, 0), (signal.SIGTERM, 2)])
def test_a_signal_ends_track_with_complete_outputs_and_exit_130(tmp_path, monkeypatch, sig, lag):
    before = signal.getsignal(sig)
    monkeypatch.setattr(offline, "iter_frames", _signalling_frames(sig, after=12))
    out = tmp_path / "t.mcap"
    res = CliRunner().invoke(main, ["track", str(LOG), "--out", str(out), "--lag", str(lag)])
    assert res.exit_code == 130, res.output
    name = signal.Signals(sig).name
    assert (f"Interrupted by {name}: tracked and wrote 12 frame(s) (up to log frame 12); "
            "the outputs are complete files") in res.output
    assert "frames            12\n" in res.output  # the summary is printed
    assert [e.frame for e in iter_tracks(out)] == list(range(1, 13))  # the lag window published too
    with open(out, "rb") as f:  # the footer is written: the mcap library reads every message
        topics = [ch.topic for _, ch, _ in make_reader(f).iter_messages()]
    assert topics.count("/tracks") == 12 and topics.count("/measurements") == 12
    assert signal.getsignal(sig) is before  # the command puts the handlers back


def test_a_signal_after_the_input_ended_does_not_cut_the_run_short():
    with StopOnSignal() as stop:
        assert list(stop.until_stopped(range(3))) == [0, 1, 2]
        signal.raise_signal(signal.SIGTERM)  # while the outputs are closed, say
    assert stop.signal_name == "SIGTERM" and not stop.cut_short
