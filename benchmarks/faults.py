"""Reliability figures of the pipeline: cases tried, cases with nothing lost.

Each family of faults is run against real stage processes on loopback (or, for the file
and sample cases, against the same code in this process) and scored: a case *holds* when
nothing is lost -- the output equals offline ``bnptrack track`` on the same frames, or the run
exits non-zero naming what is missing -- with no hang (every run ends within its timeout) and
no stage crash.

Families (``--only`` picks some):

* ``kill``: SIGKILL of the tracker and of the sink at ``--points`` seeded moments each of a
  100-frame replay at 25 frames/s (moments drawn from the tracker's snapshot progress, so
  some land during a snapshot write), plus one kill of each just after the end of stream
  (when ``sink.json`` appears); ``--long N``: N kills of each in 2,000-frame replays at
  50 frames/s;
* ``stop``: SIGSTOP of the tracker for 7 s (past Zenoh's 5 s blocking limit), then SIGCONT;
* ``forged``: an outsider's forged ``eos/source`` and ``/measurements`` (frame 10**9, sequence
  numbers inside and far past the window) against a default launch (must be refused);
* ``malformed``: ``--malformed`` malformed samples (garbage, truncated JSON, non-finite
  numbers, wrong run, sequence numbers past 2**53, bad or missing attachments, 100 KB of
  ``[``) put by an outsider on a running replay with authentication off (the defence in
  depth); the peak RSS of each stage process is sampled from /proc;
* ``mcap``: a log cut at 100 offsets and with 100 flipped bytes: the reader yields a prefix
  of the frames and then stops with ``McapLogError`` (never another exception, never a
  frame that differs);
* ``full``: the output directory on a 300 KB tmpfs (needs root to mount): exit non-zero
  within 10 s after the disk fills, one line naming the file and the stage, no ``.part`` or
  temporary files left;
* ``taken``: a launch on an ``--out`` that holds another run: refused (exit 2), the other
  run's files unchanged;
* ``stolen-key``, ``exit-truth``: stage keys taken from another process's view and forged ends
  of stream; exit codes that follow the output (``benchmarks/faults_eos.py``);
* ``router``, ``open``, ``viewer``, ``hostile``: see :mod:`fault_cases` (a router killed and
  restarted, open-mode samples far ahead or copied, a frozen live viewer, hostile logs through
  ``track`` and ``replay``);
* ``restart-alone``: a stage started by hand (``bnptrack stage``, on a router of its own) after
  the others have left: ``--points`` runs (100 frames at 25 frames/s, ``max_restarts = 0``)
  whose sink is SIGKILLed at a seeded frame, then a sink started by hand must end within 90 s
  with exit 3, the killed sink's frames intact (equal to offline ``track``) and sink.json
  naming the missing rest (exit 2 and nothing touched when the killed sink had written no
  frame); plus the tracker of such a run started by hand (exit 3, snapshot and journal
  unchanged) and a sink started by hand after a complete run (exit 0, files unchanged).

    nice -n 5 python benchmarks/faults.py                 # every family, 10 points each
    python benchmarks/faults.py --only kill --points 3 --json out.json
    nice -n 5 python benchmarks/faults.py --only restart-alone --points 10
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

VO2017 = ROOT / "recordings" / "vo2017-s1.mcap"

sys.path.insert(0, str(ROOT / "benchmarks"))
import fault_cases  # noqa: E402  (more families, same helpers)


# --------------------------------------------------------------------------- helpers


def make_log(path: Path, n: int) -> Path:
    """``n`` frames: the 100 frames of recordings/vo2017-s1.mcap repeated, frame numbers and
    stamps (1 s apart) made consecutive."""
    from bnptrack.sinks.mcap_writer import McapLogWriter
    from bnptrack.sources.mcap_log import iter_frames, read_metadata
    from bnptrack.tracker.types import Frame

    base = list(iter_frames(VO2017))
    dt = base[1].stamp_ns - base[0].stamp_ns
    with McapLogWriter(path, read_metadata(VO2017)) as w:
        for i in range(n):
            f = base[i % len(base)]
            w.write_frame(Frame(i + 1, (i + 1) * dt, f.sensor, f.kind, f.z, f.truth))
    return path


def tracks_of(path: Path) -> list:
    from bnptrack.sources.mcap_log import read_log

    def strip(e):
        d = {k: v for k, v in e.diagnostics.items() if k != "ms"}
        return (e.frame, e.labels, e.assignments, d, [(t.state.tolist(), t.existence) for t in e.tracks])

    return [strip(e) for e in read_log(path).tracks]


def offline_tracks(log: Path, out: Path) -> list:
    from bnptrack.pipeline.offline import track_log
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.sources.mcap_log import read_metadata

    meta = read_metadata(log)
    track_log(log, out, tracker_setup("ddp", metadata=meta).tracker, 0, meta)
    return tracks_of(out)


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["RERUN_ANALYTICS"] = "0"
    return env


def replay(log: Path, out: Path, rate: float | None, timeout: float, *extra: str) -> subprocess.Popen:
    """``bnptrack replay LOG`` at ``rate`` (``None``: as fast as possible) into ``out``."""
    pace = ["--rate", str(rate)] if rate else ["--as-fast-as-possible"]
    return subprocess.Popen(
        [sys.executable, "-m", "bnptrack", "replay", str(log), *pace, "--set", "sink.rerun=false",
         "--set", "tracker.snapshot_every=10", *extra, "--out", str(out), "--overwrite", "--timeout", str(timeout)],
        cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)


def finish(p: subprocess.Popen, timeout: float) -> tuple[int | None, str]:
    """Exit code and output; ``None`` on a hang (then the process group is killed)."""
    try:
        out, _ = p.communicate(timeout=timeout)
        return p.returncode, out.decode(errors="replace")
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, _ = p.communicate(timeout=10)
        return None, out.decode(errors="replace")


def snapshot_seq(out: Path) -> int:
    from bnptrack.pipeline.stages import read_snapshot

    try:
        return read_snapshot(out / "tracker.snap").last_seq
    except Exception:
        return -1


def stage_pid(out: Path, role: str) -> int | None:
    try:
        return json.loads((out / "stages.json").read_text())[role]["pid"]
    except (OSError, ValueError, KeyError):
        return None


def wait_until(cond, p: subprocess.Popen, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if p.poll() is not None or time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def judge(code: int | None, text: str, out: Path, expected: list) -> tuple[bool, str]:
    """Nothing lost: exit 0 and tracks equal to offline, or exit 3 naming what is missing."""
    if code is None:
        return False, "hang"
    if code == 0:
        try:
            same = tracks_of(out / "tracks.mcap") == expected
        except Exception as exc:
            return False, f"unreadable output: {exc}"
        return same, "identical" if same else "exit 0 but tracks differ from offline"
    if code == 3 and "missing" in text:
        return True, "exit 3 naming what is missing"
    return False, f"exit {code}: {text.strip().splitlines()[-1:] }"


# --------------------------------------------------------------------------- families


def family_kill(work: Path, points: int, long_runs: int, seed: int) -> list[dict]:
    rng = random.Random(seed)
    cases = []
    short = make_log(work / "vo100.mcap", 100)
    expected = offline_tracks(short, work / "off100.mcap")
    plans = [(role, "short", rng.randrange(5, 95)) for role in ("tracker", "sink") for _ in range(points)]
    plans += [(role, "short", "eos") for role in ("tracker", "sink")]
    if long_runs:
        long_log = make_log(work / "vo2000.mcap", 2000)
        expected_long = offline_tracks(long_log, work / "off2000.mcap")
        plans += [(role, "long", rng.randrange(100, 1900)) for role in ("tracker", "sink") for _ in range(long_runs)]
    for i, (role, size, at) in enumerate(plans):
        log, rate, exp, t_max = (short, 25, expected, 180) if size == "short" else (long_log, 50, expected_long, 400)
        out = work / f"kill{i}"
        p = replay(log, out, rate, t_max - 30)
        if at == "eos":
            reached = wait_until((out / "sink.json").exists, p, t_max)
        else:
            reached = wait_until(lambda: snapshot_seq(out) >= at, p, t_max)
        pid = stage_pid(out, role)
        killed = False
        if reached and pid:
            try:
                os.kill(pid, signal.SIGKILL)
                killed = True
            except ProcessLookupError:
                pass
        code, text = finish(p, t_max)
        ok, why = judge(code, text, out, exp)
        cases.append({"family": "kill", "role": role, "run": size, "at": at, "killed": killed,
                      "exit": code, "ok": ok, "why": why})
        print(json.dumps(cases[-1]), flush=True)
    return cases


def family_stop(work: Path) -> list[dict]:
    log = make_log(work / "vo100s.mcap", 100)
    expected = offline_tracks(log, work / "off100s.mcap")
    out = work / "stop"
    p = replay(log, out, 25, 150)
    ok_reach = wait_until(lambda: snapshot_seq(out) >= 20, p, 120)
    pid = stage_pid(out, "tracker")
    if ok_reach and pid:
        os.kill(pid, signal.SIGSTOP)
        try:  # the stop lasts 7 s of wall time (or until the launch ends)
            p.wait(7)
        except subprocess.TimeoutExpired:
            pass
        os.kill(pid, signal.SIGCONT)
    code, text = finish(p, 180)
    ok, why = judge(code, text, out, expected)
    case = {"family": "stop", "role": "tracker", "seconds": 7, "exit": code, "ok": ok, "why": why}
    print(json.dumps(case), flush=True)
    return [case]


def family_forged(work: Path) -> list[dict]:
    sys.path[:0] = [str(ROOT / "tests" / "integration"), str(ROOT / "tests")]  # the test and its testkit
    from test_pipeline_faults import _forge  # the attack the tests run

    log = make_log(work / "vo60.mcap", 60)
    expected = offline_tracks(log, work / "off60.mcap")
    cases = []
    for who in ("anonymous", "wrong-password"):
        out = work / f"forged-{who}"
        p = replay(log, out, 20, 150)
        res = "not attempted"
        if wait_until(lambda: snapshot_seq(out) >= 10, p, 120):
            endpoint = json.loads((out / "pipeline.json").read_text())["zenoh"]["connect"][0]
            run = json.loads((out / "pipeline.json").read_text())["run"]
            res = _forge(endpoint, run, *(("", "") if who == "anonymous" else ("source", "wrong")))
        code, text = finish(p, 180)
        ok, why = judge(code, text, out, expected)
        ok = ok and res == "refused"
        cases.append({"family": "forged", "who": who, "attack": res, "exit": code, "ok": ok, "why": why})
        print(json.dumps(cases[-1]), flush=True)
    return cases


def _malformed(rng: random.Random, run: str, good: bytes) -> tuple[bytes, bytes | None]:
    kind = rng.randrange(8)
    seq = rng.randrange(0, 40)
    att = json.dumps({"seq": seq, "t": 1}).encode()
    if kind == 0:
        return bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 200))), att
    if kind == 1:
        return good[: rng.randrange(1, len(good))], att
    if kind == 2:
        return good.replace(b'"frame":', b'"frame":1e999,"x":', 1), att
    if kind == 3:
        return good.replace(run.encode(), b"other-run", 1), att
    if kind == 4:
        return good, json.dumps({"seq": 2**60}).encode()
    if kind == 5:
        return good, b"not json"
    if kind == 6:
        return good, None
    return b"[" * 100_000, att


def _rss_mb(pid: int | None) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except (OSError, ValueError):
        pass
    return 0.0


def family_malformed(work: Path, n: int, seed: int) -> list[dict]:
    """``n`` malformed samples put by an outsider on ``measurements``, ``truth`` and
    ``tracks`` of a running 100-frame replay at 25 frames/s.  The defence in depth is what is
    measured, so authentication is off for this run (``zenoh.auth=false``: the outsider gets
    in).  The peak RSS of each stage process is sampled from /proc while it runs."""
    from bnptrack.pipeline.stages.summary import load_summary

    import zenoh

    log = make_log(work / "vo100x.mcap", 100)
    expected = offline_tracks(log, work / "off100x.mcap")
    out = work / "malformed"
    p = replay(log, out, 25, 200, "--set", "zenoh.auth=false")
    rng = random.Random(seed)
    peak: dict[str, float] = {}
    sent = 0
    if wait_until(lambda: snapshot_seq(out) >= 10, p, 150):
        cfg = json.loads((out / "pipeline.json").read_text())
        run, endpoint = cfg["run"], cfg["zenoh"]["connect"][0]
        from bnptrack.tracker.messages import encode
        from bnptrack.sources.mcap_log import iter_frames

        good = encode(next(iter(iter_frames(log))), run)
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        pids = {r: stage_pid(out, r) for r in ("source", "tracker", "sink")}
        with zenoh.open(conf) as session:
            topics = ["measurements", "truth", "tracks"]
            for i in range(n):
                payload, att = _malformed(rng, run, good)
                # BLOCK: every sample of the burst reaches the router (DROP would shed some)
                session.put(f"bnptrack/{run}/{topics[i % 3]}", payload, attachment=att,
                            congestion_control=zenoh.CongestionControl.BLOCK)
                sent += 1
                if i % 500 == 0:
                    for r, pid in pids.items():
                        peak[r] = max(peak.get(r, 0.0), _rss_mb(pid))
        while p.poll() is None:
            for r, pid in pids.items():
                peak[r] = max(peak.get(r, 0.0), _rss_mb(pid))
            time.sleep(0.2)
    code, text = finish(p, 250)
    ok, why = judge(code, text, out, expected)
    try:
        rejected = load_summary(out / "sink.json").counters["rejected"]
    except (AttributeError, ValueError, KeyError):  # no sink.json (None), a malformed one, no count
        rejected = None
    ok = ok and sent == n and bool(peak) and max(peak.values()) < 500
    case = {"family": "malformed", "samples": sent, "rejected_by_sink": rejected, "exit": code,
            "peak_rss_mb": {r: round(v, 1) for r, v in peak.items()}, "ok": ok, "why": why}
    print(json.dumps(case), flush=True)
    return [case]


def family_mcap(work: Path, seed: int) -> list[dict]:
    from bnptrack.sources.mcap_log import McapLogError, iter_frames

    import numpy as np

    src = make_log(work / "vo100m.mcap", 100)
    data = src.read_bytes()
    ref = list(iter_frames(src))
    rng = random.Random(seed)
    cases = []
    damaged = [("cut", data[: rng.randrange(1, len(data))]) for _ in range(100)]
    for _ in range(100):
        b = bytearray(data)
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
        damaged.append(("flip", bytes(b)))
    for kind, blob in damaged:
        path = work / "damaged.mcap"
        path.write_bytes(blob)
        got, err = [], ""
        t0 = time.monotonic()
        try:
            for f in iter_frames(path):
                got.append(f)
        except McapLogError:
            err = "McapLogError"
        except Exception as exc:  # anything else is a failure of the reader
            err = f"{type(exc).__name__}: {exc}"
        prefix = all(a.frame == b.frame and np.array_equal(a.z, b.z) for a, b in zip(got, ref)) and len(got) <= len(ref)
        complete = len(got) == len(ref) and not err
        ok = prefix and (err in ("", "McapLogError")) and (complete or err == "McapLogError")
        cases.append({"family": "mcap", "kind": kind, "frames": len(got), "error": err, "ok": ok,
                      "seconds": round(time.monotonic() - t0, 3)})
    bad = [c for c in cases if not c["ok"]]
    print(json.dumps({"family": "mcap", "tried": len(cases), "ok": len(cases) - len(bad), "failures": bad[:5]}),
          flush=True)
    return cases


def family_full(work: Path) -> list[dict]:
    mnt = work / "full"
    mnt.mkdir(exist_ok=True)
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(mnt)], capture_output=True)
    if res.returncode != 0:
        case = {"family": "full", "ok": None, "why": "cannot mount a tmpfs (not root?): not tried"}
        print(json.dumps(case), flush=True)
        return [case]
    try:
        log = make_log(work / "vo300f.mcap", 300)
        out = mnt / "run"
        t0 = time.monotonic()
        p = subprocess.Popen(
            [sys.executable, "-m", "bnptrack", "replay", str(log), "--as-fast-as-possible", "--set",
             "sink.rerun=false", "--out", str(out), "--timeout", "120"],
            cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        code, text = finish(p, 150)
        elapsed = time.monotonic() - t0
        left = [str(f) for f in out.rglob("*") if f.name.endswith((".part", ".tmp"))] if out.exists() else []
        last = text.strip().splitlines()[-1] if text.strip() else ""
        names = "tracks.mcap" in text or "tracker.journal" in text or "tracker.snap" in text
        ok = code not in (0, None) and not left and names and "No space left" in text
        case = {"family": "full", "exit": code, "seconds": round(elapsed, 1), "last_line": last,
                "names_file": names, "temp_left": left, "ok": ok}
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)
    print(json.dumps(case), flush=True)
    return [case]


def family_taken(work: Path) -> list[dict]:
    log = make_log(work / "vo10.mcap", 10)
    out = work / "taken"
    p = replay(log, out, None, 120)
    code1, _ = finish(p, 150)
    before = {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in out.iterdir() if f.is_file()}
    p2 = subprocess.Popen([sys.executable, "-m", "bnptrack", "replay", str(log), "--as-fast-as-possible",
                           "--out", str(out), "--timeout", "60"], cwd=ROOT, env=_env(),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    code2, text = finish(p2, 90)
    after = {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in out.iterdir() if f.is_file()}
    # the lock file holds the pid of the last launcher that took the lock (the refused one
    # takes it to check that no run is live there): not the other run's state
    changed = sorted(k for k in before.keys() | after.keys()
                     if before.get(k) != after.get(k) and k != ".bnptrack.lock")
    ok = code1 == 0 and code2 == 2 and not changed
    case = {"family": "taken", "first_exit": code1, "second_exit": code2, "changed": changed, "ok": ok,
            "line": text.strip().splitlines()[-1:]}
    print(json.dumps(case), flush=True)
    return [case]


def _digests(out: Path, names: list[str]) -> dict[str, str]:
    return {n: hashlib.sha256((out / n).read_bytes()).hexdigest() for n in names if (out / n).exists()}


def _by_hand(role: str, out: Path, timeout: float = 90) -> tuple[int | None, str, float]:
    """``bnptrack stage ROLE`` on a router of its own, nobody else there: exit code (None:
    it did not end within ``timeout``), output, seconds."""
    from bnptrack.pipeline.config import ZenohConfig
    from bnptrack.pipeline.transport import Router

    run = json.loads((out / "pipeline.json").read_text())["run"]
    t0 = time.monotonic()
    with Router(ZenohConfig()) as router:
        p = subprocess.Popen([sys.executable, "-m", "bnptrack", "stage", role, "--run", run, "--connect",
                              router.endpoints[0], "--out", str(out), "--set", "sink.rerun=false"],
                             cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             start_new_session=True)
        code, text = finish(p, timeout)
    return code, text, time.monotonic() - t0


def _sink_killed(log: Path, out: Path, at: int) -> tuple[int | None, bool]:
    """A replay whose sink is SIGKILLed once the tracker passed seq ``at`` (no restart: the
    launcher gives up and stops the others); its exit code and whether the kill happened."""
    p = replay(log, out, 25, 150, "--set", "supervisor.max_restarts=0")
    killed = False
    if wait_until(lambda: snapshot_seq(out) >= at, p, 150) and (pid := stage_pid(out, "sink")):
        try:
            os.kill(pid, signal.SIGKILL)
            killed = True
        except ProcessLookupError:
            pass
    code, _ = finish(p, 180)
    return code, killed


def _judge_alone_sink(out: Path, code: int | None, written: list, expected: list, before: dict) -> tuple[bool, str]:
    """A hand-started sink after its predecessor was killed: exit 3 with the killed sink's
    frames intact (= offline) and the rest named missing; or exit 2, nothing touched, when
    the predecessor had written no frame."""
    from bnptrack.pipeline.stages.summary import load_summary
    from bnptrack.pipeline.stages import salvage_part

    if code is None:
        return False, "hang"
    if not written:
        return code == 2 and _digests(out, list(before)) == before, f"exit {code} with nothing to recover"
    if code != 3:
        return False, f"exit {code}"
    s = load_summary(out / "sink.json")
    same = [f.payloads for f in salvage_part(out / "tracks.mcap", s.run).frames] == [f.payloads for f in written]
    offline_prefix = tracks_of(out / "tracks.mcap") == expected[: len(written)]
    named = bool(s.missing) and all(m["why"].startswith("upstream gone") for m in s.missing)
    ok = same and offline_prefix and named and not s.output_complete and not (out / ".tracks.mcap.part").exists()
    return ok, f"exit 3, {len(written)} frame(s) kept" + ("" if ok else f" (same {same}, offline {offline_prefix}, named {named})")


def _alone_sink_case(work: Path, i: int, log: Path, expected: list, at: int) -> dict:
    from bnptrack.pipeline.stages import salvage_part

    out = work / f"alone{i}"
    launch_code, killed = _sink_killed(log, out, at)
    run = json.loads((out / "pipeline.json").read_text())["run"]
    if launch_code == 0:  # the run was recorded before the kill landed: the complete case
        return _alone_after_complete(out, f"kill at {at} landed after the run")
    found = salvage_part(out / ".tracks.mcap.part", run)
    written = found.frames if found is not None else []
    before = _digests(out, [".tracks.mcap.part", "sink.json", "tracks.mcap"])
    code, text, secs = _by_hand("sink", out)
    ok, why = _judge_alone_sink(out, code, written, expected, before)
    return {"family": "restart-alone", "role": "sink", "at": at, "killed": killed, "launch_exit": launch_code,
            "frames_before": len(written), "exit": code, "seconds": round(secs, 1), "ok": ok, "why": why}


def _alone_after_complete(out: Path, what: str) -> dict:
    names = ["tracks.mcap", "sink.json"]
    before = _digests(out, names)
    code, _, secs = _by_hand("sink", out)
    ok = code == 0 and _digests(out, names) == before
    return {"family": "restart-alone", "role": "sink", "at": "complete", "exit": code, "seconds": round(secs, 1),
            "ok": ok, "why": f"{what}: exit {code}, files {'unchanged' if ok else 'CHANGED'}"}


def _alone_tracker(out: Path) -> dict:
    names = ["tracker.snap", "tracker.journal"]
    before = _digests(out, names)
    code, _, secs = _by_hand("tracker", out)
    ok = code == 3 and _digests(out, names) == before
    return {"family": "restart-alone", "role": "tracker", "at": "after the sink's kill", "exit": code,
            "seconds": round(secs, 1), "ok": ok, "why": f"exit {code}, snapshot and journal "
                                                         f"{'unchanged' if _digests(out, names) == before else 'CHANGED'}"}


def family_restart_alone(work: Path, points: int, seed: int) -> list[dict]:
    rng = random.Random(seed)
    log = make_log(work / "vo100a.mcap", 100)
    expected = offline_tracks(log, work / "off100a.mcap")
    cases = []
    for i in range(points):
        cases.append(_alone_sink_case(work, i, log, expected, rng.randrange(5, 95)))
        print(json.dumps(cases[-1]), flush=True)
    out = work / "alone-t"
    _sink_killed(log, out, 50)
    cases.append(_alone_tracker(out))
    print(json.dumps(cases[-1]), flush=True)
    done = work / "alone-done"
    finish(replay(log, done, None, 150), 180)
    cases.append(_alone_after_complete(done, "a complete run"))
    print(json.dumps(cases[-1]), flush=True)
    return cases


FAMILIES = ("kill", "stop", "forged", "malformed", "mcap", "full", "taken", "restart-alone", "stolen-key",
            "exit-truth", "router", "open", "viewer", "hostile")


def print_table(cases: list[dict]) -> dict:
    """The table of docs/pipeline.md: case, runs, identical (exit 0, output equal to offline),
    lost (runs that lost something or hung), exit codes."""
    from collections import Counter

    table: dict[str, dict] = {}
    for c in cases:
        key = c["family"] + (f"/{c['role']}/{c['run']}" if c["family"] == "kill" else
                             f"/{c['role']}" if c["family"] in ("restart-alone", "stolen-key", "exit-truth") else
                             f"/{c['kind']}" if "kind" in c else "")
        if c["ok"] is None:
            continue
        t = table.setdefault(key, {"runs": 0, "identical": 0, "lost": 0, "exits": Counter()})
        t["runs"] += 1
        t["identical"] += bool(c.get("identical", c["ok"] and c.get("exit") == 0))
        t["lost"] += not c["ok"]
        t["exits"][str(c.get("exit"))] += 1
    print("\n| Case | Runs | Identical | Lost | Exit codes |\n|---|---|---|---|---|")
    for k, t in table.items():
        exits = ", ".join(f"{code} x{n}" for code, n in sorted(t["exits"].items()))
        print(f"| {k} | {t['runs']} | {t['identical']} | {t['lost']} | {exits} |")
        t["exits"] = dict(t["exits"])
    return table


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", choices=FAMILIES, default=list(FAMILIES))
    ap.add_argument("--points", type=int, default=10, help="seeded kill points per stage (short runs)")
    ap.add_argument("--long", type=int, default=0, help="kills per stage in 2,000-frame runs at 50 frames/s")
    ap.add_argument("--malformed", type=int, default=10_000)
    ap.add_argument("--runs", type=int, default=3, help="stolen-key: runs of each of its two cases")
    ap.add_argument("--router", type=int, default=10, help="router kill-and-restart runs")
    ap.add_argument("--open", type=int, default=3, help="open-mode runs per kind")
    ap.add_argument("--viewer", type=int, default=3, help="frozen-viewer runs")
    ap.add_argument("--seed", type=int, default=17)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    cases: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bnptrack-faults-") as tmp:
        work = Path(tmp)
        for fam in args.only:
            if fam == "kill":
                cases += family_kill(work, args.points, args.long, args.seed)
            elif fam == "stop":
                cases += family_stop(work)
            elif fam == "forged":
                cases += family_forged(work)
            elif fam == "malformed":
                cases += family_malformed(work, args.malformed, args.seed)
            elif fam == "mcap":
                cases += family_mcap(work, args.seed)
            elif fam == "full":
                cases += family_full(work)
            elif fam == "taken":
                cases += family_taken(work)
            elif fam == "restart-alone":
                cases += family_restart_alone(work, args.points, args.seed)
            elif fam in ("stolen-key", "exit-truth"):  # benchmarks/faults_eos.py
                from faults_eos import family_exit_truth, family_stolen_key

                cases += family_stolen_key(work, args.runs) if fam == "stolen-key" else family_exit_truth(work)
            elif fam == "router":
                cases += fault_cases.family_router(work, args.router, args.seed, sys.modules[__name__])
            elif fam == "open":
                cases += fault_cases.family_open(work, args.open)
            elif fam == "viewer":
                cases += fault_cases.family_viewer(work, args.viewer, sys.modules[__name__])
            elif fam == "hostile":
                cases += fault_cases.family_hostile(work, sys.modules[__name__])
    table = print_table(cases)
    if args.json:
        args.json.write_text(json.dumps({"cases": cases, "table": table}, indent=1))
    return 0 if all(c["ok"] is not False for c in cases) else 1


if __name__ == "__main__":
    raise SystemExit(main())
