"""Label keeping through crossings (:func:`crossing_label_keeping`): do both objects of a
crossing pair keep their track labels?"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from bnptrack.sinks.metric_checks import LabelledScan, check_labelled_run, check_positive, optimal_assignment

__all__ = ["CrossingPairResult", "CrossingResult", "crossing_label_keeping"]


@dataclass(frozen=True, slots=True)
class CrossingPairResult:
    """Label keeping of one crossing pair ``(id_a, id_b)`` crossing at ``scan``.

    ``before``/``after`` are the scans checked; ``labels_before``/``labels_after`` the track
    labels assigned to ``(id_a, id_b)`` there (``None``: unassigned).  ``kept`` when all four
    exist and each object has the same label before and after.
    """

    id_a: Hashable
    id_b: Hashable
    scan: int
    before: int
    after: int
    labels_before: tuple[Hashable | None, Hashable | None]
    labels_after: tuple[Hashable | None, Hashable | None]
    kept: bool


@dataclass(frozen=True, slots=True)
class CrossingResult:
    """Fraction of crossing pairs that kept both labels (``nan`` without pairs) and each pair."""

    fraction_kept: float
    pairs: tuple[CrossingPairResult, ...]


def _assigned_labels(truth: dict, est: dict, gate: float) -> dict:
    """Object id -> track label by optimal assignment of positions; pairs at distance
    ``>= gate`` stay unassigned (as ``benchmarks/accuracy.py``'s label-switch count)."""
    if not truth or not est:
        return {}
    ids, labels = list(truth), list(est)
    X = np.array([truth[i] for i in ids], dtype=float)
    Y = np.array([est[j] for j in labels], dtype=float)
    D = np.linalg.norm(X[:, None, :] - Y[None, :, :], axis=2)
    rows, cols = optimal_assignment(np.minimum(D, gate))
    return {ids[r]: labels[c] for r, c in zip(rows, cols) if D[r, c] < gate}


def _presence(true: list[dict], obj: Hashable, first_scan: int) -> tuple[int, int]:
    scans = [first_scan + k for k, scan in enumerate(true) if obj in scan]
    if not scans:
        raise ValueError(f"crossing object {obj!r} is never present in the truth")
    return scans[0], scans[-1]


def crossing_label_keeping(
    true_tracks: Sequence[LabelledScan],
    est_tracks: Sequence[LabelledScan],
    crossings: Sequence[tuple[Hashable, Hashable, int]],
    *,
    offset: int = 5,
    gate: float = 100.0,
    first_scan: int = 1,
) -> CrossingResult:
    r"""Do both objects of each crossing pair keep their track label through the crossing?

    ``true_tracks[k]`` / ``est_tracks[k]`` are the ``{id: position}`` / ``{label: position}``
    dicts of scan ``first_scan + k``; ``crossings`` holds ``(id_a, id_b, scan)``.  For a pair
    crossing at scan :math:`c` the scans checked are :math:`c - \text{offset}` and
    :math:`c + \text{offset}`, clipped to the scans where *both* objects are present.  At each,
    all true objects are optimally assigned (Hungarian) to the estimated tracks with cost
    :math:`\min(\lVert x - y \rVert, \text{gate})`, pairs at distance ``>= gate`` unassigned.
    The pair **keeps labels** when both objects have a label at both scans and each object's
    label after equals its label before (a swap or a lost object fails).
    """
    true, dim_t = check_labelled_run(true_tracks, "true_tracks")
    est, dim_e = check_labelled_run(est_tracks, "est_tracks")
    if len(true) != len(est):
        raise ValueError(f"true_tracks has {len(true)} scans, est_tracks {len(est)}")
    if dim_t is not None and dim_e is not None and dim_t != dim_e:
        raise ValueError(f"true_tracks and est_tracks have dimensions {dim_t} and {dim_e}")
    gate = check_positive(gate, "gate")
    last_scan = first_scan + len(true) - 1
    out = []
    for id_a, id_b, scan in crossings:
        scan = int(scan)
        if not first_scan <= scan <= last_scan:
            raise ValueError(f"crossing ({id_a!r}, {id_b!r}) at scan {scan} is outside "
                             f"{first_scan}..{last_scan}")
        (fa, la), (fb, lb) = (_presence(true, o, first_scan) for o in (id_a, id_b))
        before = max(scan - int(offset), fa, fb)
        after = min(scan + int(offset), la, lb)
        got = []
        for s in (before, after):
            k = s - first_scan
            lab = _assigned_labels(true[k], est[k], gate)
            got.append((lab.get(id_a), lab.get(id_b)))
        (a0, b0), (a1, b1) = got
        kept = None not in (a0, b0, a1, b1) and a0 == a1 and b0 == b1
        out.append(CrossingPairResult(id_a, id_b, scan, before, after, got[0], got[1], kept))
    frac = float(np.mean([p.kept for p in out])) if out else float("nan")
    return CrossingResult(frac, tuple(out))
