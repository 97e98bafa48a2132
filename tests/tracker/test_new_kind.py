"""Extensibility: a measurement kind is its model class plus its registry
entry.  The kind ``range_bearing_deg`` (``z = [range_m, bearing_deg]``: the bearing-range
radar with its columns swapped and the bearing in degrees) exists only in this file; it is
simulated, encoded and decoded, tracked by ddp and glmb, warmed up and drawn by the Rerun sink
without editing any other module.  Also: a parameter file's sensor kind is checked at load."""

from __future__ import annotations

import os

os.environ.setdefault("CI", "1")  # before `import rerun` (via the sink): no analytics

import dataclasses  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from functools import cached_property  # noqa: E402
from typing import ClassVar  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bnptrack.tracker.models import measurement as mm  # noqa: E402
from bnptrack.tracker.models._gauss import gaussian_logpdf  # noqa: E402
from bnptrack.tracker.models.clutter import UniformClutter  # noqa: E402

KIND = "range_bearing_deg"
DEG = 180.0 / np.pi
#: [bearing_rad, range_m] -> [range_m, bearing_deg]
M = np.array([[0.0, 1.0], [DEG, 0.0]])


def _wrap_deg(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class RangeBearingDeg:
    """``z = M h_br(x) + w``: the bearing-range model's measurement, columns swapped and the
    bearing in degrees; ``R = M R_br M^T``."""

    sigma_range: float = 10.0
    sigma_bearing_deg: float = 2.0
    sensor_x: float = 0.0
    sensor_y: float = 0.0
    heading: float = 0.0
    dim: int = 2
    kind: str = KIND
    fixes_position: ClassVar[bool] = True

    @classmethod
    def from_sensor(cls, s):
        return cls(s.sigma_range, float(np.rad2deg(s.sigma_bearing)), s.x, s.y, s.heading)

    @cached_property
    def br(self) -> mm.BearingRange:
        return mm.BearingRange(np.deg2rad(self.sigma_bearing_deg), self.sigma_range,
                               self.sensor_x, self.sensor_y, self.heading)

    @cached_property
    def R(self) -> np.ndarray:
        return M @ self.br.R @ M.T

    def h(self, x):
        return self.br.h(x) @ M.T

    def jacobian(self, x):
        return M @ self.br.jacobian(x)

    def residual(self, z, z_pred):
        d = np.asarray(z, dtype=float) - np.asarray(z_pred, dtype=float)
        d[..., 1] = _wrap_deg(d[..., 1])
        return d

    def sample(self, rng, x):
        z = self.br.sample(rng, x) @ M.T
        z[:, 1] = _wrap_deg(z[:, 1])
        return z

    def logpdf(self, z, x):
        return gaussian_logpdf(self.residual(np.atleast_2d(z), self.h(np.atleast_2d(x))), self.R)

    def _as_br(self, z):
        z = np.atleast_2d(np.asarray(z, dtype=float))
        return np.stack([np.deg2rad(z[:, 1]), z[:, 0]], axis=-1)

    def to_cartesian(self, z):
        return self.br.to_cartesian(self._as_br(z))

    def birth_position(self, z):
        return self.to_cartesian(z)


def _clutter(s):
    h = float(np.rad2deg(s.half_fov))
    return UniformClutter(s.clutter_rate, (s.range_min, -h), (s.range_max, h))


ENTRY = mm.MeasurementKind(KIND, RangeBearingDeg, 2, (), (0.0, -180.0), (float(np.finfo(float).max), 180.0),
                           "[range_m, bearing_deg]", _clutter, examples=((500.0, 5.0), (800.0, -10.0)))


@pytest.fixture
def new_kind(monkeypatch):
    monkeypatch.setitem(mm.KINDS, KIND, ENTRY)


@pytest.fixture
def frames(new_kind):
    from bnptrack.sources.scenarios import get_scenario
    from bnptrack.sources.synthetic import simulate_all
    from bnptrack.tracker.models.params import load_params

    scenario = dataclasses.replace(get_scenario("vo2017"), kind=KIND)
    params = scenario.adapt_params(load_params("vo2017"))
    return params, simulate_all(scenario, params, 3)[:12]


def test_simulated_frames_follow_the_new_model(frames):
    """Frames of the new kind: two columns, bearings in degrees within the field of view, and
    each detected object's row near its noise-free measurement ``M h_br(x)``."""
    params, fs = frames
    assert all(f.kind == KIND and f.z.shape[1] == 2 for f in fs)
    z = np.concatenate([f.z for f in fs])
    assert z[:, 0].min() >= 0.0 and np.abs(z[:, 1]).max() <= 90.0 + 20.0
    model = params.measurement(KIND)
    assert isinstance(model, RangeBearingDeg)
    near = 0
    for f in fs:
        zp = model.h(f.truth.states)  # (N, 2) noise-free [range, bearing_deg]
        d = np.abs(model.residual(f.z[:, None, :], zp[None])) / np.array([10.0, 2.0])
        near += int((d.max(axis=2) < 4.0).any(axis=0).sum())
    n_obj = sum(f.truth.states.shape[0] for f in fs)
    assert near >= 0.8 * n_obj  # p_detect 0.98; every detection within 4 sigma


def test_messages_round_trip_the_new_kind(frames):
    """Encoded as /measurements version 2 (a kind registered after version 1), decoded to the
    same rows; rows outside the entry's bounds are refused naming the column."""
    import json

    from bnptrack.tracker.messages import TOPIC_MEASUREMENTS, CodecError, decode, encode, json_schema, to_frame

    _params, fs = frames
    f = fs[4]
    raw = encode(f)
    obj = json.loads(raw)
    assert obj["v"] == 2 and obj["kind"] == KIND
    back = to_frame(decode(TOPIC_MEASUREMENTS, raw))
    assert back.kind == KIND and back.frame == f.frame
    np.testing.assert_array_equal(back.z, f.z)
    obj["z"] = [[100.0, 181.0]]
    with pytest.raises(CodecError, match=r"bearing must be within \[-180, 180\].*\$\.z\[0\]\[1\]"):
        decode(TOPIC_MEASUREMENTS, json.dumps(obj))
    assert KIND in json_schema(TOPIC_MEASUREMENTS)["$defs"]["MeasurementsMsg"]["properties"]["kind"]["enum"]


@pytest.mark.parametrize("name", ["ddp", "glmb"])
def test_trackers_track_the_new_kind(frames, name):
    """ddp and glmb find vo2017's first objects from frames of the new kind: by frame 12 each
    estimates at least one track within 60 m of a true object."""
    from bnptrack.tracker.registry import build
    from bnptrack.tracker.state import run

    params, fs = frames
    out = list(run(build(name, params), fs, 0))
    last_frame, est, _ = out[-1]
    assert len(est.tracks) >= 1
    truth = last_frame.truth.positions
    pos = np.array([t.state[[0, 2]] for t in est.tracks])
    dist = np.linalg.norm(pos[:, None] - truth[None], axis=2).min(axis=1)
    assert dist.min() < 60.0


def test_warm_up_steps_the_new_kind(new_kind):
    """The registry's warm-up steps a tracker on the entry's example rows (after the built-in kinds')."""
    from bnptrack.tracker.models.params import load_params
    from bnptrack.tracker.registry import build, warm_up

    seen = []

    class Spy:
        def __init__(self, inner):
            self.inner = inner

        def initial_state(self):
            return self.inner.initial_state()

        def step(self, state, frame, rng):
            seen.append((frame.kind, frame.frame, frame.z.copy()))
            return self.inner.step(state, frame, rng)

    warm_up(Spy(build("ddp", load_params("vo2017"))))
    assert [k for k, _f, _z in seen] == ["bearing_range"] * 3 + ["range"] * 3 + [KIND] * 3
    k, f, z = seen[-1]
    np.testing.assert_allclose(z, [[500.0 + 3 * 0.001, 5.0 + 3 * 5.0], [800.0 + 3 * 0.001, -10.0 + 3 * 5.0]])


def test_rerun_sink_draws_the_new_kind(frames, tmp_path):
    """The sink draws each row at the model's position (``to_cartesian``) and no rings (the
    rows fix a position)."""
    from rerun.chunk import RrdReader

    from bnptrack.sinks.rerun_sink import write_recording
    from bnptrack.tracker.registry import build
    from bnptrack.tracker.state import run

    params, fs = frames
    fs = fs[:5]
    estimates = [e for _f, e, _s in run(build("ddp", params), fs, 0)]
    path = tmp_path / "new_kind.rrd"
    write_recording(path, fs, estimates, {"scenario": "vo2017"}, params=params)
    assert path.exists()
    pts: dict[int, list] = {}
    entities = set()
    for chunk in RrdReader(path).stream():
        entities.add(chunk.entity_path)
        if chunk.entity_path != "/world/measurements":
            continue
        rb = chunk.to_record_batch()
        if "frame" in rb.schema.names and "Points2D:positions" in rb.schema.names:
            for k, v in zip(rb.column("frame").to_pylist(), rb.column("Points2D:positions").to_pylist()):
                if v is not None:
                    pts[k] = v
    assert "/world/measurements/rings" not in entities
    model = params.measurement(KIND)
    for f in fs:
        np.testing.assert_allclose(np.asarray(pts[f.frame]), model.to_cartesian(f.z)[0], rtol=1e-5, atol=1e-2)


def test_params_file_sensor_kind_is_checked_at_load(tmp_path, new_kind):
    """An unknown ``[sensors.NAME] kind`` fails when the file loads, naming file, sensor, key and
    the known kinds (the registered new kind among them); a registered one loads."""
    from bnptrack.tracker.config import ConfigError
    from bnptrack.tracker.models.params import load_params

    bad = tmp_path / "esm.toml"
    bad.write_text('extends = "vo2017"\n[sensors.esm]\nkind = "sonar"\n')
    with pytest.raises(ConfigError) as ei:
        load_params(bad)
    msg = str(ei.value)
    assert msg == (f"{bad}: [sensors.esm] kind = 'sonar' is not a measurement kind "
                   f"(known: bearing_range, range, xy, {KIND})")
    good = tmp_path / "ok.toml"
    good.write_text(f'extends = "vo2017"\n[sensors.esm]\nkind = "{KIND}"\n')
    assert load_params(good).sensors["esm"].kind == KIND


def test_range_only_locus_is_the_ring():
    """What the sink draws for rows that fix no position (hand-computed): a range-only row at a
    sensor at (100, 0) with r = 50 has the ring of radius 50 around it as its locus; its nearest
    point to (200, 0) is (150, 0), to (100, 300) is (100, 50), and without a track (NaN) the
    ring's point straight up, (100, 50)."""
    m = mm.RangeOnly(10.0, 100.0, 0.0)
    assert not m.fixes_position and mm.BearingRange.fixes_position and mm.Cartesian.fixes_position
    z = np.array([[50.0], [50.0], [50.0]])
    toward = np.array([[200.0, 0.0], [100.0, 300.0], [np.nan, np.nan]])
    np.testing.assert_allclose(m.locus_point(z, toward), [[150.0, 0.0], [100.0, 50.0], [100.0, 50.0]], atol=1e-12)
    np.testing.assert_allclose(m.locus(z[:1], np.array([0.0, np.pi / 2, -np.pi / 2])),
                               [[[100.0, 50.0], [150.0, 0.0], [50.0, 0.0]]], atol=1e-12)
