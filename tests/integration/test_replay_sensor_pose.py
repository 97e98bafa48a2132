"""`bnptrack replay LOG --params FILE` records the sensor where the parameter file puts it: the
pipeline's sink stage resolves each frame's sensor as the tracker does (Zenoh on loopback)."""

from __future__ import annotations

import numpy as np

from benchmarks.posed_sensor_logs import RADAR, params_toml, posed_log
from bnptrack import write_log
from testkit import finish, popen_bnptrack


def test_replay_draws_the_params_sensor_pose(tmp_path):
    from rerun.chunk import RrdReader

    frames, _params = posed_log("bearing_range", RADAR, pose_in_frames=False, n_frames=20)
    log, toml, out = tmp_path / "radar.mcap", tmp_path / "radar.toml", tmp_path / "run"
    write_log(log, frames)
    toml.write_text(params_toml("bearing_range", RADAR))
    code, text = finish(popen_bnptrack("replay", str(log), "--params", str(toml), "--as-fast-as-possible",
                                       "--out", str(out), "--timeout", "150"), 180)
    assert code == 0, text
    sensors, lines = {}, []
    for chunk in RrdReader(out / "run.rrd").stream():
        rb = chunk.to_record_batch()
        if chunk.entity_path.startswith("/world/sensors/") and "Points2D:positions" in rb.schema.names:
            sensors[chunk.entity_path] = rb.column("Points2D:positions").to_pylist()[0][0]
        if chunk.entity_path == "/world/assignments" and "LineStrips2D:strips" in rb.schema.names:
            lines += [np.asarray(s, dtype=float) for row in rb.column("LineStrips2D:strips").to_pylist()
                      for s in (row or [])]
    assert list(sensors) == ["/world/sensors/s"]
    np.testing.assert_allclose(sensors["/world/sensors/s"], RADAR[:2], atol=1e-2)
    lengths = np.array([np.hypot(*(s[0] - s[1])) for s in lines])
    assert lengths.size > 20 and np.median(lengths) < 50.0 and lengths.max() < 300.0
