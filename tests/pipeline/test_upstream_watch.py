"""``UpstreamWatch`` counts ``upstream_gone_s`` from the first poll that finds the upstream
gone, so a stage whose polls lag behind its clock never stops waiting before the upstream
has been gone that long (a fake bus and clock; no Zenoh)."""

from __future__ import annotations

from bnptrack.pipeline.stages.salvage import UpstreamWatch


class _Bus:
    def __init__(self) -> None:
        self.live: set[str] = {"source"}
        self.cached: dict[str, object] = {}

    def alive(self) -> set[str]:
        return set(self.live)

    def head(self, topic: str):
        return self.cached.get(topic)


def test_the_count_starts_when_the_absence_is_first_seen():
    bus, now = _Bus(), [0.0]
    watch = UpstreamWatch(bus, ["source"], ["/measurements"], 5.0, lambda: now[0])
    assert not watch.gone()  # t = 0: the source is alive
    bus.live.clear()  # it leaves; the next poll comes 10 s later (a lagging stage)
    now[0] = 10.0
    assert not watch.gone()  # first seen gone at 10: the count starts here, not at 0
    now[0] = 14.9
    assert not watch.gone()
    now[0] = 15.0
    assert watch.gone()


def test_a_live_upstream_or_a_cache_starts_the_count_again():
    bus, now = _Bus(), [0.0]
    bus.live.clear()
    watch = UpstreamWatch(bus, ["source"], ["/measurements"], 5.0, lambda: now[0])
    now[0] = 4.0
    assert not watch.gone()  # absent since construction, 4 s < 5 s
    bus.cached["/measurements"] = object()
    now[0] = 5.0
    assert not watch.gone()  # time is up but a cache answers: count again from 5
    bus.cached.clear()
    now[0] = 9.9
    assert not watch.gone()
    now[0] = 10.0
    assert watch.gone()
    bus.live.add("source")
    now[0] = 11.0
    assert not watch.gone()
