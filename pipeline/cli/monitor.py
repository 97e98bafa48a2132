"""``bnptrack monitor``: watch a run's stages over Zenoh (liveliness, health counters, dead
letters, end of stream) and print one line per event."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from bnptrack.pipeline.cli.option_types import RUN
from bnptrack.pipeline.cli.common import FiniteRange, checked_endpoints, SET_HELP_ZENOH, clean_errors

__all__ = ["monitor", "event_line"]


@click.command()
@click.option("--run", "run_id", type=RUN, required=True, metavar="RUN", help="Run id to watch.")
@click.option("--connect", multiple=True, required=True, metavar="ENDPOINT", help="Router endpoint.",
              callback=checked_endpoints)
@click.option("--pipeline", "pipeline_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None, help="Pipeline file (for its [zenoh] TLS settings).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help=SET_HELP_ZENOH)
@click.option("--duration", type=FiniteRange(min=0, min_open=True), default=None, metavar="SECONDS",
              help="Stop after this long (default: until Ctrl-C).")
@click.option("--connect-timeout", type=FiniteRange(min=0), default=1.0, show_default=True,
              metavar="SECONDS", help="Give up when no router answers within this long.")
@clean_errors
def monitor(run_id: str, connect: tuple[str, ...], pipeline_file: Path | None, overrides: tuple[str, ...],
            duration: float | None, connect_timeout: float) -> None:
    """Watch a run's stages: liveliness, health counters, dead letters, end of stream.

    With no router at --connect: one line `Error: no router at ...` and exit code 2.

    \b
    Example:
      bnptrack monitor --run r1 --connect tcp/127.0.0.1:7447
    """
    import threading as _threading

    import msgspec as _ms

    from bnptrack.pipeline.stage_process import stage_config
    from bnptrack.pipeline.config import load_pipeline
    from bnptrack.pipeline.supervisor import stop_on_signals

    cfg = stage_config(load_pipeline(pipeline_file, overrides), run=run_id, out=None, connect=connect,
                       listen=(), mode=None)
    cfg = _ms.structs.replace(cfg, zenoh=_ms.structs.replace(cfg.zenoh, connect_timeout_s=connect_timeout))
    stop = _threading.Event()
    # taken off the main thread, which waits in the bus's receive (pipeline.supervisor.StopSignals)
    signals = stop_on_signals("monitor", stop)
    try:
        watch(cfg, stop, duration)
    finally:
        signals.restore(handlers=True)


def watch(cfg: Any, stop: Any, duration: float | None) -> None:
    """The monitor loop: print the alive / ready stages when they change and one line per
    health, dead-letter and end-of-stream message, until ``stop`` is set or ``duration``
    seconds have passed."""
    import time as _time

    from bnptrack.pipeline.transport import Bus

    end = _time.monotonic() + duration if duration else None
    with Bus(cfg.run, "monitor", cfg.zenoh, cfg.delivery) as bus:
        bus.subscribe(["health/*", "deadletter"], advanced=False)
        bus.subscribe(["eos/*"])
        shown: tuple = ()
        while not stop.is_set() and (end is None or _time.monotonic() < end):
            now = (bus.alive(), bus.alive("ready"))
            if now != shown:
                click.echo(f"alive: {', '.join(sorted(now[0])) or '(none)'}; "
                           f"ready: {', '.join(sorted(now[1])) or '(none)'}")
                shown = now
            ev = bus.recv(0.2)
            if ev is not None:
                click.echo(event_line(ev.topic, ev.payload))


def event_line(topic: str, payload: bytes) -> str:
    """One line for a health, dead-letter or end-of-stream message."""
    try:
        doc = json.loads(payload)
    except ValueError:
        return f"{topic}: {len(payload)} bytes (not JSON)"
    if topic.startswith("health/"):
        c = doc.get("counters", {})
        lat = c.get("latency_ms") or {}
        lat_text = (f" latency p50 {lat['p50']:.1f} ms p99 {lat['p99']:.1f} ms"
                    if lat.get("p50") is not None else "")
        return (f"{doc.get('stage')}: pid {doc.get('pid')} received {c.get('received')} "
                f"accepted {c.get('accepted')} rejected {c.get('rejected')} dup "
                f"{c.get('duplicates')} gaps {c.get('gaps')} dropped {doc.get('dropped')} "
                f"backlog {doc.get('backlog')}{lat_text}")
    if topic == "deadletter":
        return (f"dead letter from {doc.get('stage')}: {doc.get('topic')} seq {doc.get('seq')}: "
                f"{doc.get('reason')}")
    return (f"{topic}: last seq {doc.get('last_seq')}, {doc.get('frames')} frame(s)"
            + (f", gaps {doc['gaps']}" if doc.get("gaps") else "")
            + (f", error: {doc['error']}" if doc.get("error") else ""))
