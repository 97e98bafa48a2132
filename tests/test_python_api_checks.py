"""The Python API's checks of what the caller passes (docs/python.md): each mistake is one
``ConfigError`` line naming the argument as written in the call."""

from __future__ import annotations

import pytest

import bnptrack
from bnptrack.tracker.config import ConfigError


@pytest.mark.parametrize("call", [
    lambda: bnptrack.track([], scenario="vo2071"),
    lambda: bnptrack.make_tracker(scenario="vo2071"),
    lambda: bnptrack.simulate(scenario="vo2071"),
])
def test_an_unknown_scenario_is_an_error_with_the_close_name(call):
    with pytest.raises(ConfigError, match=r"\(scenario='vo2071'\): unknown scenario \(did you mean 'vo2017'\?\)"):
        call()
