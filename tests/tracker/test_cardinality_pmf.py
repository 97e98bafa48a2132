"""The posterior cardinality distribution (tracker/cardinality.py), every tracker's
``Estimate.cardinality_pmf`` and its ``/tracks`` field (schema 3)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from bnptrack.sources.scenarios import get_scenario
from bnptrack.sources.synthetic import simulate_all
from bnptrack.tracker.cardinality import TAIL, existence_cardinality, pmf_map, pmf_mean, poisson_binomial, truncate_tail
from bnptrack.tracker.glmb import GlmbState
from bnptrack.tracker.messages import TOPIC_TRACKS, CodecError, decode, encode, from_estimate, to_estimate
from bnptrack.tracker.models.params import load_params
from bnptrack.tracker.registry import build
from bnptrack.tracker.state import run
from bnptrack.tracker.types import Estimate, TrackEstimate


# -- Poisson-binomial, hand-computed ---------------------------------------------------------
def test_poisson_binomial_of_two_halves():
    np.testing.assert_allclose(poisson_binomial([0.5, 0.5]), [0.25, 0.5, 0.25], rtol=0, atol=1e-15)


def test_poisson_binomial_of_three_by_hand():
    # r = (0.9, 0.2, 0.5); q = 1 - r = (0.1, 0.8, 0.5)
    # p0 = .1*.8*.5 = .04
    # p1 = .9*.8*.5 + .1*.2*.5 + .1*.8*.5 = .36 + .01 + .04 = .41
    # p2 = .9*.2*.5 + .9*.8*.5 + .1*.2*.5 = .09 + .36 + .01 = .46
    # p3 = .9*.2*.5 = .09
    p = poisson_binomial([0.9, 0.2, 0.5])
    np.testing.assert_allclose(p, [0.04, 0.41, 0.46, 0.09], rtol=0, atol=1e-15)
    assert pmf_mean(p) == pytest.approx(0.9 + 0.2 + 0.5, abs=1e-15)  # E n = sum r
    assert pmf_map(p) == 2


def test_certain_and_impossible_objects_shift_or_leave_the_pmf():
    np.testing.assert_array_equal(poisson_binomial([1.0, 0.0, 0.5]), [0.0, 0.5, 0.5])
    np.testing.assert_array_equal(poisson_binomial([]), [1.0])
    np.testing.assert_array_equal(poisson_binomial([0.0, 0.0]), [1.0])
    with pytest.raises(ValueError, match="finite"):
        poisson_binomial([0.5, np.nan])


def test_poisson_binomial_equals_the_enumeration_of_all_subsets():
    r = np.random.default_rng(3).uniform(0.0, 1.0, 9)
    want = np.zeros(10)
    for present in itertools.product((0, 1), repeat=9):
        x = np.array(present)
        want[x.sum()] += np.prod(np.where(x == 1, r, 1.0 - r))
    np.testing.assert_allclose(poisson_binomial(r), want, rtol=1e-12, atol=1e-16)


def test_the_tail_below_1e_9_is_dropped_and_the_rest_kept_exact():
    # r = (0.5, e, e), e = 1e-6: p3 = 0.5 e^2 = 5e-13 < 1e-9 is dropped; the tail past n = 1,
    # p2 + p3 ~ 1e-6, is not: three entries, exact (not renormalised)
    e = 1e-6
    p = existence_cardinality([0.5, e, e])
    q = (1 - e) ** 2
    np.testing.assert_allclose(p, [0.5 * q, 0.5 * q + 0.5 * 2 * e * (1 - e), 0.5 * 2 * e * (1 - e) + 0.5 * e * e],
                               rtol=1e-12)
    assert 0 < 1.0 - p.sum() < TAIL
    # a long tail of unlikely objects adds no entries
    assert existence_cardinality(np.r_[[0.9, 0.8], np.full(300, 1e-14)]).size == 3
    np.testing.assert_array_equal(truncate_tail([0.5, 0.5 - 1e-10, 1e-10]), [0.5, 0.5 - 1e-10])
    np.testing.assert_array_equal(truncate_tail([0.5, 0.5 - 1e-9, 1e-9]), [0.5, 0.5 - 1e-9, 1e-9])  # not below
    np.testing.assert_array_equal(truncate_tail([1.0]), [1.0])


# -- the GLMB: sum of the hypothesis weights per cardinality ----------------------------------
def test_glmb_cardinality_sums_hypothesis_weights_on_a_hand_built_state():
    # hypotheses {0, 1} w .1, {0} w .3, {} w .2, {1} w .4 -> rho = (.2, .3 + .4, .1)
    st = GlmbState(labels=("a", "b"), mean=np.zeros((2, 5)), cov=np.tile(np.eye(5), (2, 1, 1)),
                   hyp_tracks=np.array([[0, 1], [0, -1], [-1, -1], [1, -1]]), log_w=np.log([0.1, 0.3, 0.2, 0.4]))
    np.testing.assert_allclose(truncate_tail(st.cardinality()), [0.2, 0.7, 0.1], rtol=1e-12)


# -- every tracker fills it -------------------------------------------------------------------
@pytest.fixture(scope="module")
def vo_first12():
    params = load_params("vo2017")
    return params, simulate_all(get_scenario("vo2017"), params, 1)[:12]


@pytest.mark.parametrize("name", ["ddp-mb", "dpyp-mb", "glmb"])
def test_every_tracker_reports_its_posterior_cardinality(vo_first12, name):
    params, frames = vo_first12
    tracker = build(name, params)
    for _f, est, state in run(tracker, frames, 0):
        p = est.cardinality_pmf
        assert p is not None and p.ndim == 1 and np.all(p >= 0) and abs(p.sum() - 1.0) < TAIL
        if name == "glmb":  # its own exact distribution, from the hypothesis weights
            np.testing.assert_array_equal(p, truncate_tail(state.cardinality()))
            assert pmf_map(p) == est.diagnostics["map_cardinality"]
            assert pmf_mean(p) == pytest.approx(est.diagnostics["mean_cardinality"], abs=1e-8)
        else:  # the Poisson-binomial of every hypothesised object of the state
            np.testing.assert_array_equal(p, existence_cardinality(state.existence))
            assert pmf_mean(p) == pytest.approx(float(np.sum(state.existence)), abs=1e-8)
    assert pmf_mean(p) > 0.5  # objects were found


def test_the_two_level_tracker_reports_the_cardinality_of_its_merged_objects():
    sc = get_scenario("groups", 101, scene=("n_objects=1", "group_sizes=[3]", "passing_pairs=0", "K=30", "life_min=30"))
    params = sc.adapt_params(load_params("vo2017"))
    frames = simulate_all(sc, params, 101)[:15]
    for _f, est, state in run(build("ddp", params), frames, 0):
        np.testing.assert_array_equal(est.cardinality_pmf, existence_cardinality(state.existence))
    assert any(t.cluster is not None for t in est.tracks)


# -- the /tracks field ------------------------------------------------------------------------
def _est(pmf, cluster=None) -> Estimate:
    t = TrackEstimate("1.0", np.arange(5.0), np.eye(5), 0.9, cluster=cluster)
    return Estimate(4, 4_000, (t,), (), (), {}, None if pmf is None else np.asarray(pmf, dtype=float))


def _raw(**over) -> bytes:
    obj = {"v": 3, "run": "", "frame": 7, "stamp_ns": 0, "tracks": [], "assignments": [], "assignment_prob": [],
           "cardinality_pmf": [0.04, 0.41, 0.46, 0.09]}
    obj.update(over)
    return json.dumps(obj).encode()


def test_codec_round_trip_writes_version_3_only_with_a_pmf():
    data = encode(_est([0.04, 0.41, 0.46, 0.09]))
    obj = json.loads(data)
    assert obj["v"] == 3 and obj["cardinality_pmf"] == [0.04, 0.41, 0.46, 0.09]
    back = to_estimate(decode(TOPIC_TRACKS, data))
    np.testing.assert_array_equal(back.cardinality_pmf, [0.04, 0.41, 0.46, 0.09])
    assert encode(back) == data  # and the message path writes the same bytes
    from bnptrack.tracker.message_encode import _encode_msg

    assert _encode_msg(from_estimate(back)) == data
    # without a pmf: no field, and the version of the fields used (1, or 2 with a cluster)
    assert "cardinality_pmf" not in json.loads(encode(_est(None))) and json.loads(encode(_est(None)))["v"] == 1
    assert json.loads(encode(_est(None, cluster=2)))["v"] == 2
    assert json.loads(encode(_est([1.0], cluster=2)))["v"] == 3


@pytest.mark.parametrize("v", [1, 2])
def test_old_messages_without_the_field_still_decode(v):
    raw = {"v": v, "run": "", "frame": 7, "stamp_ns": 0, "assignments": [], "assignment_prob": [],
           "tracks": [{"label": "t1", "state": [1.0] * 5, "covariance": [0.0] * 25, "existence": 0.9}]}
    est = to_estimate(decode(TOPIC_TRACKS, json.dumps(raw).encode()))
    assert est.cardinality_pmf is None and est.tracks[0].existence == 0.9
    for w in (3,):  # version 3 without the (optional) field reads too
        assert to_estimate(decode(TOPIC_TRACKS, json.dumps({**raw, "v": w}).encode())).cardinality_pmf is None


@pytest.mark.parametrize("pmf, fragment", [
    ([0.5, -0.1, 0.6], "a negative entry -0.1"),
    ([0.5, 0.4], "a sum of 0.9"),
    ([], "0 entries"),
])
def test_decode_rejects_a_bad_pmf_in_one_line_naming_the_field(pmf, fragment):
    with pytest.raises(CodecError) as ei:
        decode(TOPIC_TRACKS, _raw(cardinality_pmf=pmf))
    msg = str(ei.value)
    assert "\n" not in msg and "cardinality_pmf" in msg and fragment in msg and msg.endswith("`$.cardinality_pmf`")
    with pytest.raises(CodecError, match=r"needs schema version 3.*\$\.cardinality_pmf"):
        decode(TOPIC_TRACKS, _raw(v=2))
    with pytest.raises(CodecError, match="cardinality_pmf"):
        decode(TOPIC_TRACKS, _raw(cardinality_pmf=[0.5, "x"]))


@pytest.mark.parametrize("pmf, fragment", [
    ([0.5, np.nan, 0.5], "a non-finite entry"),
    ([0.5, np.inf], "a non-finite entry"),
    ([0.3, 0.3], "a sum of 0.6"),
    ([1.0 + 1e-5], "a sum of"),
])
def test_encode_rejects_a_bad_pmf_naming_the_field(pmf, fragment):
    with pytest.raises(CodecError) as ei:
        encode(_est(pmf))
    assert fragment in str(ei.value) and str(ei.value).endswith("`$.cardinality_pmf`")
    assert encode(_est([0.5, 0.5 - 1e-7]))  # within the 1e-6 tolerance
