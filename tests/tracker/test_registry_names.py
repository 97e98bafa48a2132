"""Tracker names: ``ddp`` / ``dpyp`` build the two-level
trackers, ``ddp-mb`` / ``dpyp-mb`` the single-level one, and the two-level aliases
``ddp-groups`` / ``dpyp-groups`` still resolve to the same trackers and presets."""

import msgspec
import pytest

from bnptrack.tracker.bnp import TRACKER_PRESETS, BnpConfig, BnpTracker
from bnptrack.tracker.bnp.groups import GROUP_PRESETS, GroupConfig, GroupTracker
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.registry import ALIASES, TRACKERS, build, kind


@pytest.fixture(scope="module")
def params():
    return load_params("vo2017")


@pytest.mark.parametrize(("name", "infer_d"), [("ddp", False), ("dpyp", True)])
def test_ddp_and_dpyp_build_the_two_level_tracker(params, name, infer_d):
    tr = build(name, params)
    assert type(tr) is GroupTracker and tr.name == name
    assert tr.config == GROUP_PRESETS[name] and tr.config.infer_d is infer_d
    assert type(tr.objects) is BnpTracker and tr.objects.config.d == 0.0  # the object level: single-level ddp
    assert kind(name).config_cls is GroupConfig


@pytest.mark.parametrize(("name", "d", "infer_d"), [("ddp-mb", 0.0, False), ("dpyp-mb", 0.1, True)])
def test_the_mb_names_build_the_single_level_tracker(params, name, d, infer_d):
    tr = build(name, params)
    assert type(tr) is BnpTracker and tr.name == name
    assert tr.config == TRACKER_PRESETS[name] and (tr.config.d, tr.config.infer_d) == (d, infer_d)
    assert kind(name).config_cls is BnpConfig
    assert set(kind(name).presets) == {"ddp-mb", "dpyp-mb", "ddp-mb-proximity", "ddp-mb-snr"}


@pytest.mark.parametrize(("old", "new"), [("ddp-groups", "ddp"), ("dpyp-groups", "dpyp")])
def test_the_old_two_level_names_still_resolve(params, old, new):
    assert ALIASES[old] == new and old in TRACKERS
    tr = build(old, params)
    assert type(tr) is GroupTracker and tr.config == build(new, params).config
    presets = kind(old).presets
    assert presets == kind(new).presets
    for suffix in ("", "-proximity", "-snr"):
        if old == "ddp-groups" or not suffix:
            assert presets[old + suffix] is presets[new + suffix]


def test_the_two_level_presets_wrap_the_single_level_presets():
    """``ddp-proximity`` / ``ddp-snr`` / ``ddp-paper`` (two level) have the object level of
    ``ddp-mb-proximity`` / ``ddp-mb-snr`` / ``ddp-mb``; the default ``ddp``, that of ``ddp-mb`` with the
    combined update."""
    for suffix in ("-proximity", "-snr"):
        assert GROUP_PRESETS["ddp" + suffix].objects == TRACKER_PRESETS["ddp-mb" + suffix]
    assert GROUP_PRESETS["ddp-paper"].objects == TRACKER_PRESETS["ddp-mb"]
    assert GROUP_PRESETS["ddp"].objects == msgspec.structs.replace(TRACKER_PRESETS["ddp-mb"], state_update="combined")
    assert GROUP_PRESETS["ddp"].merge_label == "oldest" and GROUP_PRESETS["ddp-paper"].merge_label == "oldest"
    assert "ddp" not in TRACKER_PRESETS and "dpyp" not in TRACKER_PRESETS


def test_the_default_tracker_is_the_two_level_ddp():
    from bnptrack.pipeline.config import PipelineConfig

    assert PipelineConfig().tracker.tracker == "ddp" and TRACKERS[:3] == ("ddp", "dpyp", "glmb")
