"""The cluster structure in Rerun recordings (sinks/rerun_clusters.py): tracks coloured by motion
cluster, the ``world/clusters`` links and the ``metrics/structure`` series; read back from the
``.rrd`` with the helpers of test_rerun_sink.py."""

from __future__ import annotations

import os

os.environ.setdefault("CI", "1")  # before `import rerun` (see test_rerun_sink.py)
os.environ.setdefault("RUST_LOG", "error")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bnptrack.sinks.rerun_clusters import ClusterColours  # noqa: E402
from bnptrack.sinks.rerun_sink import write_recording  # noqa: E402
from bnptrack.sinks.rerun_style import (GREY_CLUTTER, GREY_TRUTH, MIN_COLOR_DISTANCE, PALETTE, SENSOR_COLOR,  # noqa: E402
                               WHITE_UNASSIGNED, cluster_color, pack_rgba, unpack_rgba)
from bnptrack.sources.scenarios import get_scenario  # noqa: E402
from bnptrack.sources.synthetic import simulate_all  # noqa: E402
from test_rerun_sink import _blueprint_view_names, by_frame, read_rrd, rrd_verify  # noqa: E402
from bnptrack.tracker.cardinality import pmf_map, pmf_mean  # noqa: E402
from bnptrack.tracker.models.params import load_params  # noqa: E402
from bnptrack.tracker.registry import build  # noqa: E402
from bnptrack.tracker.state import run  # noqa: E402

N = 40
SCENE = ("n_objects=1", "group_sizes=[3,3]", "passing_pairs=0", f"K={N}", f"life_min={N}")
META = {"scenario": "groups", "params": "vo2017", "tracker": "ddp", "seed": "101"}
RESERVED = [c[:3] for c in (SENSOR_COLOR, GREY_TRUTH, GREY_CLUTTER, WHITE_UNASSIGNED)]


@pytest.fixture(scope="module")
def groups_run(tmp_path_factory):
    sc = get_scenario("groups", 101, scene=SCENE)
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, 101)[:N]
    estimates = [e for _f, e, _s in run(build("ddp", params), frames, 0)]
    path = tmp_path_factory.mktemp("rrd") / "groups.rrd"
    write_recording(path, frames, estimates, META, params=params)
    return frames, estimates, path, read_rrd(path)


def _colours(contents, estimates, frames) -> dict[tuple[int, str], int]:
    """(frame, label) -> the packed colour the recording gives the track's point."""
    out = {}
    for lab in {t.label for e in estimates for t in e.tracks}:
        cols = by_frame(contents[f"/world/tracks/{lab}"], "Points2D:colors")
        strips = by_frame(contents[f"/world/tracks/{lab}"], "LineStrips2D:colors")
        for k, c in cols.items():
            assert strips[k] == [c[0], (c[0] & 0xFFFFFF00) | 170]  # trail, and the ellipse more transparent
            out[(k, lab)] = c[0]
    return out


# -- unit: colours by cluster, hand-worked ----------------------------------------------------
def test_cluster_colours_keep_a_colour_per_live_cluster():
    cc = ClusterColours()
    label = np.uint32(pack_rgba((*PALETTE[0], 255)))
    got = cc.frame_colours(np.array([5, 7, 5, -1]), np.array([1, 2, 3, label], dtype=np.uint32))
    # the unclustered track's label colour is taken first; then the new clusters in id order,
    # each avoiding the colours taken before it
    c5 = pack_rgba(cluster_color(5, [PALETTE[0]]))
    c7 = pack_rgba(cluster_color(7, [PALETTE[0], unpack_rgba(c5)[:3]]))
    assert got.tolist() == [c5, c7, c5, int(label)] and len({c5, c7, int(label)}) == 3
    assert cc.seen
    # cluster 5 keeps its colour while it has members; 7 ended and its colour is free again
    assert cc.frame_colours(np.array([5, 9]), np.array([1, 2], dtype=np.uint32))[0] == c5
    # no cluster: the label colours, unchanged
    np.testing.assert_array_equal(cc.frame_colours(np.array([-1]), np.array([11], dtype=np.uint32)), [11])


def test_cluster_colours_are_never_the_reserved_colours():
    for c in range(50):
        rgb = np.array(cluster_color(c)[:3], float)
        assert min(np.linalg.norm(rgb - np.array(r, float)) for r in RESERVED) >= MIN_COLOR_DISTANCE


# -- a groups run ------------------------------------------------------------------------------
def test_groups_recording_colours_tracks_and_measurements_by_cluster(groups_run):
    frames, estimates, path, contents = groups_run
    assert rrd_verify(path).returncode == 0
    colour = _colours(contents, estimates, frames)
    meas = by_frame(contents["/world/measurements"], "Points2D:colors")
    n_shared = 0
    for f, e in zip(frames, estimates):
        by_cluster: dict[int, set[int]] = {}
        for t in e.tracks:
            c = colour[(f.frame, t.label)]
            assert unpack_rgba(c)[:3] in PALETTE
            if t.cluster is not None:
                by_cluster.setdefault(t.cluster, set()).add(c)
        # one colour per cluster, different clusters of a frame in different colours
        assert all(len(cs) == 1 for cs in by_cluster.values())
        if len(by_cluster) <= len(PALETTE):
            assert len({next(iter(cs)) for cs in by_cluster.values()}) == len(by_cluster)
        n_shared += sum(sum(t.cluster == c for t in e.tracks) >= 2 for c in by_cluster)
        # an assigned measurement has its track's colour of the frame
        for m, a in enumerate(e.assignments):
            if a is not None and a in e.labels:
                assert meas[f.frame][m] == colour[(f.frame, a)]
    assert n_shared > 0, "no cluster with two reported members: the run shows no convoy"


def test_groups_recording_draws_cluster_links_and_the_structure_series(groups_run):
    frames, estimates, path, contents = groups_run
    centre = by_frame(contents["/world/clusters"], "Points2D:positions")
    names = by_frame(contents["/world/clusters/labels"], "Points2D:labels")
    name_at = by_frame(contents["/world/clusters/labels"], "Points2D:positions")
    assert by_frame(contents["/world/clusters"], "Points2D:labels") == {}  # the centroids carry no name
    links = by_frame(contents["/world/clusters"], "LineStrips2D:strips")
    count = by_frame(contents["/metrics/structure/clusters"], "Scalars:scalars")
    card = by_frame(contents["/metrics/structure/cardinality"], "Scalars:scalars")
    first = min(f.frame for f, e in zip(frames, estimates) if any(t.cluster is not None for t in e.tracks))
    assert min(count) == first
    lifts = []
    for f, e in zip(frames, estimates):
        p = e.cardinality_pmf
        assert card[f.frame] == [pmf_mean(p), float(pmf_map(p))]  # exact
        ids = sorted({t.cluster for t in e.tracks if t.cluster is not None})
        if f.frame >= first:
            assert count[f.frame] == [float(len(ids))]
        big = [c for c in ids if sum(t.cluster == c for t in e.tracks) >= 2]
        assert names.get(f.frame, []) == [f"C{c} ({sum(t.cluster == c for t in e.tracks)})" for c in big]
        for c, xy, at in zip(big, centre.get(f.frame, []), name_at.get(f.frame, [])):
            members = [t.position for t in e.tracks if t.cluster == c]
            np.testing.assert_allclose(xy, np.mean(members, axis=0), rtol=1e-6, atol=1e-2)
            # the name over the centroid, a fixed height above the highest member (its name is under it)
            lifts.append(at[1] - max(m[1] for m in members))
            np.testing.assert_allclose(at[0], xy[0], rtol=1e-6, atol=1e-2)
        assert len(links.get(f.frame, [])) == sum(sum(t.cluster == c for t in e.tracks) for c in big)
    # 4 truth-cross half-widths of 0.0075 x the scene's 4400 m (the 4000 m field of view, 5 % margins)
    np.testing.assert_allclose(lifts, 132.0, atol=1e-3)
    views = _blueprint_view_names(path)[0]
    # the motion clusters of the reported tracks and the state's objects (n_clusters) apart
    assert {"motion clusters of the tracks; posterior cardinality mean and MAP",
            "hypothesised objects (n_clusters)"} <= views and "clusters" not in views
    series = [b.column("SeriesLines:names").to_pylist() for b in contents["/metrics/structure/clusters"]
              if "SeriesLines:names" in b.schema.names]
    assert series == [[["motion clusters"]]]


def test_a_single_level_recording_has_label_colours_and_no_clusters(tmp_path):
    params = load_params("vo2017")
    frames = simulate_all(get_scenario("vo2017"), params, 1)[:15]
    estimates = [e for _f, e, _s in run(build("ddp-mb", params), frames, 0)]
    path = tmp_path / "ddp-mb.rrd"
    write_recording(path, frames, estimates, META, params=params)
    contents = read_rrd(path)
    assert "/world/clusters" not in contents
    assert by_frame(contents["/metrics/structure/clusters"], "Scalars:scalars") == {}  # its style only
    assert len(by_frame(contents["/metrics/structure/cardinality"], "Scalars:scalars")) == 15
    colour = _colours(contents, estimates, frames)
    for lab in {t.label for e in estimates for t in e.tracks}:
        mine = {c for (k, lb), c in colour.items() if lb == lab}
        assert len(mine) == 1 and unpack_rgba(mine.pop())[:3] in PALETTE  # one colour for the label's life
    assert _legend_track_label(contents) == "track + trail (colour: its label)"


def _legend_track_label(contents) -> str:
    return contents["/world/legend/track"][-1].column("Points2D:labels").to_pylist()[-1][0]


def test_the_legend_says_a_track_s_colour_is_its_motion_cluster(groups_run):
    _frames, _estimates, _path, contents = groups_run
    assert _legend_track_label(contents) == "track + trail (colour: its motion cluster)"


def test_a_scene_that_starts_without_objects_records(groups_run, tmp_path):
    """Frames with truth but no true object (a groups scene before its first birth), sent on
    their own (flush_interval=0): no truth trail, no error (it raised in np.concatenate)."""
    from dataclasses import replace

    from bnptrack.sinks.rerun_geometry import truth_trails
    from bnptrack.tracker.types import Truth

    pts, lengths, kept = truth_trails([((), np.zeros((0, 2)))], {}, 20)
    assert pts.shape == (0, 2) and lengths.size == 0 and kept == {}
    frames, estimates, _path, _contents = groups_run
    empty = Truth((), np.zeros((0, 5)))
    frames = [replace(f, truth=empty) for f in frames[:3]] + list(frames[3:6])
    path = tmp_path / "empty-start.rrd"
    write_recording(path, frames, estimates[:6], META, flush_interval=0.0)
    trails = by_frame(read_rrd(path)["/world/truth/trails"], "LineStrips2D:strips")
    assert [len(trails.get(f.frame, [])) for f in frames] == [0, 0, 0] + [len(f.truth.ids) for f in frames[3:]]


def test_cluster_rows_do_not_depend_on_how_frames_were_batched(groups_run, tmp_path):
    """``world/clusters`` starts at the first frame with a motion cluster whether the frames
    reach the file one by one (flush_interval=0) or in one chunk: before, a chunk that held
    that frame also gave the earlier frames of the chunk empty rows (seen as a flaky
    ``track --topic ... --rrd`` comparison)."""
    frames, estimates, _path, batched = groups_run
    path = tmp_path / "one-by-one.rrd"
    write_recording(path, frames, estimates, META, params=None, flush_interval=0.0)
    single = read_rrd(path)
    first = min(f.frame for f, e in zip(frames, estimates) if any(t.cluster is not None for t in e.tracks))
    for entity, comp in (("/world/clusters", "Points2D:positions"), ("/world/clusters", "LineStrips2D:strips"),
                         ("/world/clusters/labels", "Points2D:positions"), ("/world/clusters/labels", "Points2D:labels")):
        a = by_frame(batched[entity], comp)
        b = by_frame(single[entity], comp)
        assert a == b and min(a) == first
