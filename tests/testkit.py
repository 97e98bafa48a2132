"""Shared test helpers (importable as ``testkit``: tests/ is on ``sys.path`` through its conftest).

* :data:`REPO_ROOT` -- the repository root, for tests that run commands or read docs/recordings;
* :func:`wait_until` -- wait on an observable condition (never a fixed sleep);
* :class:`ListSource` / :class:`ListSink` -- stage-level fakes over :mod:`pipeline.membus`:
  feed a list of samples to a stage, collect what a stage publishes;
* the in-memory pipeline helpers of the stage tests (:func:`mem_cfg`,
  :func:`run_memory_pipeline`, :func:`offline`, :func:`strip`, :func:`drop_seq`).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

#: the repository root (tests/ is one level below it)
REPO_ROOT = Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------- waiting


def wait_until(predicate: Callable[[], T], timeout: float, what: str, *, interval: float = 0.02,
               abort: Callable[[], bool] | None = None) -> T:
    """Poll ``predicate`` until it returns a truthy value and return that value.

    Fails (``AssertionError``) with ``what`` once ``timeout`` seconds have passed, or at once
    when ``abort()`` is true (e.g. the process being waited on has exited).  ``interval`` is
    the polling period, not a wait for anything."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if abort is not None and abort():
            raise AssertionError(f"gave up waiting for {what}: the awaited party ended first")
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(interval)


# --------------------------------------------------------------------------- stage fakes


class ListSink:
    """Collects what stages publish.

    Two uses: as the bus of a component that only publishes (``publish(topic, payload,
    meta)``, e.g. an :class:`pipeline.stages.Intake`), and as a reader of what went on the
    wire of a :class:`pipeline.membus.MemoryNetwork` for one run (after any ``tap``)."""

    def __init__(self, net: Any = None, run: str | None = None) -> None:
        self.net = net
        self.run = run
        self.published: list[tuple[str, bytes, dict | None]] = []

    def publish(self, topic: str, payload: bytes, meta: dict | None = None) -> None:
        self.published.append((topic, payload, meta))

    def samples(self, topic: str) -> list[tuple[bytes, bytes | None]]:
        """(payload, attachment) of every sample on ``topic``, in publishing order."""
        if self.net is None:
            return [(p, None if m is None else json.dumps(m).encode()) for t, p, m in self.published if t == topic]
        with self.net.lock:
            return [(p, a) for r, t, p, a in self.net.history if t == topic and (self.run is None or r == self.run)]

    def payloads(self, topic: str) -> list[bytes]:
        return [p for p, _ in self.samples(topic)]

    def docs(self, topic: str, decode: Callable[[bytes], Any] = json.loads) -> list[Any]:
        """The decoded payloads on ``topic`` (JSON by default)."""
        return [decode(p) for p in self.payloads(topic)]


class ListSource:
    """Feeds a fixed list of samples to the stages of one run over a MemoryNetwork, as the
    stage ``name`` (by default the source): ``(topic, payload, meta)`` in order."""

    def __init__(self, net: Any, run: str, samples: Iterable[tuple[str, bytes, dict | None]],
                 name: str = "source") -> None:
        self.net = net
        self.run = run
        self.samples = list(samples)
        self.name = name

    @classmethod
    def of_frames(cls, net: Any, run: str, frames: Iterable[Any], metadata: dict[str, str] | None = None,
                  t0_ns: int = 0) -> "ListSource":
        """What the source stage publishes for ``frames``: ``info/source`` (with ``metadata``),
        /measurements and /truth with the ``seq``/``t``/``frame`` attachment, ``eos/source``."""
        import msgspec

        from bnptrack.pipeline.stages.health import EndOfStream, StageInfo
        from bnptrack.tracker.messages import encode, from_truth

        enc = msgspec.json.encode
        samples: list[tuple[str, bytes, dict | None]] = [
            ("info/source", enc(StageInfo(stage="source", run=run, kind="list", metadata=metadata)), None)]
        seq = -1
        for seq, f in enumerate(frames):
            has_truth = f.truth is not None
            samples.append(("measurements", encode(f, run),
                            {"seq": seq, "t": t0_ns + seq, "frame": f.frame, "truth": has_truth}))
            if has_truth:
                samples.append(("truth", encode(from_truth(f.frame, f.stamp_ns, f.truth, run)),
                                {"seq": seq, "t": t0_ns + seq, "frame": f.frame}))
        samples.append(("eos/source", enc(EndOfStream(stage="source", run=run, last_seq=seq, frames=seq + 1)),
                        None))
        return cls(net, run, samples)

    def publish(self) -> None:
        """Publish every sample on a bus of its own, then close it."""
        bus = self.net.bus(self.run, self.name)
        try:
            for topic, payload, meta in self.samples:
                bus.publish(topic, payload, meta)
        finally:
            bus.close()


def drop_seq(seqs: Iterable[int], topics: Iterable[str] = ("measurements", "truth")):
    """A MemoryNetwork tap that loses the samples of ``seqs`` on ``topics`` for good."""
    lost, on = set(seqs), set(topics)

    def tap(run, topic, payload, att):
        if topic in on and att and json.loads(att)["seq"] in lost:
            return []
        return [(payload, att)]

    return tap


def forge_seq(seq: int, frame: int):
    """A tap that rewrites the frame number of the measurements of ``seq``."""

    def tap(run, topic, payload, att):
        if topic == "measurements" and att and json.loads(att)["seq"] == seq:
            doc = json.loads(payload)
            doc["frame"] = frame
            meta = json.loads(att)
            meta["frame"] = frame
            return [(json.dumps(doc).encode(), json.dumps(meta).encode())]
        return [(payload, att)]

    return tap


# --------------------------------------------------------------------------- in-memory pipeline


def mem_cfg(tmp_path: Path, frames: int = 12, **extra: str):
    """A small pipeline (the single-level ``ddp-mb``, sweeps 8, burn-in 2, no Rerun) writing to
    ``tmp_path/out``."""
    from bnptrack.pipeline.config import PipelineConfig, resolve_run
    from bnptrack.tracker.config import apply_overrides

    overrides = [f"source.frames={frames}", "tracker.tracker=ddp-mb", "tracker.overrides=['sweeps=8', 'burn_in=2']",
                 "sink.rerun=false", "tracker.snapshot_every=4", "delivery.eos_grace_s=0.3",
                 "supervisor.linger_s=0.5"]
    overrides += [f"{k}={v}" for k, v in extra.items()]
    cfg = apply_overrides(PipelineConfig(run="mem", out=str(tmp_path / "out")), overrides)
    return resolve_run(cfg)


def run_memory_pipeline(cfg, net, roles=("sink", "tracker", "source"), timeout=120.0,
                        clock=None) -> dict[str, int]:
    """Run ``roles`` on ``net`` in threads, all on one :class:`ManualClock` (see
    :func:`_drive_clock`): their grace periods do not depend on the machine's speed."""
    from bnptrack.pipeline.stages import STAGES, ManualClock, StageContext

    codes: dict[str, int] = {}
    errors: list[BaseException] = []
    clock = clock or ManualClock()

    def go(role: str) -> None:
        bus = net.bus(cfg.run, role)
        try:
            codes[role] = STAGES[role](StageContext(cfg, bus, name=role, clock=clock)).run()
        except BaseException as exc:  # pragma: no cover - surfaced below
            errors.append(exc)
        finally:
            bus.close()

    threads = [threading.Thread(target=go, args=(r,), daemon=True) for r in roles]
    for t in threads:
        t.start()
    _drive_clock(net, cfg.run, clock, threads, timeout)
    for t in threads:
        t.join(timeout)
    assert not errors, errors
    assert not any(t.is_alive() for t in threads), "a stage did not finish"
    return codes


def _source_ended(net, run: str) -> bool:
    with net.lock:
        return any(r == run and t == "eos/source" for r, t, _, _ in net.history)


def _drive_clock(net, run: str, clock, threads: list[threading.Thread], timeout: float) -> None:
    """The stages' time stands still until the source has published its end of stream;
    from then on it moves one second per poll, so that end-of-stream grace periods and
    lingering expire (a frame still missing then is a gap by the sequencer's rules, not
    because the machine was slow: every stage checks its backlog first)."""
    deadline = time.monotonic() + timeout
    while any(t.is_alive() for t in threads) and time.monotonic() < deadline:
        if _source_ended(net, run):
            clock.advance(1.0)
        threads[0].join(0.02)


def offline(cfg, drop: frozenset[int] = frozenset()):
    """The offline result for the pipeline's synthetic frames (minus the dropped seqs)."""
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.pipeline.stages import source_frames
    from bnptrack.tracker.state import run

    meta, frames = source_frames(cfg)
    frames = [f for i, f in enumerate(frames) if i not in drop]
    tracker = tracker_setup(cfg.tracker.tracker, overrides=cfg.tracker.overrides, metadata=meta).tracker
    return frames, [est for _, est, _ in run(tracker, frames, cfg.tracker.seed)]


def strip(est):
    """An Estimate as comparable data, without the timing diagnostics."""
    d = {k: v for k, v in est.diagnostics.items() if k != "ms"}
    return (est.frame, est.labels, est.assignments, est.assignment_prob, d,
            [(t.state.tolist(), t.covariance.tolist(), t.existence) for t in est.tracks])


def log_tracks(path):
    """The /tracks of the MCAP log at ``path`` as comparable data (frame, labels, assignments,
    diagnostics without the timing, states and existences)."""
    from bnptrack import read_log

    def row(e):
        d = {k: v for k, v in e.diagnostics.items() if k != "ms"}
        return (e.frame, e.labels, e.assignments, d, [(t.state.tolist(), t.existence) for t in e.tracks])

    return [row(e) for e in read_log(path).tracks]


def offline_log_tracks(log, out):
    """Track the log at ``log`` offline with ``ddp`` (seed 0) into ``out``: its :func:`log_tracks`."""
    from bnptrack.pipeline.offline import track_log
    from bnptrack.pipeline.resolve import tracker_setup
    from bnptrack.sources.mcap_log import read_metadata

    meta = read_metadata(log)
    track_log(log, out, tracker_setup("ddp", metadata=meta).tracker, 0, meta)
    return log_tracks(out)


# --------------------------------------------------------------------------- logs


def rename_channels(src: Path, dst: Path, renames: dict[str, str], n: int | None = None) -> Path:
    """Copy the MCAP log ``src`` to ``dst`` with its channels renamed (``{"/measurements":
    "/radar/detections"}``): the same records (schemas, metadata, messages, the first ``n``
    ``/measurements`` frames and what comes with them), as a foreign sensor's log that
    ``--topic /radar/detections=/measurements`` maps back."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as fin, open(dst, "wb") as fout:
        reader, w = make_reader(fin), Writer(fout)
        w.start()
        for rec in reader.iter_metadata():
            w.add_metadata(rec.name, dict(rec.metadata))
        ids: dict[int, int] = {}
        schemas: dict[int, int] = {}
        seen = 0
        for schema, ch, msg in reader.iter_messages(log_time_order=False):
            if ch.topic == "/measurements":
                seen += 1
                if n is not None and seen > n:
                    break
            if ch.id not in ids:
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
                ids[ch.id] = w.register_channel(renames.get(ch.topic, ch.topic), ch.message_encoding,
                                                schemas.get(schema.id, 0) if schema is not None else 0)
            w.add_message(ids[ch.id], log_time=msg.log_time, publish_time=msg.publish_time, data=msg.data)
        w.finish()
    return dst


def png_stats(png: "str | Path | bytes") -> dict[str, float]:
    """Width, height, luminance variance and number of distinct luminance values of a PNG
    (Pillow, a dependency of rerun-sdk): enough to tell a rendered screenshot from a blank one."""
    import io

    import numpy as np
    from PIL import Image

    src = io.BytesIO(png) if isinstance(png, bytes) else Path(png)
    with Image.open(src) as img:
        lum = np.asarray(img.convert("L"), dtype=np.float64)
    return {"width": float(lum.shape[1]), "height": float(lum.shape[0]),
            "variance": float(lum.var()), "distinct": float(np.unique(lum).size)}


#: Where Vulkan loaders look for installable client drivers (a GPU's, or Mesa's software one).
VULKAN_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")
RENDERER_INSTALL = "apt-get install -y mesa-vulkan-drivers"
#: ``"1"`` when ``CI`` was set as the test run started (conftest.py notes it before the Rerun
#: test modules set ``CI`` themselves to keep rerun's analytics off).
UNDER_CI_ENV = "BNPTRACK_TESTS_UNDER_CI"


def vulkan_drivers() -> list[str]:
    """The Vulkan driver manifests of this machine (``VK_ICD_FILENAMES`` / ``VK_DRIVER_FILES``,
    else the ``*.json`` files of :data:`VULKAN_ICD_DIRS`)."""
    import glob
    import os

    listed = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if listed:
        return [f for f in listed.split(os.pathsep) if os.path.isfile(f)]
    return sorted(f for d in VULKAN_ICD_DIRS for f in glob.glob(os.path.join(d, "*.json")))


def require_renderer() -> None:
    """For a test that renders with the Rerun viewer: without any Vulkan driver it is skipped,
    naming the driver and its install command, except under CI (``CI`` set when the test run
    started, as .ci/run does, which installs the driver; :data:`UNDER_CI_ENV`), where it fails."""
    import os

    import pytest

    if vulkan_drivers():
        return
    why = ("no Vulkan driver on this machine (the Rerun viewer renders with one; without a GPU: "
           f"Mesa's software driver, `{RENDERER_INSTALL}`)")
    if os.environ.get(UNDER_CI_ENV) == "1":
        pytest.fail(f"{why}; CI must have it")
    pytest.skip(why)


def bnptrack_env(extra: "dict[str, str] | None" = None) -> dict[str, str]:
    """The environment of a ``python -m bnptrack`` subprocess: this checkout first on
    ``PYTHONPATH``, Rerun's analytics off, plus ``extra``."""
    import os

    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO_ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["RERUN_ANALYTICS"] = "0"
    return {**env, **(extra or {})}


def popen_bnptrack(*args: str, log: "Path | None" = None, env: "dict[str, str] | None" = None):
    """Start ``bnptrack ARGS`` (``python -m bnptrack``) in its own process group; output to
    ``log`` (appended, stderr merged) or to two pipes (stdout, stderr: progress lines go to
    stderr) that :func:`finish` reads."""
    import subprocess
    import sys

    out = open(log, "ab") if log is not None else subprocess.PIPE
    return subprocess.Popen([sys.executable, "-m", "bnptrack", *args], cwd=REPO_ROOT, env=bnptrack_env(env),
                            stdout=out, stderr=subprocess.STDOUT if log is not None else subprocess.PIPE,
                            start_new_session=True)


def finish(p, timeout: float) -> tuple[int, str]:
    """Wait for ``p`` (:func:`popen_bnptrack`); its exit code and output.  Past ``timeout``
    its process group is killed and the test fails with the output so far."""
    import os
    import signal
    import subprocess

    import pytest

    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate(timeout=10)
        pytest.fail(f"{p.args} did not finish in {timeout} s:\n{(out or b'').decode()}\n{(err or b'').decode()}")
    return p.returncode, (out or b"").decode() + (err or b"").decode()


# --------------------------------------------------------------------------- recordings


def read_rrd(path: Path) -> dict[str, list]:
    """Entity path -> Arrow record batches of its chunks (the file's first recording)."""
    from collections import defaultdict

    from rerun.chunk import RrdReader

    out: dict[str, list] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        out[chunk.entity_path].append(chunk.to_record_batch())
    return out


def by_frame(batches: list, column: str) -> dict[int, object]:
    """``frame`` -> value of ``column`` over the temporal rows of an entity."""
    out: dict[int, object] = {}
    for rb in batches:
        names = rb.schema.names
        if "frame" not in names or column not in names:
            continue
        for f, v in zip(rb.column("frame").to_pylist(), rb.column(column).to_pylist()):
            if v is not None:
                out[f] = v
    return out


def rrd_verify(path: Path):
    """``rerun rrd verify PATH`` (exit code 0: the file is complete and readable)."""
    import subprocess

    from bnptrack.sinks.rerun_tools import rerun_cli, rerun_env

    return subprocess.run([*rerun_cli(), "rrd", "verify", str(path)], capture_output=True,
                          text=True, timeout=60, env=rerun_env(), check=False)
