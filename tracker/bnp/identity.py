r"""Identities through crossings: a multi-scan check of the label of two tracks that met
(``GroupConfig.crossing_scans``, off by default; docs/trackers.md, "Identities through crossings").

The one-scan association of the object level (eqs. (11), (13)-(14)) decides at the crossing
scan which track takes which measurement, from one scan of data and from predictions that the
velocity sharing (eq. (2)) may have pulled together.  Two to four scans later the data tell
the two objects apart.  Each object keeps, over the last ``W`` scans (a ring), its own
(sharing-free) posterior and the measurement information the object level's update gave it
in each scan, in information form:

.. math::

    \Lambda_t = [P_t^{-1} - P_{s,t}^{-1}]_+, \qquad
    \eta_t = P_t^{-1}(m_t - m_{s,t}) + \Lambda_t m_{s,t},

with :math:`(m_{s,t}, P_{s,t})` the prediction the object level updated and :math:`(m_t, P_t)`
its posterior (for a linear(ised) measurement :math:`\Lambda = H^T R^{-1} H`,
:math:`\eta = H^T R^{-1} \tilde z`: a pseudo-measurement that applies to any prior).

For two tracks whose own positions pass their closest approach ``after`` scans before the
newest scan (inside a chi-square gate), the check filters both tracks from their own
posteriors at the ring's oldest scan through the scans since, once with their own
measurement information (keep) and once for each swap point with each other's from that scan
on (swap), and sums the log evidence
:math:`\log \mathcal N(\tilde z; H m, H P H^T + R)` of every scan; the terms of one measurement
that do not depend on the prior are the same in every hypothesis (each measurement is used
once per hypothesis) and are left out:

.. math::

    \ell = -\tfrac12\left(m^T P^{-1} m - m'^T P'^{-1} m'\right)
           + \tfrac12 \log\frac{|P'|}{|P|},
    \qquad P'^{-1} = P^{-1} + \Lambda, \quad P'^{-1} m' = P^{-1} m + \eta.

The labels are exchanged from the newest scan on when the best swap beats keeping by more than
``margin`` nats.  This is N-scan (track-oriented MHT) pruning restricted to the two-track
hypotheses of a crossing, run after the one-scan step; elsewhere the one-scan step stands.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from bnptrack.tracker.bnp.group_config import GroupConfig
from bnptrack.tracker.bnp.group_state import GroupState
from bnptrack.tracker.types import Estimate

__all__ = ["Ring", "measurement_information", "advance", "crossing_swaps", "check_labels"]

#: Chi-square gate (99.9 %, two dimensions) of two tracks' positions at their closest approach.
GATE = 13.8
#: Scans beyond the ring that two members of one cluster must have sat with another object
#: (``GroupState.together``) to count as a convoy the check leaves alone.
SETTLED_SCANS = 4


@dataclass(frozen=True)
class Ring:
    """The last ``W`` scans (oldest first) of every object (rows as the tracker state's).

    ``frames``/``stamps`` (W,): the scans (-1: empty); ``mean`` (N, W, 5), ``cov``
    (N, W, 5, 5): each object's own posterior (zeros where absent); ``lam`` (N, W, 5, 5),
    ``eta`` (N, W, 5): the measurement information of each scan; ``swapped`` (N,): the last
    scan the object's label was exchanged (-1: never); ``cluster`` (N, W): its motion cluster
    (-1: none, or absent)."""

    frames: np.ndarray
    stamps: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    lam: np.ndarray
    eta: np.ndarray
    swapped: np.ndarray
    cluster: np.ndarray


def measurement_information(m_s: np.ndarray, P_s: np.ndarray, m: np.ndarray, P: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
    r"""``(Lambda, eta)`` of the updates from the predictions ``(m_s, P_s)`` to the posteriors
    ``(m, P)`` (``(K, n)``, ``(K, n, n)``): :math:`\Lambda = [P^{-1} - P_s^{-1}]_+` (negative
    eigenvalues, a missed-detection branch widening :math:`P`, set to 0) and
    :math:`\eta = P^{-1}(m - m_s) + \Lambda m_s`."""
    if m.shape[0] == 0:
        return np.zeros_like(P), np.zeros_like(m)
    J = np.linalg.inv(P)
    D = J - np.linalg.inv(P_s)
    w, V = np.linalg.eigh(0.5 * (D + np.swapaxes(D, 1, 2)))
    lam = (V * np.maximum(w, 0.0)[:, None, :]) @ np.swapaxes(V, 1, 2)
    eta = np.einsum("kij,kj->ki", J, m - m_s) + np.einsum("kij,kj->ki", lam, m_s)
    return lam, eta


def empty_ring(W: int, n: int = 5) -> Ring:
    return Ring(np.full(W, -1, dtype=np.int64), np.zeros(W, dtype=np.int64), np.zeros((0, W, n)),
                np.zeros((0, W, n, n)), np.zeros((0, W, n, n)), np.zeros((0, W, n)), np.zeros(0, dtype=np.int64),
                np.zeros((0, W), dtype=np.int64))


def advance(ring: Ring, src: np.ndarray, frame: int, stamp_ns: int, own: tuple[np.ndarray, np.ndarray],
            info: tuple[np.ndarray, np.ndarray], cluster: np.ndarray) -> Ring:
    """The ring one scan on: each object's row from its previous row ``src`` (-1: new), shifted by
    one scan, with this scan's own posterior ``own``, measurement information ``info`` and motion
    cluster ``cluster`` (N,)."""
    N, n = own[0].shape
    W = ring.frames.size
    have = src >= 0
    mean = np.zeros((N, W, n))
    cov = np.zeros((N, W, n, n))
    lam, eta = np.zeros((N, W, n, n)), np.zeros((N, W, n))
    swapped = np.full(N, -1, dtype=np.int64)
    clusters = np.full((N, W), -1, dtype=np.int64)
    if ring.mean.shape[0] and have.any():
        rows = src[have]
        mean[have, :-1], cov[have, :-1] = ring.mean[rows, 1:], ring.cov[rows, 1:]
        lam[have, :-1], eta[have, :-1] = ring.lam[rows, 1:], ring.eta[rows, 1:]
        swapped[have] = ring.swapped[rows]
        clusters[have, :-1] = ring.cluster[rows, 1:]
    mean[:, -1], cov[:, -1] = own
    lam[:, -1], eta[:, -1] = info
    clusters[:, -1] = cluster
    frames = np.append(ring.frames[1:], frame)
    stamps = np.append(ring.stamps[1:], stamp_ns)
    return Ring(frames, stamps, mean, cov, lam, eta, swapped, clusters)


def _log_evidence(m, P, lam, eta):
    """One information update of the rows ``(m, P)``; returns the posterior and the log evidence
    terms that depend on the prior (module docstring)."""
    Pi = np.linalg.inv(P)
    J = Pi + lam
    h = np.einsum("kij,kj->ki", Pi, m) + eta
    P1 = np.linalg.inv(J)
    P1 = 0.5 * (P1 + np.swapaxes(P1, 1, 2))
    m1 = np.einsum("kij,kj->ki", P1, h)
    quad = np.einsum("ki,ki->k", m, np.einsum("kij,kj->ki", Pi, m)) - np.einsum("ki,ki->k", m1, h)
    ld = np.linalg.slogdet(P1)[1] - np.linalg.slogdet(P)[1]
    return m1, P1, -0.5 * quad + 0.5 * ld


def _hypotheses(W: int, approach: int) -> np.ndarray:
    """(H, W) bool: for each hypothesis, the scans at which the two tracks' measurements are
    exchanged: none (keep), then from each scan ``approach .. W - 1`` on."""
    rows = [np.zeros(W, dtype=bool)]
    for s in range(max(approach, 1), W):
        r = np.zeros(W, dtype=bool)
        r[s:] = True
        rows.append(r)
    return np.array(rows)


def pair_evidence(ring: Ring, pairs: list[tuple[int, int]], approach: int, predict) -> np.ndarray:
    """Log evidence (len(pairs), H) of each hypothesis of :func:`_hypotheses` for each pair of
    objects ``(a, b)``: both filtered from their own posteriors at the ring's oldest scan, all
    pairs and hypotheses in one batch per scan; ``predict(m, P, dt)`` the object level's."""
    W = ring.frames.size
    hyp = _hypotheses(W, approach)
    H, K = hyp.shape[0], len(pairs)
    ab = np.array(pairs, dtype=np.int64).reshape(K, 2)
    own = np.repeat(ab, H, axis=0)  # (K H, 2): row (k, h) -> (a, b)
    first = np.concatenate([own[:, 0], own[:, 1]])  # track a's rows, then track b's
    m, P = ring.mean[first, 0], ring.cov[first, 0]
    total = np.zeros(2 * K * H)
    for t in range(1, W):
        dt = (ring.stamps[t] - ring.stamps[t - 1]) * 1e-9
        m, P = predict(m, P, dt)
        ex = np.tile(hyp[:, t], K)
        src = np.concatenate([np.where(ex, own[:, 1], own[:, 0]), np.where(ex, own[:, 0], own[:, 1])])
        m, P, ll = _log_evidence(m, P, ring.lam[src, t], ring.eta[src, t])
        total += ll
    return (total[:K * H] + total[K * H:]).reshape(K, H)


def _closest_pairs(ring: Ring, approach: int, gate: float, settled: np.ndarray) -> list[tuple[int, int]]:
    """Pairs present over the whole ring whose own positions are closest at scan ``approach``
    (no closer at the scans beside it) and inside the chi-square ``gate`` there, except two
    ``settled`` objects (N,) that sat in one motion cluster at every scan of the ring: members
    of one convoy, which move together and do not cross."""
    full = (ring.cov[:, :, 0, 0] > 0.0).all(axis=1)
    idx = np.flatnonzero(full)
    if idx.size < 2:
        return []
    pos = ring.mean[idx][:, :, [0, 2]]  # (K, W, 2)
    S = ring.cov[idx][:, approach][:, [0, 2]][:, :, [0, 2]]
    D = pos[:, None] - pos[None]  # (K, K, W, 2)
    dist = np.linalg.norm(D, axis=-1)
    d_app = D[:, :, approach]
    d2 = np.einsum("abi,abij,abj->ab", d_app, np.linalg.inv(S[:, None] + S[None]), d_app)
    near = d2 < gate
    lo, hi = max(approach - 1, 0), min(approach + 2, ring.frames.size)
    local = dist[:, :, approach] <= dist[:, :, lo:hi].min(axis=-1)
    cl = ring.cluster[idx]
    convoy = ((cl[:, None] == cl[None]) & (cl[:, None] >= 0)).all(axis=-1)
    convoy &= settled[idx][:, None] & settled[idx][None]
    ii, jj = np.nonzero(np.triu(near & local & ~convoy, 1))
    return [(int(idx[i]), int(idx[j])) for i, j in zip(ii, jj)]


def crossing_swaps(ring: Ring, after: int, gate: float, margin: float, predict,
                   settled: np.ndarray | None = None) -> list[tuple[int, int]]:
    """The object pairs (rows) whose labels the multi-scan check exchanges now (module
    docstring): closest approach ``after`` scans before the newest scan, neither exchanged
    within the ring, not two ``settled`` members of one cluster (:func:`_closest_pairs`; None:
    none settled), the best swap better than keeping by more than ``margin`` nats."""
    W = ring.frames.size
    approach = W - 1 - after
    if approach < 1 or (ring.frames < 0).any() or ring.mean.shape[0] < 2:
        return []
    oldest = ring.frames[0]
    settled = np.zeros(ring.mean.shape[0], dtype=bool) if settled is None else settled
    pairs = [(a, b) for a, b in _closest_pairs(ring, approach, gate, settled)
             if ring.swapped[a] < oldest and ring.swapped[b] < oldest]
    if not pairs:
        return []
    ev = pair_evidence(ring, pairs, approach, predict)
    gain = ev[:, 1:].max(axis=1) - ev[:, 0]
    out, used = [], set()
    for k in np.argsort(-gain):  # the clearest swaps first; an object in one swap only
        a, b = pairs[k]
        if gain[k] > margin and a not in used and b not in used:
            out.append((a, b))
            used |= {a, b}
    return out


def swapped_ring(ring: Ring, pairs: list[tuple[int, int]], frame: int) -> Ring:
    """``ring`` with the objects of ``pairs`` marked as exchanged at ``frame``."""
    if not pairs:
        return ring
    swapped = ring.swapped.copy()
    swapped[[i for p in pairs for i in p]] = frame
    return Ring(ring.frames, ring.stamps, ring.mean, ring.cov, ring.lam, ring.eta, swapped, ring.cluster)


def check_labels(state: GroupState, new: GroupState, src: np.ndarray, own: tuple[np.ndarray, np.ndarray],
                 info: tuple[np.ndarray, np.ndarray], est: Estimate, kept: list | None, config: GroupConfig,
                 predict) -> tuple[GroupState, Estimate, list]:
    """The check in the two-level tracker's step: the ring of ``state`` one scan on (rows of
    ``new``, each from its previous row ``src``; this scan's own posteriors ``own`` and measurement
    information ``info``), and the labels of the pairs it resolves as swaps exchanged from this
    scan on, in the state ``new``, the tracks ``kept`` (None: ``est``'s) and ``est``'s assignments."""
    W = config.crossing_before + 1 + config.crossing_scans
    ring = Ring(state.id_frames, state.id_stamps, state.id_mean, state.id_cov, state.id_lam, state.id_eta,
                state.id_swapped, state.id_cluster)
    if ring.frames.size != W:
        ring = empty_ring(W)
    ring = advance(ring, src, new.frame, new.stamp_ns, own, info, new.cluster)
    settled = new.together >= W + SETTLED_SCANS if new.together.size else None
    pairs = crossing_swaps(ring, config.crossing_scans, GATE, config.crossing_margin, predict, settled)
    ring = swapped_ring(ring, pairs, new.frame)
    labels = list(new.labels)
    rename = {}
    for a, b in pairs:
        rename[labels[a]], rename[labels[b]] = labels[b], labels[a]
        labels[a], labels[b] = labels[b], labels[a]
    new = replace(new, labels=tuple(labels), id_frames=ring.frames, id_stamps=ring.stamps, id_mean=ring.mean,
                  id_cov=ring.cov, id_lam=ring.lam, id_eta=ring.eta, id_swapped=ring.swapped, id_cluster=ring.cluster)
    if kept is None:
        kept = [(t.label, t.existence) for t in est.tracks]
    assignments = est.assignments
    if rename:
        kept = [(rename.get(lab, lab), r) for lab, r in kept]
        assignments = tuple(None if a is None else rename.get(a, a) for a in assignments)
    est = Estimate(est.frame, est.stamp_ns, (), assignments, est.assignment_prob,
                   dict(est.diagnostics, crossing_swaps=float(len(pairs))), est.cardinality_pmf)
    return new, est, kept
