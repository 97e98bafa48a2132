"""Identities through a crossing under the default two-level tracker: a hand-built scene of two
objects that cross, seed-pinned against the JPDA* update with the shorter sharing guard."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from bnptrack.sinks.crossings import crossing_label_keeping
from bnptrack.sources.scene import Scenario, TargetSpec
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.bnp.config import TRACKER_PRESETS
from bnptrack.tracker.bnp.group_config import GROUP_PRESETS, GroupConfig
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.registry import build
from bnptrack.tracker.state import run

#: The JPDA* update (the whole detection on the best one-to-one assignment) with sharing
#: after six scans together: the comparison setting.
JPDA_STAR_6 = msgspec.structs.replace(GROUP_PRESETS["ddp"], objects=TRACKER_PRESETS["ddp-mb"], share_after=6)


def _crossing(c: int = 15, K: int = 30) -> Scenario:
    """Two objects at 20 m/s, headings 60 deg apart, meeting at scan ``c`` at (0, 1200) m: 1200 m
    from the vo2017 sensor, where its 2-deg bearing noise is 42 m across the line of sight."""
    p = np.array([0.0, 1200.0])
    targets = []
    for name, heading in (("A", 90.0), ("B", 150.0)):
        v = 20.0 * np.array([np.cos(np.deg2rad(heading)), np.sin(np.deg2rad(heading))])
        start = p - c * v  # xstart is the state one scan before birth (scan 1)
        targets.append(TargetSpec(name, (start[0], v[0], start[1], v[1], 0.0), 1, K))
    return Scenario("crossing", "two objects crossing", K=K, targets=tuple(targets), birth=(),
                    crossings=(("A", "B", c),))


def _labels(config: GroupConfig, seed: int):
    sc = _crossing()
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, seed)
    ests = [e for _, e, _ in run(build("ddp", params, config), frames, seed)]
    truth = [dict(zip(f.truth.ids, f.truth.positions)) for f in frames]
    tracks = [{t.label: t.position for t in e.tracks} for e in ests]
    pair = crossing_label_keeping(truth, tracks, sc.crossings).pairs[0]
    return pair.labels_before, pair.labels_after


@pytest.mark.parametrize(("seed", "before"), [(6, ("1.12", "1.0")), (21, ("1.3", "1.9")), (23, ("1.1", "1.4"))])
def test_the_default_keeps_both_labels_where_the_jpda_star_update_swaps_them(seed, before):
    """Seed-pinned (measured on seeds 1-40 of this scene: the default keeps 40 of 40 pairs, the
    JPDA* update with sharing after six scans 29): scans 10 and 20 carry the same two labels under the default and
    exchanged ones under the JPDA* update with sharing after six scans."""
    assert _labels(GROUP_PRESETS["ddp"], seed) == (before, before)
    assert _labels(JPDA_STAR_6, seed) == (before, before[::-1])


def test_the_default_differs_from_the_paper_preset_only_in_the_update_and_the_sharing_guard():
    cfg = GROUP_PRESETS["ddp"]
    assert cfg.objects.state_update == "combined" and cfg.share_after == 12
    assert GROUP_PRESETS["ddp-paper"] == GroupConfig(objects=TRACKER_PRESETS["ddp-mb"])
    assert TRACKER_PRESETS["ddp-mb"].state_update == "best-permutation"
    assert msgspec.structs.replace(cfg, objects=TRACKER_PRESETS["ddp-mb"], share_after=0) == GROUP_PRESETS["ddp-paper"]
