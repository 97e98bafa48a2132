r"""Merging of duplicate objects that never merges two objects of one formation (two-level tracker).

The object level's :func:`tracker.bnp.clusters.merge_duplicates` merges clusters whose states are
close and whose existences sum to at most 1, reading them as *one object split over exclusive
hypotheses* (a measurement shared between a young cluster and the base distribution).  Members of
a convoy (0-40 m apart, one velocity) are exactly such close pairs while they are young: a group
of four born in one scan opens four clusters of existence 0.3-0.6 each, with velocity std 30 m/s,
and the merge folds them into one or two (``groups`` seeds 101-110: 62 missed member-scans per
run among young members, 34 among old ones, against the GLMB's 44 and 11).

Two clusters are not exclusive hypotheses when they explain **different measurements of one
scan**: a point object makes at most one measurement per scan (the measurement model of eq. (11)
[likelihood]), so both may exist.  :func:`merge_exclusive` is the same greedy merge with those
pairs kept apart:

* two clusters born in the same scan (labels ``"<frame>.<m>"``) from different measurements;
* two clusters that this scan took different measurements (the estimate's MAP assignment with
  probability at least ``min_prob``, or the measurement a cluster born this scan was born from).

Every other pair merges by the usual rule (squared Mahalanobis distance at most ``max_d2`` on position
and velocity, summed covariances; existences summing to at most 1).  The pairs that may pass
are found by one compiled pass (:func:`exclusive_pairs`: :func:`exclusive_candidates`' bound, a
necessary condition; the exclusion; the exact test by :func:`pair_status` wherever its outcome
cannot differ from numpy's batched solve, which decides the rest).
The result is the all-pairs numpy code's, bit for bit (``tests/tracker/test_group_kernels.py``).
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from operator import itemgetter

import numpy as np

from bnptrack.tracker.numerics import argsort_stable, jit
from bnptrack.tracker.bnp.clusters import _apply_groups, _Clusters, _near_pairs, oldest_members

#: Up to this many clusters :func:`tracker.bnp.clusters._near_pairs` returns every pair.
_ALL_PAIRS = 200


@lru_cache(maxsize=8192)
def birth_frame(label: str) -> int:
    """Birth frame of a cluster label ``"<frame>.<measurement>"`` (0 if it has none); remembered
    (a label lives many frames and is read every frame)."""
    head, _, _ = label.partition(".")
    return int(head) if head.lstrip("-").isdigit() else 0


def taken_measurements(assignments, probs, min_prob: float, labels: tuple[str, ...] = (), frame: int | None = None
                       ) -> dict[str, int]:
    """Label -> the measurement it took this scan: the MAP assignment with probability >=
    ``min_prob``, and for each of ``labels`` born at ``frame`` (``"<frame>.<m>"``) its measurement ``m``."""
    taken = {lab: m for m, (lab, p) in enumerate(zip(assignments, probs)) if lab is not None and p >= min_prob}
    prefix = f"{frame}."
    for lab in labels:
        if frame is not None and lab.startswith(prefix):
            taken.setdefault(lab, int(lab[len(prefix):]))
    return taken


@lru_cache(maxsize=8192)
def _label_parts(label: str) -> tuple[int, bool, str, int | None]:
    """:func:`birth_frame`, whether the label has a ``"."``, its text before the first ``"."`` and
    the integer after it (None if that text is not one; remembered)."""
    head, dot, tail = label.partition(".")
    try:
        number = int(tail) if dot else None
    except ValueError:
        number = None
    return birth_frame(label), dot == ".", head, number


def label_arrays(labels: tuple[str, ...], assignments, probs, min_prob: float, frame: int | None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_label_arrays` of :func:`taken_measurements`' dict, without building it: each label's
    birth frame, whether dotted, and the measurement it took (the MAP assignment with probability
    >= ``min_prob``, the last one if several; else, born at ``frame``, the measurement it was born
    from; else -1).  The labels' parts are remembered (:func:`_label_parts`); only the labels
    without a taken measurement are looked at one by one."""
    taken = {lab: m for m, (lab, p) in enumerate(zip(assignments, probs)) if lab is not None and p >= min_prob}
    parts = list(map(_label_parts, labels))
    n = len(parts)
    birth = np.fromiter(map(itemgetter(0), parts), dtype=np.int64, count=n)
    dotted = np.fromiter(map(itemgetter(1), parts), dtype=bool, count=n)
    took = list(map(taken.get, labels))
    head_now = None if frame is None else str(frame)
    for k in [k for k, m in enumerate(took) if m is None]:
        _, dot, head, number = parts[k]
        if dot and head == head_now:
            took[k] = number if number is not None else int(labels[k].partition(".")[2])  # a non-numeric index raises
        else:
            took[k] = -1
    return birth, dotted, np.array(took, dtype=np.int64).reshape(n)


def _distinct(labels: tuple[str, ...], taken: dict[str, int], i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Pairs ``(i, j)`` that explain different measurements of one scan (never one object)."""
    out = np.zeros(i.size, dtype=bool)
    for k, (a, b) in enumerate(zip(i.tolist(), j.tolist())):
        la, lb = labels[a], labels[b]
        same_scan = birth_frame(la) == birth_frame(lb) and "." in la and "." in lb
        ma, mb = taken.get(la), taken.get(lb)
        out[k] = same_scan or (ma is not None and mb is not None and ma != mb)
    return out


#: Relative slack of :func:`exclusive_candidates`' bound (it only has to keep every pair that passes).
_BOUND_SLACK = 1.0 + 1e-6


def _within_bound(mean: np.ndarray, cov: np.ndarray, r: np.ndarray, i: int, j: int, max_d2: float
                  ) -> bool:  # pragma: no cover - compiled
    r"""Whether the pair ``(i, j)`` passes :func:`exclusive_candidates`' bound: existences summing
    to at most 1 and :math:`\lVert d\rVert^2 \le` ``max_d2`` :math:`\mathrm{tr}\,S` (with the slack)."""
    if not r[i] + r[j] <= 1.0:
        return False
    dd = 0.0
    tr = 0.0
    for k in range(4):
        x = mean[i, k] - mean[j, k]
        dd += x * x
        tr += cov[i, k, k] + cov[j, k, k]
    return dd <= max_d2 * tr * _BOUND_SLACK


_within_bound = jit(_within_bound, inline=True)


def exclusive_candidates(mean: np.ndarray, cov: np.ndarray, r: np.ndarray, max_d2: float
                         ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    r"""Pairs ``i < j`` (in ``np.triu_indices`` order) with ``r[i] + r[j] <= 1`` and
    ``|d|^2 <= max_d2 tr(S) (1 + 1e-6)``, ``d`` the difference of the first four state entries
    (position and velocity) and ``S`` the sum of their covariances: a superset of the pairs
    within squared Mahalanobis distance ``max_d2``, since :math:`d^\top S^{-1} d \ge
    \lVert d\rVert^2 / \lambda_{max}(S) \ge \lVert d\rVert^2 / \mathrm{tr}\,S` (S positive definite).
    Only comparisons and products here: the exact distances stay numpy's."""
    n = mean.shape[0]
    ii = np.empty(n * (n - 1) // 2, dtype=np.int64)
    jj = np.empty(n * (n - 1) // 2, dtype=np.int64)
    count = 0
    for i in range(n):
        for j in range(i + 1, n):
            if _within_bound(mean, cov, r, i, j, max_d2):
                ii[count] = i
                jj[count] = j
                count += 1
    return ii[:count], jj[:count]


def pair_differences(mean: np.ndarray, cov: np.ndarray, ii: np.ndarray, jj: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """``mean[ii] - mean[jj]`` and ``cov[ii] + cov[jj]`` on position and velocity (the first four
    entries): ``(P, 4)``, ``(P, 4, 4)``."""
    diff = np.empty((ii.size, 4))
    S = np.empty((ii.size, 4, 4))
    for p in range(ii.size):
        i, j = ii[p], jj[p]
        for a in range(4):
            diff[p, a] = mean[i, a] - mean[j, a]
            for b in range(4):
                S[p, a, b] = cov[i, a, b] + cov[j, a, b]
    return diff, S


#: Relative margin of :func:`exact_status`' decision: a pair nearer the threshold than this (or
#: whose covariance is ill-conditioned) is decided by numpy's batched solve.
_DECIDE_MARGIN = 1e-6
#: Largest bound on cond(S) for which the compiled distance decides (its relative error and
#: numpy's, about 4 cond(S) 1e-16 each, stay far inside :data:`_DECIDE_MARGIN`).
_MAX_COND = 1e7


def pair_status(mean: np.ndarray, cov: np.ndarray, i: int, j: int, max_d2: float, S: np.ndarray, L: np.ndarray,
                Li: np.ndarray, y: np.ndarray) -> int:  # pragma: no cover - compiled
    r"""The exact test of pair ``(i, j)``, decided where it is safe: 1 if
    :math:`d^\top S^{-1} d \le` ``max_d2``, 0 if not, 2 if numpy must decide (``S``, ``L``,
    ``Li`` (4, 4) and ``y`` (4,) are scratch).

    ``d``, ``S`` as :func:`pair_differences`; :math:`d^\top S^{-1} d = \lVert L^{-1} d\rVert^2`
    with ``S = L L'`` (Cholesky).  The value differs from numpy's (``np.linalg.solve`` then
    ``np.einsum``) in its last bits only: both are backward stable, and for positive definite
    ``S`` the relative error of the quadratic form is a small multiple (<= 100 at 4x4) of
    :math:`\mathrm{cond}(S)\,\epsilon` (not its square, since :math:`x^\top S x \ge
    \lambda_{min} \lVert x\rVert^2`), at most about 1e-7 here; so a pair is decided here only when
    its distance is farther than :data:`_DECIDE_MARGIN` (relative) from ``max_d2`` and
    :math:`\mathrm{cond}(S) \le \mathrm{tr}(S)\,\lVert L^{-1}\rVert_F^2 \le` :data:`_MAX_COND`:
    then numpy's comparison has the same outcome.  Not positive definite, or not finite: 2."""
    tr = 0.0
    for a in range(4):
        for b in range(4):
            S[a, b] = cov[i, a, b] + cov[j, a, b]
        tr += S[a, a]
    for a in range(4):  # Cholesky S = L L'
        for b in range(a + 1):
            acc = S[a, b]
            for k in range(b):
                acc -= L[a, k] * L[b, k]
            if a != b:
                L[a, b] = acc / L[b, b]
            elif acc > 0.0:
                L[a, a] = np.sqrt(acc)
            else:
                return 2
    fro = 0.0
    for b in range(4):  # L^-1 column by column (forward substitution), its Frobenius norm
        for a in range(4):
            acc = 1.0 if a == b else 0.0
            for k in range(a):
                acc -= L[a, k] * Li[k, b]
            Li[a, b] = acc / L[a, a]
            fro += Li[a, b] * Li[a, b]
    d2 = 0.0
    for a in range(4):  # y = L^-1 d
        acc = mean[i, a] - mean[j, a]
        for k in range(a):
            acc -= L[a, k] * y[k]
        y[a] = acc / L[a, a]
        d2 += y[a] * y[a]
    if not tr * fro <= _MAX_COND:
        return 2
    if d2 <= max_d2 * (1.0 - _DECIDE_MARGIN):
        return 1
    if d2 > max_d2 * (1.0 + _DECIDE_MARGIN):
        return 0
    return 2


def exact_status(mean: np.ndarray, cov: np.ndarray, ii: np.ndarray, jj: np.ndarray, max_d2: float
                 ) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`pair_status` of the pairs ``(ii, jj)`` (int8: 1 pass, 0 fail, 2 numpy decides)."""
    out = np.empty(ii.size, dtype=np.int8)
    S, L, Li, y = np.empty((4, 4)), np.zeros((4, 4)), np.zeros((4, 4)), np.empty(4)
    for p in range(ii.size):
        out[p] = pair_status(mean, cov, ii[p], jj[p], max_d2, S, L, Li, y)
    return out


def exclusive_pairs(mean: np.ndarray, cov: np.ndarray, r: np.ndarray, max_d2: float, birth: np.ndarray,
                    dotted: np.ndarray, taken: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`exclusive_candidates`' pairs (same bound, same order) that are not
    :func:`distinct_pairs` and that :func:`pair_status` does not reject: ``ii``, ``jj`` and
    their status (1: within ``max_d2``; 2: numpy decides)."""
    n = mean.shape[0]
    ii = np.empty(n * (n - 1) // 2, dtype=np.int64)
    jj = np.empty(n * (n - 1) // 2, dtype=np.int64)
    status = np.empty(n * (n - 1) // 2, dtype=np.int8)
    S, L, Li, y = np.empty((4, 4)), np.zeros((4, 4)), np.zeros((4, 4)), np.empty(4)
    count = 0
    for i in range(n):
        for j in range(i + 1, n):
            if not _within_bound(mean, cov, r, i, j, max_d2):
                continue
            same_scan = birth[i] == birth[j] and dotted[i] and dotted[j]
            if same_scan or (taken[i] >= 0 and taken[j] >= 0 and taken[i] != taken[j]):
                continue
            st = pair_status(mean, cov, i, j, max_d2, S, L, Li, y)
            if st != 0:
                ii[count], jj[count], status[count] = i, j, st
                count += 1
    return ii[:count], jj[:count], status[:count]


def distinct_pairs(birth: np.ndarray, dotted: np.ndarray, taken: np.ndarray, ii: np.ndarray, jj: np.ndarray
                   ) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`_distinct` on arrays: ``birth`` (N,) each label's :func:`birth_frame`, ``dotted``
    (N,) whether it has a ``"."``, ``taken`` (N,) the measurement it took this scan (-1: none)."""
    out = np.empty(ii.size, dtype=np.bool_)
    for p in range(ii.size):
        a, b = ii[p], jj[p]
        same_scan = birth[a] == birth[b] and dotted[a] and dotted[b]
        out[p] = same_scan or (taken[a] >= 0 and taken[b] >= 0 and taken[a] != taken[b])
    return out


exclusive_candidates = jit(exclusive_candidates)
pair_differences = jit(pair_differences)
pair_status = jit(pair_status, kernels_only=True)
exact_status = jit(exact_status)
exclusive_pairs = jit(exclusive_pairs)
distinct_pairs = jit(distinct_pairs)


def _label_arrays(labels: tuple[str, ...], taken: dict[str, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`distinct_pairs`' inputs: birth frames, whether dotted, taken measurement (-1: none)."""
    rows = np.array([(birth_frame(lab), "." in lab, taken.get(lab, -1)) for lab in labels], dtype=np.int64)
    rows = rows.reshape(len(labels), 3)
    return rows[:, 0].copy(), rows[:, 1] != 0, rows[:, 2].copy()


def _candidate_pairs(c: _Clusters, max_d2: float, taken: dict[str, int] | None,
                     arrays: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pairs close enough to merge, whose existences sum to at most 1, that may be one object.

    With few clusters (every pair a candidate of :func:`tracker.bnp.clusters._near_pairs`) one
    compiled pass (:func:`exclusive_pairs`) applies :func:`exclusive_candidates`' bound, the
    exclusion (:func:`distinct_pairs`) and the exact test (:func:`pair_status`); with many, the
    KD-tree's pairs go through the same tests.  Pairs the compiled test leaves undecided take
    numpy's (a batched solve, each pair on its own).  ``arrays``: the labels'
    :func:`label_arrays` (then ``taken`` is not read)."""
    r = c.existence
    birth, dotted, took = _label_arrays(c.labels, taken) if arrays is None else arrays
    if len(c.labels) <= _ALL_PAIRS:  # bound, exclusion and the exact test in one compiled pass
        ii, jj, status = exclusive_pairs(c.mean, c.cov, r, float(max_d2), birth, dotted, took)
    else:
        ii, jj = _near_pairs(c, max_d2, exclusive=True)  # existences summing to at most 1
        keep = ~distinct_pairs(birth, dotted, took, ii, jj)
        ii, jj = ii[keep], jj[keep]
        status = exact_status(c.mean, c.cov, ii, jj, float(max_d2))
    unsure = np.flatnonzero(status == 2)
    if unsure.size:  # near the threshold or ill-conditioned: numpy's test
        diff, S = pair_differences(c.mean, c.cov, ii[unsure], jj[unsure])  # _POS_VEL = [0, 1, 2, 3]
        d2 = np.einsum("pk,pk->p", diff, np.linalg.solve(S, diff[..., None])[..., 0])
        status[unsure] = d2 <= max_d2
    passed = status == 1
    return ii[passed], jj[passed]


def merge_exclusive(c: _Clusters, max_d2: float, taken: dict[str, int] | None,
                    arrays: tuple | None = None, reported: float | None = None) -> tuple[_Clusters, dict[str, str]]:
    """Greedy merge (leaders in order of decreasing existence, as ``merge_duplicates``) of the
    candidate pairs; a cluster joins a leader's group only if it may be one object with every
    member already in it.  Returns the clusters and the label each absorbed label now goes by.
    The measurements the labels took: ``taken`` (:func:`taken_measurements`) or, given,
    ``arrays`` (:func:`label_arrays` of ``c.labels``).  A merged group keeps its oldest member's
    label; with ``reported`` (the reporting threshold), its oldest member's among those whose
    existence is above it, when there are any (:func:`merged_label`)."""
    n = len(c.labels)
    if max_d2 <= 0.0 or n < 2:
        return c, {}
    ii, jj = _candidate_pairs(c, max_d2, taken, arrays)
    if ii.size == 0:
        return c, {}
    ptr, members = greedy_groups(ii, jj, c.existence, np.argsort(-c.existence, kind="stable"))
    if ptr.size == 1:
        return c, {}
    birth = arrays[0] if arrays is not None else np.fromiter(map(birth_frame, c.labels), dtype=np.int64, count=n)
    first = oldest_members(ptr, members, birth)  # each group's oldest member (min by birth_frame)
    renamed, moved = {}, {}
    labels = c.labels
    for a, b, k in zip(ptr[:-1].tolist(), ptr[1:].tolist(), first.tolist()):
        group = members[a:b].tolist()
        oldest = labels[k]
        final = oldest if reported is None else merged_label(labels, c.existence, group, reported)
        if final != oldest:
            moved[oldest] = final
        renamed.update({labels[k]: final for k in group if labels[k] != final})
    merged = _apply_groups(c, ptr, members, first)  # each group under its oldest member's label
    if moved:
        merged = replace(merged, labels=tuple(moved.get(lab, lab) for lab in merged.labels))
    return merged, renamed


def merged_label(labels: tuple[str, ...], existence: np.ndarray, group: list[int], reported: float) -> str:
    """The label a merged ``group`` (rows of ``labels``) keeps: its oldest member's among those
    with existence above ``reported``, else its oldest member's.  A hypothesis too weak to be
    reported (a track fading after its object was lost, a stray cluster) does not rename a
    reported track it is merged into; a newborn duplicate still never renames an older track."""
    seen = [labels[k] for k in group if existence[k] > reported]
    return min(seen or [labels[k] for k in group], key=birth_frame)


def greedy_groups(ii: np.ndarray, jj: np.ndarray, r: np.ndarray, order: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`merge_exclusive`'s greedy grouping of the candidate pairs ``(ii, jj)``: leaders in
    ``order`` (decreasing existence ``r``, stable) among the clusters of a pair; each takes, in the
    same order, its free partners whose existence keeps the group's sum (added in that order) at
    most 1 and that are candidates with every member already in.  Groups of two or more in CSR
    form: ``members[ptr[g]:ptr[g + 1]]``, leader first.

    O(pairs): each cluster's partners in ``order`` (CSR); a partner is a candidate with every
    member when its count of members it pairs with equals the group's size (a dense
    (n, n) table would be O(n^2) in time and memory)."""
    n = r.size
    rank = np.empty(n, dtype=np.int64)
    for k in range(n):
        rank[order[k]] = k
    adj_ptr, adj = _partners_by_rank(ii, jj, rank, n)
    free = np.ones(n, dtype=np.bool_)
    hits = np.zeros(n, dtype=np.int64)  # members of the current group each cluster pairs with
    ptr = np.zeros(n + 1, dtype=np.int64)
    members = np.empty(n, dtype=np.int64)
    group = np.empty(n, dtype=np.int64)
    n_groups, used = 0, 0
    for i in order:
        if adj_ptr[i] == adj_ptr[i + 1] or not free[i]:
            continue
        group[0], size, total = i, 1, r[i]
        for k in range(adj_ptr[i], adj_ptr[i + 1]):
            hits[adj[k]] += 1
        for k in range(adj_ptr[i], adj_ptr[i + 1]):
            j = adj[k]
            if not free[j] or not total + r[j] <= 1.0 or hits[j] != size:
                continue
            group[size] = j
            size += 1
            total += r[j]
            for q in range(adj_ptr[j], adj_ptr[j + 1]):
                hits[adj[q]] += 1
        for m in range(size):
            free[group[m]] = False
            for q in range(adj_ptr[group[m]], adj_ptr[group[m] + 1]):
                hits[adj[q]] = 0
        if size > 1:
            for m in range(size):  # not a slice assignment: that compiles numba's string code
                members[used + m] = group[m]
            used += size
            n_groups += 1
            ptr[n_groups] = used
    return ptr[:n_groups + 1], members[:used]


def _partners_by_rank(ii, jj, rank, n):  # pragma: no cover - compiled
    """Each cluster's distinct partners among the pairs ``(ii, jj)``, in increasing ``rank``
    (CSR: ``adj[ptr[i]:ptr[i + 1]]``)."""
    deg = np.zeros(n + 1, dtype=np.int64)
    for k in range(ii.size):
        deg[ii[k] + 1] += 1
        deg[jj[k] + 1] += 1
    ptr = np.cumsum(deg)
    fill = ptr[:-1].copy()
    adj = np.empty(ptr[-1], dtype=np.int64)
    for k in range(ii.size):
        adj[fill[ii[k]]] = jj[k]
        fill[ii[k]] += 1
        adj[fill[jj[k]]] = ii[k]
        fill[jj[k]] += 1
    out = np.empty(ptr[-1], dtype=np.int64)
    optr = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        seg = adj[ptr[i]:ptr[i + 1]]
        keys = np.empty(seg.size, dtype=np.int64)
        for k in range(seg.size):
            keys[k] = rank[seg[k]]
        srt = argsort_stable(keys)  # ties are one partner: any order of them gives the same out
        m = optr[i]
        for k in range(seg.size):
            j = seg[srt[k]]
            if j != i and (k == 0 or keys[srt[k]] != keys[srt[k - 1]]):
                out[m] = j
                m += 1
        optr[i + 1] = m
    return optr, out


_partners_by_rank = jit(_partners_by_rank, kernels_only=True)
greedy_groups = jit(greedy_groups)
