"""The anchor cache of benchmarks/vs_stonesoup.py (``--anchor-cache``), without Stone Soup:
the anchor run is replaced by a counting fake."""

from __future__ import annotations

import numpy as np

import benchmarks.vs_stonesoup as vs
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.types import Frame, Truth


def _frames(shift: float = 0.0) -> list[Frame]:
    out = []
    for k in (1, 2):
        z = np.array([[0.1 * k + shift, 500.0], [-0.2, 900.0]])
        out.append(Frame(frame=k, stamp_ns=k * 10**9, sensor="self", kind="bearing_range", z=z,
                         truth=Truth(("a",), np.zeros((1, 5)))))
    return out


def _job(tmp_path, sets=()) -> vs.Job:
    return vs.Job("ss-jpda", "random", 3, "vo2017", (), (), tuple(sets), str(tmp_path))


def test_cache_reuses_a_run_and_its_key_follows_frames_and_settings(tmp_path, monkeypatch):
    calls = []

    def fake_anchor(job, params, frames):
        calls.append(job.tracker)
        return [vs.Scan(("t1",), np.array([[1.5, 2.5]]), 7.0) for _ in frames], 2

    monkeypatch.setattr(vs, "_run_anchor", fake_anchor)
    monkeypatch.setattr("importlib.metadata.version", lambda name: "1.9.1")
    params = load_params("vo2017")
    first, warn1, cached1 = vs._cached_anchor(_job(tmp_path), params, _frames())
    again, warn2, cached2 = vs._cached_anchor(_job(tmp_path), params, _frames())
    assert calls == ["ss-jpda"] and (cached1, cached2) == (False, True)
    assert warn1 == warn2 == 2
    assert [s.labels for s in again] == [("t1",), ("t1",)] and again[1].ms == 7.0
    np.testing.assert_array_equal(again[0].positions, [[1.5, 2.5]])
    # other measurements, other settings or another parameter set: a new run each
    vs._cached_anchor(_job(tmp_path), params, _frames(shift=1e-9))
    vs._cached_anchor(_job(tmp_path, ["jpda.min_points=4"]), params, _frames())
    vs._cached_anchor(_job(tmp_path), load_params("vo2017", ["p_detect=0.9"]), _frames())
    assert len(calls) == 4
    assert len(list(tmp_path.glob("ss-jpda-*.json"))) == 4
