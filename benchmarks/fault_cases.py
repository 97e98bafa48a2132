"""More fault families of ``benchmarks/faults.py``: a router killed and restarted, open-mode
samples, a frozen live viewer.

* ``router``: an external ``bnptrack router`` SIGKILLed at a seeded moment of a 300-frame
  replay at 25 frames/s and restarted on the same port after a seeded 0.5-3 s: the output must
  equal offline ``track`` (exit 0), or the run exits 3 only for frames no publisher held;
* ``open``: in this process, on the in-memory bus whose publishers answer the explicit
  history (the stages' code, no Zenoh): with ``zenoh.auth = false`` anybody may put, so one
  well-formed ``/measurements`` sample 99,999 sequence numbers ahead, and copies of genuine
  frames under later sequence numbers: no genuine frame may be lost;
* ``viewer``: a replay streaming to a viewer (``rerun --serve-grpc``) that is SIGSTOPped
  mid-run: files complete, the run ends within 10 s after the end of stream.
"""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _router(port: int, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "bnptrack", "router", "--listen", f"tcp/127.0.0.1:{port}"],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def family_router(work: Path, runs: int, seed: int, h) -> list[dict]:
    """``h``: the faults module (make_log, offline_tracks, replay, finish, judge, ...)."""
    rng = random.Random(seed)
    log = h.make_log(work / "vo300r.mcap", 300)
    expected = h.offline_tracks(log, work / "off300r.mcap")
    cases = []
    for i in range(runs):
        at, down = rng.randrange(10, 290), round(rng.uniform(0.5, 3.0), 2)
        port = _free_port()
        router = _router(port, h._env())
        deadline = time.monotonic() + 30
        while not _listening(port) and time.monotonic() < deadline:
            time.sleep(0.05)
        out = work / f"router{i}"
        p = h.replay(log, out, 25, 300, "--set", "zenoh.embedded_router=false",
                     "--set", f"zenoh.connect=['tcp/127.0.0.1:{port}']")
        reached = h.wait_until(lambda: h.snapshot_seq(out) >= at, p, 200)
        restarted = False
        if reached:
            os.killpg(router.pid, signal.SIGKILL)
            router.wait()
            time.sleep(down)  # the router stays away this long (the fault itself, not a wait)
            router = _router(port, h._env())
            restarted = True
        code, text = h.finish(p, 360)
        os.killpg(router.pid, signal.SIGKILL)
        router.wait()
        ok, why = h.judge(code, text, out, expected)
        if code == 3:  # every frame is in the source's cache (10,000 > 300): nothing may be lost
            ok, why = False, "exit 3 although the source held every frame: " + why
        cases.append({"family": "router", "at": at, "down_s": down, "restarted": restarted, "exit": code,
                      "ok": ok, "identical": code == 0 and ok, "why": why})
        print(json.dumps(cases[-1]), flush=True)
    return cases


def _open_case(tmp: Path, kind: str, n: int) -> dict:
    from bnptrack.pipeline.stages.summary import load_summary
    from bnptrack.pipeline.config import PipelineConfig, resolve_run
    from bnptrack.pipeline.membus import MemoryNetwork
    from bnptrack.tracker.config import apply_overrides

    sys.path.insert(0, str(ROOT / "tests"))
    from testkit import offline, run_memory_pipeline, strip

    cfg = resolve_run(apply_overrides(PipelineConfig(run="open", out=str(tmp / kind)), [
        f"source.frames={n}", "tracker.tracker=ddp-mb", "tracker.overrides=['sweeps=8', 'burn_in=2']",
        "sink.rerun=false", "delivery.eos_grace_s=0.3", "supervisor.linger_s=0.5", "zenoh.auth=false"]))
    net = MemoryNetwork()
    net.fetchable = True
    rng = random.Random(n)

    def tap(run, topic, payload, att):
        out = [(payload, att)]
        meta = json.loads(att) if att else {}
        if topic == "measurements" and isinstance(meta.get("seq"), int):
            s = meta["seq"]
            if kind == "far-ahead" and s % 10 == 3:
                out.append((payload, json.dumps({**meta, "seq": s + 99_999}).encode()))
            if kind == "duplicate-frame" and s % 7 == 2 and s + 5 < n:
                out.insert(rng.randrange(2), (payload, json.dumps({**meta, "seq": s + rng.randrange(1, 6)}).encode()))
        return out

    net.tap = tap
    codes = run_memory_pipeline(cfg, net)
    from bnptrack.sources.mcap_log import read_log

    rec = read_log(Path(cfg.out) / "tracks.mcap")
    _, ests = offline(cfg)
    summary = load_summary(Path(cfg.out) / "sink.json")
    same = [strip(e) for e in rec.tracks] == [strip(e) for e in ests]
    lost = n - len(rec.tracks)
    ok = same and codes.get("sink") == 0 and summary.output_complete
    return {"family": "open", "kind": kind, "frames": n, "exit": codes.get("sink"), "lost": lost, "ok": ok,
            "identical": same, "why": "identical" if same else f"{lost} frame(s) lost or differing"}


def family_open(work: Path, runs: int) -> list[dict]:
    cases = []
    for kind in ("far-ahead", "duplicate-frame"):
        for i in range(runs):
            with tempfile.TemporaryDirectory(dir=work) as tmp:
                cases.append(_open_case(Path(tmp), kind, 40 + 10 * i))
            print(json.dumps(cases[-1]), flush=True)
    return cases


def family_viewer(work: Path, runs: int, h) -> list[dict]:
    sys.path[:0] = [str(ROOT / "tests" / "integration"), str(ROOT / "tests")]
    from test_live_view import Receiver

    log = h.make_log(work / "vo100v.mcap", 100)
    expected = h.offline_tracks(log, work / "off100v.mcap")
    cases = []
    for i in range(runs):
        rec = Receiver(work / f"viewer{i}.rrd")
        out = work / f"viewer{i}"
        p = subprocess.Popen(
            [sys.executable, "-m", "bnptrack", "replay", str(log), "--rate", "25", "--connect", rec.url,
             "--out", str(out), "--timeout", "200"],
            cwd=ROOT, env=h._env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        if h.wait_until(lambda: h.snapshot_seq(out) >= 20, p, 150):
            os.kill(rec.proc.pid, signal.SIGSTOP)
        h.wait_until(lambda: h.snapshot_seq(out) >= 99, p, 200)
        t_end = time.monotonic()
        code, text = h.finish(p, 220)
        after = time.monotonic() - t_end
        os.kill(rec.proc.pid, signal.SIGCONT)
        rec.stop()
        files = all((out / f).is_file() for f in ("tracks.mcap", "run.rrd", "sink.json"))
        ok, why = h.judge(code, text, out, expected)
        ok = ok and files and after <= 10.0
        cases.append({"family": "viewer", "exit": code, "files": files, "s_after_eos": round(after, 1),
                      "ok": ok, "identical": code == 0 and ok, "why": why})
        print(json.dumps(cases[-1]), flush=True)
    return cases


def _hostile_log(path: Path, kind: str, h) -> Path:
    """100 frames of vo2017 with one hostile feature: ``stamp-back`` (frame 42's stamp goes
    back once), ``long-gap`` (from frame 51 on, 2,000 frames and 2 h later), ``jump`` (frame
    60 numbered 10**9), ``repeat`` (frame 30's number repeated by the next frame), ``cut`` (the
    file cut in the middle)."""
    import dataclasses

    from bnptrack.sinks.mcap_writer import McapLogWriter
    from bnptrack.sources.mcap_log import iter_frames, read_metadata

    base = list(iter_frames(h.VO2017))
    with McapLogWriter(path, read_metadata(h.VO2017)) as w:
        for i, f in enumerate(base):
            if kind == "stamp-back" and i == 41:
                f = dataclasses.replace(f, stamp_ns=base[10].stamp_ns)
            elif kind == "long-gap" and i >= 50:
                f = dataclasses.replace(f, frame=f.frame + 2000, stamp_ns=f.stamp_ns + 7200 * 10**9)
            elif kind == "jump" and i == 59:
                f = dataclasses.replace(f, frame=10**9)
            elif kind == "repeat" and i == 30:
                f = dataclasses.replace(f, frame=base[29].frame)
            w.write_frame(f)
    if kind == "cut":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    return path


def family_hostile(work: Path, h) -> list[dict]:
    """Each hostile log through ``bnptrack track`` and ``bnptrack replay``: the same exit code
    and the same frames and tracks."""
    cases = []
    for kind in ("stamp-back", "long-gap", "jump", "repeat", "cut"):
        log = _hostile_log(work / f"hostile-{kind}.mcap", kind, h)
        off = work / f"hostile-{kind}-track.mcap"
        res = subprocess.run([sys.executable, "-m", "bnptrack", "track", str(log), "--out", str(off), "-q",
                              "--overwrite"], cwd=ROOT, env=h._env(), capture_output=True, text=True, timeout=600)
        out = work / f"hostile-{kind}-replay"
        code, text = h.finish(h.replay(log, out, None, 300), 360)
        try:
            same = h.tracks_of(out / "tracks.mcap") == h.tracks_of(off)
        except Exception as exc:  # noqa: BLE001 - reported as a difference
            same, text = False, f"{text}\n{exc}"
        ok = code == res.returncode and same
        cases.append({"family": "hostile", "kind": kind, "exit": f"track {res.returncode} / replay {code}",
                      "identical": ok, "ok": ok,
                      "why": "same exit and tracks" if ok else f"track {res.returncode}, replay {code}, same tracks {same}"})
        print(json.dumps(cases[-1]), flush=True)
    return cases
