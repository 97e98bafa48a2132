"""Logs of a sensor of one's own, away from the origin, with the parameter files to track them:
the vo2017 scene (seed 1) moved rigidly to lie around the sensor (``sources.synthetic.move_truth``)
and measured by it.

* ``radar_at_pose.mcap`` + ``radar.toml``: a bearing-range radar at (1500, -700) heading 40 deg;
  the pose is in the parameter file's ``[sensors.s]`` table, the frames carry none;
* ``lidar_at_pose.mcap`` + ``lidar.toml``: an ``xy`` lidar at (3000, 1000) heading -30 deg; each
  frame carries its own ``pose``, the parameter file declares no sensor.

Births anywhere (``birth = []``, ``birth_rate = 0.1``): the scene's birth regions are not moved.
docs/rerun.md draws them ("Sensors at their poses")::

    python benchmarks/posed_sensor_logs.py --out /tmp/posed --frames 60
    bnptrack track /tmp/posed/radar_at_pose.mcap --params /tmp/posed/radar.toml --rrd /tmp/posed/r.rrd
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import measure_with, measurement_frame_rng, move_truth
from bnptrack.tracker.config import apply_overrides
from bnptrack.tracker.models.params import ModelParams, load_params
from bnptrack.tracker.types import Frame

RADAR = (1500.0, -700.0, float(np.deg2rad(40.0)))
LIDAR = (3000.0, 1000.0, float(np.deg2rad(-30.0)))
ANYWHERE = ("birth=[]", "birth_rate=0.1")


def sensor_table(kind: str, pose: tuple[float, float, float], name: str = "s") -> list[str]:
    """``--set``-style keys of a ``[sensors.NAME]`` table of ``kind`` at ``pose``."""
    return [f"sensors.{name}.kind='{kind}'", f"sensors.{name}.x={pose[0]}", f"sensors.{name}.y={pose[1]}",
            f"sensors.{name}.heading_deg={np.rad2deg(pose[2])}"]


def posed_log(kind: str, pose: tuple[float, float, float], *, pose_in_frames: bool,
              n_frames: int = 30) -> tuple[list[Frame], ModelParams]:
    """vo2017 seed 1 moved to lie around a sensor ``s`` at ``pose`` and measured by it: the
    frames and the parameters to track them with.  With ``pose_in_frames`` each frame carries
    the pose (the parameters declare no sensor), else the parameters' ``[sensors.s]`` table
    holds it (the frames carry none)."""
    sc = get_scenario("vo2017")
    table = sensor_table(kind, pose)
    measured = sc.adapt_params(apply_overrides(load_params("vo2017"), table))
    frames = []
    for k, tr in enumerate(sc.truth(1.0)[:n_frames], start=1):
        moved = move_truth(tr, pose)
        z, kd, ps = measure_with(measurement_frame_rng(1, k), moved, measured, kind, "s")
        frames.append(Frame(k, k * 10**9, "s", kd, z, moved, pose=ps if pose_in_frames else None))
    base = sc.adapt_params(load_params("vo2017"))
    return frames, apply_overrides(base, [*ANYWHERE] if pose_in_frames else [*table, *ANYWHERE])


def params_toml(kind: str, pose: tuple[float, float, float] | None) -> str:
    """The parameter file of a log: births anywhere and, with ``pose``, the ``[sensors.s]`` table."""
    text = 'extends = "vo2017"\nbirth = []\nbirth_rate = 0.1\n'
    if pose is not None:
        text += (f'\n[sensors.s]\nkind = "{kind}"\nx = {pose[0]}\ny = {pose[1]}\n'
                 f"heading_deg = {np.rad2deg(pose[2]):g}\n")
    return text


def main() -> None:
    from bnptrack import write_log

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("recordings/posed"))
    ap.add_argument("--frames", type=int, default=60)
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    for name, kind, pose, in_frames in (("radar", "bearing_range", RADAR, False), ("lidar", "xy", LIDAR, True)):
        frames, _params = posed_log(kind, pose, pose_in_frames=in_frames, n_frames=a.frames)
        write_log(a.out / f"{name}_at_pose.mcap", frames, overwrite=True)
        (a.out / f"{name}.toml").write_text(params_toml(kind, None if in_frames else pose))
        print(f"wrote {a.out / f'{name}_at_pose.mcap'} and {a.out / f'{name}.toml'}")


if __name__ == "__main__":
    main()
