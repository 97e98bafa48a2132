"""Zenoh's shared-memory transport is off in every session bnptrack opens.

Zenoh 1.x turns it on by default and sends each sample above 3 KB through a shared-memory
pool that the first such put creates on the publishing thread (a file in /dev/shm, mapped
and mlocked, two watchdog threads): that put blocked for 5 to 120 ms, and it was the
tracker's first /tracks of several KB in every run (docs/pipeline.md, Performance).  These
tests check the setting, and that large samples then travel without any shared-memory
segment in the process (the same scenario with shared memory turned back on through
``zenoh.extra`` maps one: the check is not blind).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from bnptrack.pipeline.config import ZenohConfig
from bnptrack.pipeline.transport import SHM_OFF, session_config

from testkit import bnptrack_env

#: A router and two stage buses in one process: 3 samples of 20 KB on ``tracks`` (above
#: Zenoh's 3 KB shared-memory threshold), then what arrived and the process's mappings of
#: Zenoh shared-memory segments (``/dev/shm/<id>.zenoh``).
_SCRIPT = r"""
import json, sys, time
from bnptrack.pipeline.config import DeliveryConfig, ZenohConfig
from bnptrack.pipeline.transport import Bus, Router
extra = json.loads(sys.argv[1])
sent = [bytes([65 + i]) * 20_000 for i in range(3)]
with Router(ZenohConfig(extra=extra)) as router:
    zc = ZenohConfig(connect=router.connect_endpoints, extra=extra)
    with Bus("shm", "sub", zc, DeliveryConfig()) as sub, Bus("shm", "pub", zc, DeliveryConfig()) as pub:
        sub.subscribe(["tracks"])
        pub.declare(["tracks"])
        got, deadline = [], time.monotonic() + 20
        while not got and time.monotonic() < deadline:  # until the subscription is known
            pub.publish("tracks", b"{}", {"seq": -1, "t": 0})
            got = [ev for ev in iter(lambda: sub.recv(0.2), None)]
        for i, payload in enumerate(sent):
            pub.publish("tracks", payload, {"seq": i, "t": 0})
        recv = []
        while len(recv) < 3 and time.monotonic() < deadline:
            ev = sub.recv(0.5)
            if ev is not None and ev.meta.get("seq", -1) >= 0:
                recv.append(ev)
        with open("/proc/self/maps") as f:
            maps = sorted({l.split()[-1] for l in f if "/dev/shm/" in l and l.rstrip().endswith(".zenoh")})
        print(json.dumps({"equal": [ev.payload for ev in recv] == sent,
                          "seqs": [ev.meta["seq"] for ev in recv], "shm": maps}))
"""


def _run(extra: dict[str, str]) -> dict:
    out = subprocess.run([sys.executable, "-c", _SCRIPT, json.dumps(extra)], env=bnptrack_env(),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_session_config_turns_shared_memory_off_unless_extra_turns_it_on():
    assert SHM_OFF == ("transport/shared_memory/enabled", "false")
    assert session_config(ZenohConfig()).get_json("transport/shared_memory/enabled") == "false"
    assert session_config(ZenohConfig(), router=True).get_json("transport/shared_memory/enabled") == "false"
    on = ZenohConfig(extra={"transport/shared_memory/enabled": "true"})
    assert session_config(on).get_json("transport/shared_memory/enabled") == "true"


@pytest.mark.parametrize("shm", [False, True])
def test_large_samples_travel_without_a_shared_memory_segment(shm):
    res = _run({"transport/shared_memory/enabled": "true"} if shm else {})
    assert res["equal"] and res["seqs"] == [0, 1, 2]
    if shm:  # Zenoh's default: the large samples went through a segment this process mapped
        assert len(res["shm"]) >= 1
    else:
        assert res["shm"] == []
