"""``benchmarks/scale.py``'s dense scene: the initial tracks' covariance (``--seed-std``)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

import benchmarks.scale as scale
from bnptrack.tracker.registry import build


def test_seeded_tracks_carry_the_given_position_and_velocity_std():
    params = scale.dense_params()
    x = np.array([[100.0, 1.0, 500.0, -2.0, 0.0], [-300.0, 5.0, 900.0, 0.0, 0.0]])
    tracker = build("ddp", params)
    default = scale.seeded_state(tracker, x)
    np.testing.assert_array_equal(np.diagonal(default.cov, axis1=1, axis2=2),
                                  [[100.0, 4.0, 100.0, 4.0, 1e-4]] * 2)
    wide = scale.seeded_state(tracker, x, 20.0, 8.0)
    np.testing.assert_array_equal(np.diagonal(wide.cov, axis1=1, axis2=2), [[400.0, 64.0, 400.0, 64.0, 1e-4]] * 2)
    assert wide.labels == (f"{scale.SEED_FRAME}.0", f"{scale.SEED_FRAME}.1")
    np.testing.assert_array_equal(wide.mean, x)


def test_seed_std_parses_two_positive_numbers():
    assert scale._seed_std("20,8") == (20.0, 8.0)
    for bad in ("20", "20,x", "0,8", "20,-1", "nan,8"):
        with pytest.raises(argparse.ArgumentTypeError):
            scale._seed_std(bad)
