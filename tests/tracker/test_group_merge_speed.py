"""The compiled exact test and exclusion of the two-level tracker's merge
(group_merge.py's ``exact_status``, ``distinct_pairs``, ``exclusive_pairs``) and the remembered field-of-view
moments (group_theta.py's ``fov_moments``): the same decisions and numbers as the numpy code."""

from __future__ import annotations

import numpy as np
import pytest

from bnptrack.tracker.bnp.group_merge import (_distinct, _label_arrays, distinct_pairs, exact_status,
                                              exclusive_candidates, exclusive_pairs, pair_differences)
from bnptrack.tracker.bnp.group_theta import _fov_moments, fov_moments
from bnptrack.tracker.models.params import load_params


def _numpy_d2(mean, cov, ii, jj) -> np.ndarray:
    """The numpy exact test's distances (batched solve, then einsum): the reference."""
    diff, S = pair_differences(mean, cov, ii, jj)
    return np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])


def _pairs(seed: int, n: int):
    rng = np.random.default_rng(seed)
    mean = rng.normal(0, 30, (n, 5))
    A = rng.normal(size=(n, 5, 5)) * rng.uniform(0.5, 20, (n, 1, 1))
    cov = A @ np.swapaxes(A, 1, 2) + 0.05 * np.eye(5)
    ii, jj = np.triu_indices(n, k=1)
    return mean, cov, ii.astype(np.int64), jj.astype(np.int64)


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("max_d2", [1.0, 9.0, 100.0])
def test_exact_status_decides_as_numpy(seed: int, max_d2: float) -> None:
    """Every pair it decides (0/1) is decided the same by numpy; it decides almost all."""
    mean, cov, ii, jj = _pairs(seed, 40)
    status = exact_status(mean, cov, ii, jj, max_d2)
    ref = _numpy_d2(mean, cov, ii, jj) <= max_d2
    decided = status != 2
    np.testing.assert_array_equal(status[decided] == 1, ref[decided])
    assert decided.mean() > 0.99
    assert 0 < ref.sum() < ref.size  # both outcomes occur


def test_exact_status_hand_computed() -> None:
    """Unit covariances (S = 2 I), d = (3, 0, 0, 0): d'S^-1 d = 4.5; at 4.5 numpy decides."""
    mean = np.array([[0.0, 0, 0, 0, 0], [3.0, 0, 0, 0, 0]])
    cov = np.stack([np.eye(5), np.eye(5)])
    ii, jj = np.array([0]), np.array([1])
    assert exact_status(mean, cov, ii, jj, 4.6).tolist() == [1]
    assert exact_status(mean, cov, ii, jj, 4.4).tolist() == [0]
    assert exact_status(mean, cov, ii, jj, 4.5).tolist() == [2]  # within the margin: numpy's call


def test_exact_status_leaves_degenerate_pairs_to_numpy() -> None:
    """Singular, ill-conditioned or non-finite S: status 2 (numpy decides, as before)."""
    mean = np.array([[0.0, 0, 0, 0, 0], [3.0, 0, 0, 0, 0]])
    ii, jj = np.array([0]), np.array([1])
    singular = np.zeros((2, 5, 5))
    assert exact_status(mean, singular, ii, jj, 9.0).tolist() == [2]
    skewed = np.stack([np.diag([1e6, 1e-3, 1.0, 1.0, 1.0])] * 2)  # cond 1e9
    assert exact_status(mean, skewed, ii, jj, 9.0).tolist() == [2]
    nan_cov = np.stack([np.eye(5), np.full((5, 5), np.nan)])
    assert exact_status(mean, nan_cov, ii, jj, 9.0).tolist() == [2]


@pytest.mark.parametrize("seed", [1, 2])
def test_distinct_pairs_equals_python(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 30
    labels = tuple(f"{rng.integers(-1, 4)}.{m}" if rng.random() < 0.8 else f"init{m}" for m in range(n))
    taken = {lab: int(rng.integers(0, 5)) for lab in labels if rng.random() < 0.5}
    ii, jj = np.triu_indices(n, k=1)
    got = distinct_pairs(*_label_arrays(labels, taken), ii.astype(np.int64), jj.astype(np.int64))
    ref = _distinct(labels, taken, ii, jj)
    np.testing.assert_array_equal(got, ref)
    assert 0 < ref.sum() < ref.size


def test_label_arrays_hand_computed() -> None:
    birth, dotted, took = _label_arrays(("3.1", "-2.0", "x"), {"-2.0": 4})
    assert birth.tolist() == [3, -2, 0]
    assert dotted.tolist() == [True, True, False]
    assert took.tolist() == [-1, 4, -1]


def test_fov_moments_remembered_and_copied() -> None:
    """The remembered moments are the computed ones, and a caller's change does not reach them."""
    det = load_params("vo2017").detection()
    _fov_moments.cache_clear()
    mean, cov = fov_moments(det)
    fresh_mean, fresh_cov = _fov_moments.__wrapped__(det, 400)
    np.testing.assert_array_equal(mean, fresh_mean, strict=True)
    np.testing.assert_array_equal(cov, fresh_cov, strict=True)
    mean[0] = 1e9
    cov[0, 0] = -1.0
    again_mean, again_cov = fov_moments(det)
    np.testing.assert_array_equal(again_mean, fresh_mean, strict=True)
    np.testing.assert_array_equal(again_cov, fresh_cov, strict=True)
    assert _fov_moments.cache_info().hits == 1


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("max_d2", [4.0, 25.0])
def test_exclusive_pairs_equals_the_three_passes(seed: int, max_d2: float) -> None:
    """The fused pass keeps, in the same order, the pairs of exclusive_candidates that are not
    distinct and that exact_status does not reject, with exact_status' status."""
    rng = np.random.default_rng(seed)
    mean, cov, _, _ = _pairs(seed, 40)
    mean[:, [0, 2]] /= 10.0  # crowd them: many pairs pass the bound
    r = rng.uniform(0.05, 0.7, 40)
    labels = tuple(f"{rng.integers(0, 3)}.{m}" for m in range(40))
    taken = {lab: int(rng.integers(0, 4)) for lab in labels if rng.random() < 0.5}
    arrays = _label_arrays(labels, taken)
    ii, jj, status = exclusive_pairs(mean, cov, r, max_d2, *arrays)
    ci, cj = exclusive_candidates(mean, cov, r, max_d2)
    keep = ~distinct_pairs(*arrays, ci, cj)
    ci, cj = ci[keep], cj[keep]
    cs = exact_status(mean, cov, ci, cj, max_d2)
    np.testing.assert_array_equal(ii, ci[cs != 0])
    np.testing.assert_array_equal(jj, cj[cs != 0])
    np.testing.assert_array_equal(status, cs[cs != 0])
    assert (status == 1).sum() > 0 and ci.size > ii.size


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_label_arrays_equal_the_taken_dict_route(seed: int) -> None:
    """``label_arrays`` (one pass) equals ``_label_arrays`` of ``taken_measurements``' dict:
    MAP assignments above the threshold (the last one of a label that took several), the
    measurement a cluster born this frame was born from, labels without a dot or frame."""
    from bnptrack.tracker.bnp.group_merge import _label_arrays, label_arrays, taken_measurements

    rng = np.random.default_rng(seed)
    frame = int(rng.integers(3, 6))
    labels = tuple(dict.fromkeys([f"{rng.integers(0, 7)}.{rng.integers(0, 9)}" for _ in range(30)]
                                 + ["x", "-1.2", "12", f"{frame}.4"]))
    assignments = tuple(None if rng.random() < 0.3 else labels[rng.integers(len(labels))] for _ in range(25))
    probs = tuple(rng.uniform(0.2, 1.0, len(assignments)).tolist())
    for fr in (frame, None):
        want = _label_arrays(labels, taken_measurements(assignments, probs, 0.5, labels, fr))
        got = label_arrays(labels, assignments, probs, 0.5, fr)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b, strict=True)
    assert (got[2] >= 0).any() and (got[2] < 0).any()  # both kinds present


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_oldest_members_is_the_first_smallest_birth_of_each_group(seed: int) -> None:
    from bnptrack.tracker.bnp.clusters import oldest_members

    rng = np.random.default_rng(seed)
    n = 60
    birth = rng.integers(-3, 3, n)  # many ties: the first of them in group order wins
    members = rng.permutation(n)
    sizes = rng.integers(2, 6, 20)
    sizes = sizes[np.cumsum(sizes) <= n]
    ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    members = members[:ptr[-1]].astype(np.int64)
    got = oldest_members(ptr, members, birth)
    want = [min(members[a:b].tolist(), key=lambda k: birth[k]) for a, b in zip(ptr[:-1], ptr[1:])]
    assert got.tolist() == want
    # hand-built: groups [4, 2, 7] (births 1, 0, 0) and [1, 3] (births 5, 5)
    birth = np.array([9, 5, 0, 5, 1, 9, 9, 0])
    got = oldest_members(np.array([0, 3, 5]), np.array([4, 2, 7, 1, 3]), birth)
    assert got.tolist() == [2, 1]
