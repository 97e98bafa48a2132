"""What the launcher sets up before its stages start and takes down after: the output
directory freed of an earlier run's files, the network (the embedded router or the routers to
connect to), a viewer for ``--view``, and the stages' environment.

:class:`LaunchSetup` is a base class of :class:`~pipeline.launch.Launcher` and works on its
state: ``cfg``, ``out``, ``router``, ``viewer``, ``overwrite``, ``echo``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import msgspec

from bnptrack.pipeline.config import PipelineConfig, ZenohConfig
from bnptrack.pipeline.preflight import run_files
from bnptrack.pipeline.supervisor import open_embedded_router
from bnptrack.pipeline.stages import JOURNAL_NAME, SNAPSHOT_NAME, SUMMARY_NAME
from bnptrack.tracker.config import ConfigError

__all__ = ["LaunchSetup"]

log = logging.getLogger("bnptrack.launch")


class LaunchSetup:
    """Set a run up and take it down (see the module docstring)."""

    def _stage_env(self) -> dict[str, str]:
        env = dict(os.environ)
        env.setdefault("PYTHONUNBUFFERED", "1")
        env.setdefault("RERUN_ANALYTICS", "0")
        if self.credentials:  # each stage gets its own on its link: no other in its environment
            env.pop("BNPTRACK_ZENOH_USER", None)
            env.pop("BNPTRACK_ZENOH_PASSWORD", None)
        # children run this checkout even if the package is not installed
        root = str(Path(__file__).resolve().parent.parent)
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        return env

    def _spawn_viewer(self, cfg: PipelineConfig) -> PipelineConfig:
        """``view``: start a Rerun viewer (left open after the run) and have the sink stream
        ``run.rrd``'s rows to it (``sink.view_url``)."""
        from bnptrack.pipeline.live import spawn_viewer

        if not cfg.sink.rerun:
            raise ConfigError("--view needs the Rerun sink (sink.rerun = true)")
        self.viewer = spawn_viewer()
        self.echo(f"viewer: {self.viewer.url} (pid {self.viewer.pid}; it stays open after the run)")
        return msgspec.structs.replace(cfg, sink=msgspec.structs.replace(cfg.sink, view_url=self.viewer.url))

    def _remove_earlier_run(self) -> None:
        """Remove the files an earlier run left in ``out`` (only there with ``overwrite``:
        :func:`check_pipeline` refuses them otherwise), so that none is mistaken for this
        run's (a stale snapshot would even be resumed)."""
        for name in {*run_files(self.cfg), SNAPSHOT_NAME, JOURNAL_NAME, SUMMARY_NAME}:
            path = self.out / name
            if path.is_dir():  # logs/
                for f in path.glob("*.log"):
                    f.unlink()
                continue
            try:
                path.unlink()
            except FileNotFoundError:
                pass

    def _network(self, cfg: PipelineConfig) -> PipelineConfig:
        """The stages' pipeline: with ``zenoh.embedded_router``, the router this launcher
        opens (with per-run credentials when the ACL or authentication asks for them)."""
        z = cfg.zenoh
        if z.embedded_router:
            self.router, z, self.credentials = open_embedded_router(_quick_router(z), self.out, self.cfg.stages)
            z = msgspec.structs.replace(z, router_extra=cfg.zenoh.router_extra)
        elif not z.connect and z.mode == "client":
            raise ConfigError("zenoh.connect: a client needs router endpoints (or set "
                              "zenoh.embedded_router = true)")
        return msgspec.structs.replace(cfg, zenoh=z)

    def _close_network(self) -> None:
        self.monitor.close()
        if self.router is not None:
            self.router.close()
            self.router = None


def _quick_router(z: ZenohConfig) -> ZenohConfig:
    """``z`` with ``scouting/delay`` 0 for the embedded router (unless set, or multicast
    scouting is on): Zenoh's 500 ms default held every launch half a second (docs/performance.md)."""
    if "scouting/delay" in z.router_extra or z.multicast_scouting:
        return z
    return msgspec.structs.replace(z, router_extra={**z.router_extra, "scouting/delay": "0"})
