"""Marginals of an updated GLMB and the estimators that pick the reported tracks."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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


def marginals(st: GlmbState, row_meas: np.ndarray, n_meas: int) -> _Marginals:
    r"""Label existences :math:`r(\ell) = \sum_{I \ni \ell} w(I)`, measurement use
    :math:`r_U(z) = \sum_{h \text{ uses } z} w_h` and label-measurement pair weights of an
    updated GLMB (``row_meas``: the measurement of each table row this frame, or -1)."""
    w = np.exp(st.log_w)
    hyp = st.hyp_tracks
    if st.n_tracks:
        uniq, label_id = np.unique(np.array(st.labels, dtype=object), return_inverse=True)
        n_labels = uniq.size
    else:
        n_labels, label_id = 0, np.zeros(0, dtype=np.int64)
    label_id = np.asarray(label_id, dtype=np.int64).reshape(-1)
    h_idx, slot = np.nonzero(hyp >= 0)
    rows = hyp[h_idx, slot]
    lab_of = label_id[rows]
    existence = np.bincount(lab_of, weights=w[h_idx], minlength=n_labels)
    meas_of = row_meas[rows]
    det = meas_of >= 0
    p_used = np.bincount(meas_of[det], weights=w[h_idx[det]], minlength=n_meas)
    pair_p = np.bincount(lab_of[det] * n_meas + meas_of[det], weights=w[h_idx[det]],
                         minlength=n_labels * n_meas) if n_meas else np.zeros(0)
    return _Marginals(w, h_idx, rows, label_id, n_labels, existence, p_used, pair_p)


def _map_cardinality(st: GlmbState, w: np.ndarray) -> tuple[int, np.ndarray]:
    """MAP cardinality and the cardinality of each hypothesis."""
    n = np.sum(st.hyp_tracks >= 0, axis=1)
    return int(np.argmax(np.bincount(n, weights=w))), n


def map_cardinality_rows(st: GlmbState, mg: _Marginals) -> np.ndarray:
    """Vo's ``extract_estimates``: the MAP cardinality :math:`\\hat n`, then the rows of the
    highest-weight hypothesis with :math:`\\hat n` labels."""
    n_map, n = _map_cardinality(st, mg.w)
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
    n_map, n = _map_cardinality(st, mg.w)
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
    n_map, _ = _map_cardinality(st, mg.w)
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
    tracks = tuple(
        TrackEstimate(st.labels[r], st.mean[r].copy(), st.cov[r].copy(),
                      float(min(1.0, mg.existence[mg.label_id[r]])))
        for r in rows.tolist()
    )
    M = frame.n_measurements
    assignments: list[str | None] = [None] * M
    probs = [float(np.clip(1.0 - mg.p_used[m], 0.0, 1.0)) for m in range(M)]
    for r in rows.tolist():
        m = int(row_meas[r])
        if m >= 0:
            assignments[m] = st.labels[r]
            probs[m] = float(np.clip(mg.pair_p[mg.label_id[r] * M + m], 0.0, 1.0))
    return Estimate(frame.frame, frame.stamp_ns, tracks, tuple(assignments), tuple(probs))
