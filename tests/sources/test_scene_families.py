"""Generated scenario families ``random`` and ``random-cv`` (sources/scene_families.py)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.pipeline.resolve import resolve_params
from bnptrack.sources.scenarios import parse_crossings
from bnptrack.sources.scenarios import scenario_params as resolve_simulation_params
from bnptrack.sources.mcap_log import iter_frames, read_metadata
from bnptrack.sources.scenarios import get_scenario, is_generated, scenario_names
from bnptrack.sources.scene_families import FAMILIES, CROSSING_MIN_SIDE, in_field, scene_config, scene_rng
from bnptrack.sources.synthetic import measurement_frame_rng, simulate_all
from bnptrack.tracker.config import ConfigError
from bnptrack.tracker.models.params import load_params

SEEDS = range(12)


def _positions(sc):
    return sc.states()[..., [0, 2]]  # (K, n, 2), NaN where absent


def test_registry():
    assert {"random", "random-cv"} <= set(scenario_names())
    assert is_generated("random") and not is_generated("vo2017")
    with pytest.raises(ConfigError, match="needs a scene seed"):
        get_scenario("random")
    with pytest.raises(ConfigError, match="apply only to the generated"):
        get_scenario("vo2017", scene=("n_objects=3",))


def test_seed_pinned_determinism():
    a, b = get_scenario("random", 3), get_scenario("random", seed=3, scene=())
    assert a is b  # cached, and a pure function of (name, seed, scene)
    from bnptrack.sources.scene_families import generate_scene

    c = generate_scene("random", 3)
    assert c == a
    assert get_scenario("random", 4) != a
    # pinned values (catch changes of the generator or of its stream)
    assert len(a.targets) == 24
    assert a.crossings == (("T6", "T7", 43), ("T15", "T16", 69), ("T14", "T1", 55))
    t1 = a.targets[0]
    assert (t1.birth, t1.death) == (1, 83)
    np.testing.assert_allclose(
        t1.xstart, [-411.71433425410845, 4.545287767342241, 314.2305922551954,
                    8.298433864316898, -0.033164398057416535], rtol=1e-10)
    # the scene stream is not a frame stream
    assert scene_rng("random", 3).integers(0, 2**31) != measurement_frame_rng(3, 0).integers(0, 2**31)


@pytest.mark.parametrize("seed", SEEDS)
def test_random_counts_ranges_and_field(seed):
    sc = get_scenario("random", seed)
    fam = FAMILIES["random"]
    assert 20 <= len(sc.targets) <= 30 and sc.K == 100
    assert len(sc.crossings) == 3
    life = sc.deaths - sc.births + 1
    assert life.min() >= 15 and life.max() <= 100
    st = sc.states()
    present = sc.presence()
    assert np.isnan(st[~present]).all() and np.isfinite(st[present]).all()
    assert in_field(st[present], fam).all()  # inside range 150-1900 m, |bearing| <= 85 deg
    speed = np.hypot(st[..., 1], st[..., 3])[present]
    assert speed.min() >= 5.0 - 1e-9 and speed.max() <= 40.0 + 1e-9
    turn = np.abs(np.rad2deg(st[..., 4][present]))
    assert turn.max() <= 3.0 + 1e-12
    assert [t.id for t in sc.targets] == [f"T{i + 1}" for i in range(len(sc.targets))]
    assert (np.diff(sc.births) >= 0).all()  # named in order of birth


@pytest.mark.parametrize("seed", SEEDS)
def test_crossing_pairs_within_20m(seed):
    sc = get_scenario("random", seed)
    pos = _positions(sc)
    idx = {t: j for j, t in enumerate(sc.ids)}
    for a, b, k in sc.crossings:
        ja, jb = idx[a], idx[b]
        d = np.linalg.norm(pos[k - 1, ja] - pos[k - 1, jb])
        assert d <= 10.0 + 1e-6  # crossing_sep default 10 m, so within 20 m
        for j in (ja, jb):  # present CROSSING_MIN_SIDE scans either side
            t = sc.targets[j]
            assert t.birth <= k - CROSSING_MIN_SIDE and t.death >= k + CROSSING_MIN_SIDE
        # they really cross rather than travel together: headings differ by >= 30 deg
        va, vb = sc.states()[k - 1, ja, [1, 3]], sc.states()[k - 1, jb, [1, 3]]
        cosang = va @ vb / np.linalg.norm(va) / np.linalg.norm(vb)
        assert cosang <= np.cos(np.deg2rad(30.0)) + 1e-9


@pytest.mark.parametrize("seed", SEEDS)
def test_random_cv_family(seed):
    sc = get_scenario("random-cv", seed)
    assert 8 <= len(sc.targets) <= 15 and sc.crossings == ()
    st, present = sc.states(), sc.presence()
    assert (st[..., 4][present] == 0.0).all()
    speed = np.hypot(st[..., 1], st[..., 3])[present]
    assert speed.min() >= 2.0 - 1e-9 and speed.max() <= 25.0 + 1e-9
    assert in_field(st[present], FAMILIES["random-cv"]).all()
    assert (sc.deaths - sc.births + 1).min() >= 20
    # births in at most 3 bursts, each spanning burst..burst+2: at most 3 groups of births
    # separated by gaps of more than 2 scans
    births = np.unique(sc.births)
    assert 1 + int((np.diff(births) > 2).sum()) <= 3


def test_scene_overrides_and_errors():
    sc = get_scenario("random", 5, ("n_objects=25", "crossing_pairs=2"))
    assert len(sc.targets) == 25 and len(sc.crossings) == 2
    assert sc.scene == ("n_objects=25", "crossing_pairs=2") and sc.seed == 5
    with pytest.raises(ConfigError, match=r"unknown key 'scene\.n_object'"):
        scene_config("random", ["n_object=3"])
    with pytest.raises(ConfigError, match="crossing_sep"):
        scene_config("random", ["crossing_sep=25"])
    with pytest.raises(ConfigError, match="crossing_pairs"):
        scene_config("random", ["n_objects=4", "crossing_pairs=3"])


def test_no_birth_regions_after_adapt_params():
    base = get_scenario("vo2017").adapt_params(load_params("vo2017"))
    assert len(base.birth) == 4  # Vo's regions, from the vo2017 scenario
    for name in ("random", "random-cv"):
        assert get_scenario(name, 1).adapt_params(base).birth == []
        assert resolve_simulation_params(name, "vo2017", ("scene.n_objects=9",)).birth == []
        # track on such a log: the record's params, with no birth regions either
        meta = {"scenario": name, "params": "vo2017", "seed": "1"}
        assert resolve_params(None, meta).params.birth == []
    assert len(resolve_params(None, {"scenario": "vo2017", "params": "vo2017"}).params.birth) == 4


def test_simulated_frames_carry_the_scene_truth():
    sc = get_scenario("random", 2)
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, 2)
    assert [len(f.truth.ids) for f in frames] == sc.cardinality().tolist()


def test_cli_simulate_random_and_track(tmp_path):
    out = tmp_path / "r.mcap"
    res = CliRunner().invoke(main, ["simulate", "--scenario", "random", "--seed", "3",
                                    "--set", "scene.n_objects=21", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "21 objects" in res.output
    meta = read_metadata(out)
    assert meta["scene_seed"] == "3" and meta["scene"] == "n_objects=21"
    assert "overrides" not in meta
    sc = get_scenario("random", 3, ("n_objects=21",))
    assert parse_crossings(meta["crossings"]) == sc.crossings
    frames = list(iter_frames(out))
    assert [len(f.truth.ids) for f in frames] == sc.cardinality().tolist()
    np.testing.assert_allclose(frames[49].truth.states, sc.truth()[49].states)
    tr = CliRunner().invoke(main, ["track", str(out), "--tracker", "ddp", "--out",
                                   str(tmp_path / "t.mcap")])
    assert tr.exit_code == 0, tr.output
    assert "mean OSPA" in tr.output and "n/a" not in tr.output.split("mean OSPA")[1].split("\n")[0]
    assert "no birth regions" in tr.output
    assert "crossings kept" in tr.output and "/3 pairs keep both labels" in tr.output
    bad = CliRunner().invoke(main, ["simulate", "--scenario", "random", "--set", "scene.nope=1",
                                    "--out", str(tmp_path / "b.mcap")])
    assert bad.exit_code == 2 and "unknown key 'scene.nope'" in bad.output
    assert len(bad.output.strip().splitlines()) == 1


def test_family_template_and_explicit_params():
    from bnptrack.sources.scene_families import family_template

    t = family_template("random")
    assert t.targets == () and t.birth == () and t.K == 100 and t.kind == "bearing_range"
    assert t.adapt_params(load_params("vo2017")).birth == []
    # track --params NAME of a random log: the named set with the scene's defaults (no regions)
    meta = {"scenario": "random", "params": "vo2017", "seed": "1"}
    assert resolve_params("vo2017", meta).params.birth == []
    assert "no birth regions" in resolve_params(None, meta).reason
