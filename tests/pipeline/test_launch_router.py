"""The launcher's embedded Zenoh router opens without Zenoh's 500 ms scouting wait
(``pipeline.launch_setup._quick_router``, docs/performance.md, start-up), unless the user
set ``scouting/delay`` or turned multicast scouting on; the stages' settings are untouched."""

from __future__ import annotations

import msgspec

from bnptrack.pipeline.config import ZenohConfig
from bnptrack.pipeline.launch_setup import _quick_router


def test_the_embedded_router_does_not_wait_for_scouting() -> None:
    z = ZenohConfig(router_extra={"transport/link/tx/lease": "5000"})
    quick = _quick_router(z)
    assert quick.router_extra == {"transport/link/tx/lease": "5000", "scouting/delay": "0"}
    assert z.router_extra == {"transport/link/tx/lease": "5000"}  # the caller's settings unchanged
    assert msgspec.structs.replace(quick, router_extra=z.router_extra) == z


def test_a_users_scouting_settings_are_kept() -> None:
    own = ZenohConfig(router_extra={"scouting/delay": "250"})
    assert _quick_router(own) is own
    scouting = ZenohConfig(multicast_scouting=True)
    assert _quick_router(scouting) is scouting
