"""Marginals of an updated GLMB and the estimators that pick the reported tracks."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bnptrack.tracker.numerics import jit
from bnptrack.tracker.glmb.state import GlmbState
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate


@dataclass(frozen=True)
class _Marginals:
    """Per-frame marginals of the updated GLMB (shared by the estimators and the births)."""

    w: np.ndarray  # (H,) hypothesis weights
    h_idx: np.ndarray  # (P,) hypothesis of each (hypothesis, slot) entry
    rows: np.ndarray  # (P,) its table row
    label_id: np.ndarray  # (T,) index of each row's label in the sorted distinct labels
    n_labels: int
    existence: np.ndarray  # (L,) r(l) = sum_{I contains l} w(I)
    p_used: np.ndarray  # (M,) r_U(z_m) = sum_{h uses z_m} w_h
    pair_p: np.ndarray  # (L * M,) weight of the hypotheses assigning z_m to label l
    n_per_hyp: np.ndarray  # (H,) each hypothesis's number of tracks
    card: np.ndarray  # (maxN + 1,) cardinality distribution, GlmbState.cardinality()


def _marginal_sums_kernel(hyp: np.ndarray, w: np.ndarray, label_id: np.ndarray, row_meas: np.ndarray,
                          n_labels: int, n_meas: int):  # pragma: no cover - compiled
    """The (hypothesis, slot) entries in row-major order and the weight sums of
    :func:`marginals`, each added in that order (as ``np.bincount`` adds)."""
    n = 0
    for h in range(hyp.shape[0]):
        for i in range(hyp.shape[1]):
            if hyp[h, i] >= 0:
                n += 1
    h_idx = np.empty(n, dtype=np.int64)
    rows = np.empty(n, dtype=np.int64)
    existence = np.zeros(n_labels)
    p_used = np.zeros(n_meas)
    pair_p = np.zeros(n_labels * n_meas)
    k = 0
    for h in range(hyp.shape[0]):
        for i in range(hyp.shape[1]):
            r = hyp[h, i]
            if r < 0:
                continue
            h_idx[k] = h
            rows[k] = r
            k += 1
            existence[label_id[r]] += w[h]
            m = row_meas[r]
            if m >= 0:
                p_used[m] += w[h]
                pair_p[label_id[r] * n_meas + m] += w[h]
    return h_idx, rows, existence, p_used, pair_p


_marginal_sums = jit(_marginal_sums_kernel)


def marginals(st: GlmbState, row_meas: np.ndarray, n_meas: int) -> _Marginals:
    r"""Label existences :math:`r(\ell) = \sum_{I \ni \ell} w(I)`, measurement use
    :math:`r_U(z) = \sum_{h \text{ uses } z} w_h` and label-measurement pair weights of an
    updated GLMB (``row_meas``: the measurement of each table row this frame, or -1)."""
    w = np.exp(st.log_w)
    if st.n_tracks:
        # np.unique(labels, return_inverse=True) on the strings, without an object array
        uniq = sorted(set(st.labels))
        rank = {label: i for i, label in enumerate(uniq)}
        label_id = np.fromiter(map(rank.__getitem__, st.labels), dtype=np.int64, count=len(st.labels))
        n_labels = len(uniq)
    else:
        n_labels, label_id = 0, np.zeros(0, dtype=np.int64)
    h_idx, rows, existence, p_used, pair_p = _marginal_sums(
        np.ascontiguousarray(st.hyp_tracks, dtype=np.int64), w, label_id, np.ascontiguousarray(row_meas, dtype=np.int64),
        n_labels, n_meas)
    # GlmbState.cardinality(), computed once here for the estimators and the step's output
    n = np.sum(st.hyp_tracks >= 0, axis=1)
    card = np.bincount(n, weights=w, minlength=st.hyp_tracks.shape[1] + 1)
    return _Marginals(w, h_idx, rows, label_id, n_labels, existence, p_used, pair_p, n, card)


def _map_cardinality(st: GlmbState, mg: _Marginals) -> tuple[int, np.ndarray]:
    """MAP cardinality and the cardinality of each hypothesis (the first maximum of the
    distribution: its padding beyond the largest hypothesis is 0, below the maximum)."""
    return int(np.argmax(mg.card)), mg.n_per_hyp


def map_cardinality_rows(st: GlmbState, mg: _Marginals) -> np.ndarray:
    """Vo's ``extract_estimates``: the MAP cardinality :math:`\\hat n`, then the rows of the
    highest-weight hypothesis with :math:`\\hat n` labels."""
    n_map, n = _map_cardinality(st, mg)
    best = int(np.argmax(np.where(n == n_map, st.log_w, -np.inf)))
    return st.hyp_tracks[best][st.hyp_tracks[best] >= 0].astype(np.int64)


def continuity_rows(st: GlmbState, mg: _Marginals, continues: np.ndarray, ratio: float) -> np.ndarray:
    r"""Label-consistent MAP extraction: among the hypotheses with the MAP cardinality
    :math:`\hat n` whose weight is at least ``ratio`` times the best of them, the one whose
    rows continue the most of the rows the previous estimate reported (``continues`` (T,):
    the row's parent was reported), ties broken by weight.  With ``ratio = 1`` this is
    :func:`map_cardinality_rows`; below 1 the estimate keeps following its own association
    histories (and so its labels) unless another labelling is more than ``1 / ratio`` times
    as likely -- a streaming, hysteresis form of Vo's track-based extraction.  The reported
    set is always one hypothesis (no two labels on one object)."""
    n_map, n = _map_cardinality(st, mg)
    log_w = np.where(n == n_map, st.log_w, -np.inf)
    cand = np.flatnonzero(log_w >= np.max(log_w) + math.log(ratio))
    hyp = st.hyp_tracks[cand]
    cont = np.sum((hyp >= 0) & continues[np.maximum(hyp, 0)], axis=1)
    h = cand[np.lexsort((-st.log_w[cand], -cont))[0]]
    return st.hyp_tracks[h][st.hyp_tracks[h] >= 0].astype(np.int64)


def marginal_label_rows(st: GlmbState, mg: _Marginals, continues: np.ndarray, ratio: float) -> np.ndarray:
    r"""Label-marginal extraction: the MAP cardinality :math:`\hat n`, then the :math:`\hat n`
    labels with the largest existence :math:`r(\ell)` (ties: label order); each label's state
    is one of its rows (association histories): the row with the largest weight
    :math:`\sum_{h \ni \text{row}} w_h`, except that a row continuing the row the previous
    estimate reported for the label (``continues`` (T,)) is preferred if its weight is at least
    ``ratio`` times that.  Per-label choices: two labels can report the same object when the
    posterior is split between labellings.  Returns the rows, one per label."""
    n_map, _ = _map_cardinality(st, mg)
    if n_map == 0:
        return np.zeros(0, dtype=np.int64)
    chosen = np.zeros(mg.n_labels, dtype=bool)
    chosen[np.argsort(-mg.existence, kind="stable")[:n_map]] = True
    row_w = np.bincount(mg.rows, weights=mg.w[mg.h_idx], minlength=st.n_tracks)
    top = np.zeros(mg.n_labels)
    np.maximum.at(top, mg.label_id, row_w)
    keep = continues & (row_w >= ratio * top[mg.label_id])
    score = row_w + 2.0 * keep  # row weights are <= 1: continuing rows first
    order = np.lexsort((-score, mg.label_id))
    first = np.concatenate([[True], mg.label_id[order][1:] != mg.label_id[order][:-1]])
    best = order[first]  # one row per label, in label order
    return np.sort(best[chosen[mg.label_id[best]]]).astype(np.int64)


def estimate_from_rows(st: GlmbState, row_meas: np.ndarray, mg: _Marginals, frame: Frame,
                       rows: np.ndarray) -> Estimate:
    """The estimate made of the table rows ``rows`` (one per label): their Gaussians, the
    labels' marginal existence, and as ``assignments`` the measurements those rows used
    (with the pair's posterior probability; other measurements: ``None`` with the clutter
    probability :math:`1 - r_U(z)`)."""
    # each track's mean and covariance: a row of one copy of the rows (never the state's)
    exist = np.fmin(mg.existence[mg.label_id[rows]], 1.0).tolist()  # min(1.0, r) of each row (NaN: 1.0 too)
    tracks = tuple(TrackEstimate(st.labels[r], m, P, e)
                   for r, m, P, e in zip(rows.tolist(), st.mean[rows], st.cov[rows], exist))
    M = frame.n_measurements
    assignments: list[str | None] = [None] * M
    probs = np.clip(1.0 - mg.p_used[:M], 0.0, 1.0).tolist()
    for r in rows.tolist():
        m = int(row_meas[r])
        if m >= 0:
            assignments[m] = st.labels[r]
            probs[m] = min(1.0, max(0.0, float(mg.pair_p[mg.label_id[r] * M + m])))
    return Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assignments), tuple(probs))
