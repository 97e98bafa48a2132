"""Fault cases of ``benchmarks/faults.py`` about stage keys, ends of stream and exit codes
(families ``stolen-key`` and ``exit-truth``; the helpers are faults.py's).

* ``stolen-key``: ``runs`` default launches (a 60-frame replay at 20 frames/s), each attacked
  while it runs by another process of the same user that takes every password it can find
  in the stages' view (``/proc/<pid>/environ``, ``cmdline``, open descriptors, the run's
  files) and puts a forged ``eos/source`` as ``source`` with each (none found: no password,
  a wrong one): holds when the session is refused and the run ends identical to offline
  ``track``; plus ``runs`` launches with authentication off (anyone may put, as with a
  stolen key) given a forged ``eos/source`` at seq 5: holds on exit 3 naming the end of
  stream conflict.
* ``exit-truth``: a tracker SIGKILLed after its end of stream with ``max_restarts = 0``
  (the sink held by SIGSTOP meanwhile): holds on exit 0 and tracks identical to offline; a
  launcher SIGKILLed mid-run: holds when every stage stops, ``sink.json`` is incomplete and
  names the rest of the run as missing, and ``stages.json`` shows no stage running.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path

from faults import ROOT, finish, judge, make_log, offline_tracks, replay, snapshot_seq, stage_pid, wait_until

__all__ = ["family_stolen_key", "family_exit_truth"]


def _attack_helpers():
    sys.path[:0] = [str(ROOT / "tests" / "integration"), str(ROOT / "tests")]  # the tests' attack
    from test_stage_keys import forge_eos, harvest

    return forge_eos, harvest


def _stolen_key_case(work: Path, i: int, log: Path, expected: list, open_mode: bool) -> dict:
    forge_eos, harvest = _attack_helpers()
    out = work / f"stolen-{'open' if open_mode else 'closed'}{i}"
    p = replay(log, out, 20, 150, *(["--set", "zenoh.auth=false"] if open_mode else []))
    attack, found = "not attempted", 0
    if wait_until(lambda: snapshot_seq(out) >= 10, p, 120):
        cfg = json.loads((out / "pipeline.json").read_text())
        endpoint, run = cfg["zenoh"]["connect"][0], cfg["run"]
        if open_mode:
            attack = forge_eos(endpoint, run, 5)
        else:
            pids = [pid for role in ("source", "tracker", "sink") if (pid := stage_pid(out, role))]
            keys = harvest(pids, out)
            found = len(keys)
            results = {forge_eos(endpoint, run, 5, "source", pw) for pw in sorted(keys) or ["", "wrong"]}
            attack = "refused" if results == {"refused"} else "sent"
    code, text = finish(p, 180)
    if open_mode:
        ok = code == 3 and "end of stream conflict" in text
        why = "exit 3 naming the end of stream conflict" if ok else f"exit {code}: {text.strip().splitlines()[-1:]}"
    else:
        ok, why = judge(code, text, out, expected)
        ok = ok and attack == "refused" and found == 0
    return {"family": "stolen-key", "role": "open" if open_mode else "default", "keys_found": found,
            "attack": attack, "exit": code, "ok": ok, "why": why}


def family_stolen_key(work: Path, runs: int) -> list[dict]:
    log = make_log(work / "vo60k.mcap", 60)
    expected = offline_tracks(log, work / "off60k.mcap")
    cases = []
    for open_mode in (False, True):
        for i in range(runs):
            cases.append(_stolen_key_case(work, i, log, expected, open_mode))
            print(json.dumps(cases[-1]), flush=True)
    return cases


def _given_up_tracker(work: Path, log: Path, expected: list) -> dict:
    out = work / "given-up"
    p = replay(log, out, 10, 150, "--set", "supervisor.max_restarts=0")
    sink = None
    try:
        if wait_until(lambda: snapshot_seq(out) >= 5, p, 120) and (sink := stage_pid(out, "sink")):
            os.kill(sink, signal.SIGSTOP)
            tlog = out / "logs" / "tracker.log"
            if wait_until(lambda: "processed 30 frame(s)" in tlog.read_text(), p, 60):
                os.kill(stage_pid(out, "tracker") or 0, signal.SIGKILL)
                wait_until(lambda: json.loads((out / "stages.json").read_text())["tracker"]["state"] == "failed", p, 30)
    finally:
        if sink:
            try:
                os.kill(sink, signal.SIGCONT)
            except ProcessLookupError:
                pass
    code, text = finish(p, 180)
    ok, why = judge(code, text, out, expected)
    ok = ok and code == 0
    return {"family": "exit-truth", "role": "tracker given up after its end of stream", "exit": code, "ok": ok, "why": why}


def _alive(pid: int) -> bool:
    try:
        return "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False


def _launcher_killed(work: Path, log: Path) -> dict:
    from bnptrack.pipeline.stages.summary import load_summary

    out = work / "orphans"
    p = replay(log, out, 20, 150)
    pids: list[int] = []
    if wait_until(lambda: snapshot_seq(out) >= 10, p, 120):
        pids = [pid for role in ("source", "tracker", "sink") if (pid := stage_pid(out, role))]
        os.kill(p.pid, signal.SIGKILL)
    finish(p, 60)
    stopped = _wait_gone(pids, 60)
    try:
        s = load_summary(out / "sink.json")
        st = json.loads((out / "stages.json").read_text())
    except (OSError, ValueError) as exc:  # a malformed sink.json is a ValueError (SummaryError)
        return {"family": "exit-truth", "role": "launcher killed", "exit": None, "ok": False, "why": str(exc)}
    named = s is not None and not s.output_complete and bool(s.missing)
    shown = all(v["state"] != "running" for v in st.values())
    ok = bool(pids) and stopped and named and shown
    why = f"sink.json names {len(s.missing) if s else 'no'} missing range(s); stages.json: " + \
        ", ".join(f"{k} {v['state']}" for k, v in st.items())
    return {"family": "exit-truth", "role": "launcher killed", "exit": None, "ok": ok, "why": why}


def _wait_gone(pids: list[int], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while any(_alive(x) for x in pids):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def family_exit_truth(work: Path) -> list[dict]:
    log = make_log(work / "vo30e.mcap", 30)
    expected = offline_tracks(log, work / "off30e.mcap")
    cases = [_given_up_tracker(work, log, expected), _launcher_killed(work, make_log(work / "vo200e.mcap", 200))]
    for c in cases:
        print(json.dumps(c), flush=True)
    return cases
