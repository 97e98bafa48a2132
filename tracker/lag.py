"""Fixed-lag output: a pure layer over any tracker's step that publishes frame ``k - N`` when
frame ``k`` arrives, re-deciding it with the ``N`` scans that followed.

The layer keeps a window of the last ``N + 1`` frames and the tracker's online estimates of
them.  When it publishes the oldest frame of the window it

* **ends dead tracks at their last detection**: a track absent from the newest estimate is
  published only up to the last frame of the window in which a measurement was assigned to it;
* **reports new tracks from their first detection**: a track first reported inside the window is
  followed backwards (the motion model run back in time) through the earlier frames of the
  window, and each frame's nearest unassigned measurement inside a chi-square gate is taken as
  its detection there (an extended Kalman update); the chain stops at the first frame without
  one;
* **continues broken tracks**: a track that ends and a track that starts within the window
  whose back-followed state meets the ended one's inside the gate take the ended track's label;
* **smooths** each track over the window (Rauch-Tung-Striebel with the tracker's own
  coordinated-turn model, linearised at the filtered states).

With ``N = 0`` there is no layer: the tracker's own output is published.  The state is the
tracker's state plus the window (:class:`LagState`), so a snapshot of it resumes exactly.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bnptrack.tracker.models.params import ModelParams
import msgspec

from bnptrack.tracker.state import SNAPSHOT_VERSION, _pack, _unpack, restore, snapshot, tracker_frame_rng
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, Truth, frame_dt

#: chi-square gate on a measurement's squared Mahalanobis distance (99.9 % for 2 dimensions).
GATE_CHI2 = 13.8
#: A crossing is resolved as a label swap when swapping the two tracks' measurements after it
#: lowers the pair's summed squared innovations (each filtered on from its state at the oldest
#: frame of the window) by more than this; ``None``: crossings are left as the tracker decided
#: them (the default).  Over the default ``ddp`` (velocity shared only among objects that have
#: moved together) the check swaps more pairs wrongly than it repairs (``random`` seeds 101-120,
#: ``--lag 3``: 50/60 crossing pairs kept with margin 0, 53 with 2, 55 with 5 and without;
#: docs/results.md, "Fixed-lag output"); over ``ddp-paper`` 0 kept the most.
#: It needs a window of at least 3 frames (``lag >= 2``).
SWAP_MARGIN: float | None = None


@dataclass(frozen=True)
class LagState:
    """The tracker's state and the window: the last frames and their online estimates (oldest
    first), and the labels published at the last published frame with their replacements."""

    inner: Any
    frames: tuple[Frame, ...] = ()
    online: tuple[Estimate, ...] = ()
    renamed: tuple[tuple[str, str], ...] = ()
    """Continued tracks: a track's label -> the label it continues."""
    swaps: tuple[tuple[int, str, str], ...] = ()
    """Crossings resolved as label swaps: ``(frame, a, b)``, labels ``a`` and ``b`` exchanged
    from ``frame`` on (in order)."""


@dataclass(frozen=True)
class LagStep:
    """One step's output: the online estimate of the new frame and the lagged estimate of the
    frame ``lag`` scans earlier (``None`` for the first ``lag`` frames)."""

    online: Estimate
    lagged: Estimate | None
    frame: Frame | None = None
    """The frame ``lagged`` is the estimate of."""


@dataclass(frozen=True)
class _Track:
    """One label's record over the window: presence, filtered moments, detection flags."""

    label: str
    present: np.ndarray
    x: np.ndarray
    P: np.ndarray
    detected: np.ndarray
    existence: np.ndarray
    cluster: tuple
    rows: tuple = ()
    """The measurement row assigned to the label at each frame (``-1``: none)."""


class FixedLag:
    """``tracker`` with its output delayed by ``lag`` scans and re-decided in hindsight."""

    def __init__(self, tracker: Any, params: ModelParams, lag: int, smooth: bool = True,
                 gate: float = GATE_CHI2, swap_margin: float | None = SWAP_MARGIN) -> None:
        if int(lag) < 1:
            raise ValueError(f"FixedLag: lag must be >= 1 scans, got {lag!r}")
        self.tracker, self.params, self.lag, self.smooth, self.gate = tracker, params, int(lag), smooth, gate
        self.swap_margin = swap_margin
        self._motions: dict[float, tuple] = {}
        self.name = tracker.name

    def initial_state(self) -> LagState:
        return LagState(self.tracker.initial_state())

    def step(self, state: LagState, frame: Frame, rng: np.random.Generator) -> tuple[LagState, LagStep]:
        inner, est = self.tracker.step(state.inner, frame, rng)
        frames, online = state.frames + (frame,), state.online + (est,)
        if len(frames) <= self.lag:
            return replace(state, inner=inner, frames=frames, online=online), LagStep(est, None)
        lagged, renamed, swaps = self._publish(frames, online, dict(state.renamed), list(state.swaps))
        return LagState(inner, frames[1:], online[1:], renamed, swaps), LagStep(est, lagged, frames[0])

    def flush(self, state: LagState) -> list[tuple[Frame, Estimate]]:
        """The frames still in the window at the end of the stream and their lagged
        estimates, oldest first."""
        out, frames, online, renamed, swaps = [], state.frames, state.online, state.renamed, state.swaps
        while frames:
            est, renamed, swaps = self._publish(frames, online, dict(renamed), list(swaps))
            out.append((frames[0], est))
            frames, online = frames[1:], online[1:]
        return out

    # ------------------------------------------------------------------ publishing one frame

    def _publish(self, frames, online, renamed: dict[str, str], swaps: list) -> tuple[Estimate, tuple, tuple]:
        """The lagged estimate of the window's oldest frame, and the continued labels and
        swaps to keep.  Its assignments are the online ones under the published labels (plus a
        new track's first detections); it has no cardinality distribution (the online one
        counts the online tracks).  Its diagnostic ``ms`` is the frame's whole cost: the
        online step's ``ms`` plus the time this layer spent publishing it."""
        t0 = time.perf_counter()
        tracks = _records(online)
        used = [set() for _ in frames]
        for i, e in enumerate(online):
            used[i] = {m for m, a in enumerate(e.assignments) if a is not None}
        out: list[TrackEstimate] = []
        assign = list(online[0].assignments)
        ended = [t for t in tracks.values() if t.present[0] and not t.present[-1]]
        for tr in tracks.values():
            if not tr.present[0] and tr.label not in renamed and ended:
                self._continue(tr, ended, frames, renamed)
        if self.swap_margin is not None:
            swaps += self._crossings(tracks, frames, renamed, swaps)
        perm = _permutation(swaps, frames[0].frame)
        final: dict[str, str] = {}
        for te in self._existing(tracks, frames):
            label = renamed.get(te.label, te.label)
            final[te.label] = perm.get(label, label)
            out.append(replace(te, label=final[te.label]))
        for tr in tracks.values():
            te = None if tr.present[0] else self._backfilled(tr, frames, used, assign)
            if te is not None:  # a continued label still in use here: the track's own label
                label = renamed.get(tr.label, tr.label)
                label = perm.get(label, label)
                final[tr.label] = tr.label if label in final.values() else label
                out.append(replace(te, label=final[tr.label]))
        est = online[0]
        assign = [None if a is None else final.get(a, a) for a in assign]
        renamed = {k: v for k, v in renamed.items() if k in tracks}
        diagnostics = dict(est.diagnostics)
        if "ms" in diagnostics:  # the online step's time plus this layer's
            diagnostics["ms"] = diagnostics["ms"] + (time.perf_counter() - t0) * 1e3
        lagged = Estimate(est.frame, est.stamp_ns, tuple(out), tuple(assign), est.assignment_prob,
                          diagnostics, lag=self.lag)
        return lagged, tuple(sorted(renamed.items())), tuple(swaps)

    def _existing(self, tracks: dict, frames) -> list[TrackEstimate]:
        """The tracks present at the published frame, but those dead by the newest frame and
        not detected since, with their (smoothed) moments."""
        keep, runs = [], []
        for tr in tracks.values():
            if not tr.present[0] or (not tr.present[-1] and not tr.detected.any()):
                continue
            run = _run_from(tr.present, 0)
            if not tr.present[-1]:
                run = min(run, int(np.flatnonzero(tr.detected)[-1]) + 1)
            keep.append(tr)
            runs.append(run)
        if not keep:
            return []
        X = np.stack([t.x for t in keep])
        P = np.stack([t.P for t in keep])
        xs, Ps = (self._rts(X, P, np.array(runs), frames) if self.smooth else (X[:, 0], P[:, 0]))
        return [TrackEstimate(t.label, xs[j], Ps[j], float(t.existence[0]), t.cluster[0])
                for j, t in enumerate(keep)]

    def _rts(self, X: np.ndarray, P: np.ndarray, runs: np.ndarray, frames) -> tuple[np.ndarray, np.ndarray]:
        """Rauch-Tung-Striebel for ``n`` tracks at once: filtered moments ``X`` ``(n, W, 5)``,
        ``P`` ``(n, W, 5, 5)`` over the window, track ``j`` smoothed over frames
        ``0 .. runs[j]-1``; returns the smoothed moments at frame 0."""
        idx = np.arange(len(runs))
        xs, Ps = X[idx, runs - 1].copy(), P[idx, runs - 1].copy()
        for i in range(int(runs.max()) - 2, -1, -1):
            on = runs > i + 1
            m, Q = self._motion(self._dt(frames[i], frames[i + 1]))
            x, Pi = X[on, i], P[on, i]
            J = m.jacobian(x)
            Pp = J @ Pi @ J.transpose(0, 2, 1) + Q
            C = np.linalg.solve(Pp, J @ Pi).transpose(0, 2, 1)
            xs[on] = x + np.einsum("nij,nj->ni", C, xs[on] - m.f(x))
            Ps[on] = Pi + C @ (Ps[on] - Pp) @ C.transpose(0, 2, 1)
        return xs, 0.5 * (Ps + Ps.transpose(0, 2, 1))

    def _motion(self, dt: float):
        """The motion model over ``dt`` and its process noise (kept per ``dt``)."""
        if dt not in self._motions:
            m = self.params.motion(dt)
            self._motions[dt] = (m, m.Q if dt >= 0 else None)
        return self._motions[dt]

    def _backfilled(self, tr: _Track, frames, used, assign) -> TrackEstimate | None:
        """A track first reported later in the window, followed back to the published frame
        through unassigned measurements; ``None`` when the chain breaks before it."""
        b = int(np.argmax(tr.present))
        if not tr.present[b]:
            return None
        run = _run_from(tr.present, b)
        x, P = tr.x[b], tr.P[b]
        if self.smooth and run - b > 1:
            xs, Ps = self._rts(tr.x[None, b:], tr.P[None, b:], np.array([run - b]), frames[b:])
            x, P = xs[0], Ps[0]
        picks = []
        for i in range(b - 1, -1, -1):
            x, P, m = self._back_step(x, P, frames[i], frames[i + 1], used[i])
            if m is None:
                return None
            picks.append((i, m))
        for i, m in picks:
            used[i].add(m)
        assign[picks[-1][1]] = tr.label
        return TrackEstimate(tr.label, x, P, float(tr.existence[b]), tr.cluster[b])

    def _back_step(self, x, P, frame: Frame, later: Frame, used: set):
        """Predict ``(x, P)`` from ``later`` back to ``frame`` and update it with the nearest
        unassigned measurement of ``frame`` inside the gate; ``m`` is its row (``None``: none)."""
        dt = self._dt(frame, later)
        back, _ = self._motion(-dt)
        J = back.jacobian(x[None])[0]
        x = back.f(x[None])[0]
        P = J @ (P + self._motion(dt)[1]) @ J.T
        if used is None or frame.n_measurements == 0:
            return x, P, None
        meas = self.params.measurement(frame.kind, self.params.frame_sensor(frame))
        H = meas.jacobian(x[None])[0]
        S = H @ P @ H.T + meas.R
        r = meas.residual(frame.z, meas.h(x[None]))
        d2 = np.einsum("mi,ij,mj->m", r, np.linalg.inv(S), r)
        if used:
            d2[list(used)] = np.inf
        m = int(np.argmin(d2))
        if not d2[m] < self.gate:
            return x, P, None
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ r[m]
        P = P - K @ S @ K.T
        return x, 0.5 * (P + P.T), m

    def _crossings(self, tracks: dict, frames, renamed: dict[str, str], swaps: list) -> list:
        """Pairs of tracks within the gate of each other at window frame 1 (their closest
        approach) whose measurements after it fit each other's earlier states better than their
        own (summed squared innovations lower by more than ``swap_margin``): a swap
        ``(frame 2, a, b)`` of their labels."""
        W = len(frames)
        both = [t for t in tracks.values() if t.present.all()]
        if W < 3 or len(both) < 2:
            return []
        pos = np.stack([t.x[1][[0, 2]] for t in both])
        Pp = np.stack([t.P[1][np.ix_([0, 2], [0, 2])] for t in both])
        D = pos[:, None] - pos[None]
        d2 = np.einsum("abi,abij,abj->ab", D, np.linalg.inv(Pp[:, None] + Pp[None]), D)
        recent = [(a, b) for f, a, b in swaps if f > frames[0].frame - W]
        done = set(recent) | {(b, a) for a, b in recent}
        found, models = [], [None] * W
        for i, j in zip(*np.nonzero(np.triu(d2 < self.gate, 1))):
            A, B = both[i], both[j]
            ka, kb = renamed.get(A.label, A.label), renamed.get(B.label, B.label)
            if (ka, kb) in done:
                continue
            nis = self._nis((A, B, A, B), (A, B, B, A), frames, models)
            keep, swap = nis[0] + nis[1], nis[2] + nis[3]
            if keep - swap > self.swap_margin:
                found.append((frames[2].frame, ka, kb))
                done |= {(ka, kb), (kb, ka)}
        return found

    def _nis(self, starts: tuple, afters: tuple, frames, models: list) -> np.ndarray:
        """For each hypothesis ``h``: the sum of squared innovations (Mahalanobis) under an
        extended Kalman filter started from ``starts[h]``'s state at window frame 0, of
        ``starts[h]``'s measurement at frame 1 (the closest approach) and ``afters[h]``'s at
        frames 2 .. W-1 (``models``: each frame's measurement model, filled as needed)."""
        x = np.stack([t.x[0] for t in starts])
        P = np.stack([t.P[0] for t in starts])
        total = np.zeros(len(starts))
        for i in range(1, len(frames)):
            m, Q = self._motion(self._dt(frames[i - 1], frames[i]))
            J = m.jacobian(x)
            x, P = m.f(x), J @ P @ J.transpose(0, 2, 1) + Q
            rows = np.array([(s if i == 1 else a).rows[i] for s, a in zip(starts, afters)])
            on = rows >= 0
            if not on.any():
                continue
            f = frames[i]
            if models[i] is None:
                models[i] = self.params.measurement(f.kind, self.params.frame_sensor(f))
            model = models[i]
            xo, Po = x[on], P[on]
            H = model.jacobian(xo)
            S = H @ Po @ H.transpose(0, 2, 1) + model.R
            r = model.residual(f.z[rows[on]], model.h(xo))
            total[on] += np.einsum("ni,ni->n", r, np.linalg.solve(S, r[..., None])[..., 0])
            K = np.linalg.solve(S, H @ Po).transpose(0, 2, 1)
            x[on] = xo + np.einsum("nij,nj->ni", K, r)
            P[on] = Po - K @ S @ K.transpose(0, 2, 1)
        return total

    def _continue(self, tr: _Track, ended: list[_Track], frames, renamed: dict[str, str]) -> None:
        """Give newborn ``tr`` the label of an ended track whose last state its back-followed
        state meets inside the gate (first such track)."""
        b = int(np.argmax(tr.present))
        taken = set(renamed.values())
        for old in ended:
            last = int(np.flatnonzero(old.present)[-1])
            label = renamed.get(old.label, old.label)
            if last >= b or label in taken:
                continue
            x, P = tr.x[b], tr.P[b]
            for i in range(b - 1, last - 1, -1):
                x, P, _ = self._back_step(x, P, frames[i], frames[i + 1], None)
            d = x[[0, 2]] - old.x[last][[0, 2]]
            S = P[np.ix_([0, 2], [0, 2])] + old.P[last][np.ix_([0, 2], [0, 2])]
            if d @ np.linalg.solve(S, d) < self.gate:
                renamed[tr.label] = label
                return

    def _dt(self, a: Frame, b: Frame) -> float:
        """Seconds from frame ``a`` to frame ``b`` (:func:`tracker.types.frame_dt`)."""
        return frame_dt(a.frame, a.stamp_ns, b.frame, b.stamp_ns, self.params.T)


def run_lagged(layer: FixedLag, frames: Iterable[Frame], seed: int,
               on_online: Callable[[Frame, Estimate], None] | None = None,
               ) -> Iterator[tuple[Frame, Estimate, LagState]]:
    """As :func:`tracker.state.run` for a :class:`FixedLag` layer: yields each published
    ``(frame, lagged estimate, state)``, the window's frames flushed at the end of ``frames``
    (also when the frame source raises: the window is published, then the error re-raised).
    ``on_online(frame, estimate)`` sees each online estimate as it is made."""
    state, error = layer.initial_state(), None
    try:
        for frame in frames:
            state, out = layer.step(state, frame, tracker_frame_rng(seed, frame.frame))
            if on_online is not None:
                on_online(frame, out.online)
            if out.lagged is not None:
                yield out.frame, out.lagged, state
    except Exception as exc:  # noqa: BLE001 -- re-raised once the window is published
        error = exc
    for frame, est in layer.flush(state):
        yield frame, est, state
    if error is not None:
        raise error


def _permutation(swaps, frame: int) -> dict[str, str]:
    """The label map in effect at ``frame``: the swaps from frames up to it, in order."""
    perm: dict[str, str] = {}
    for f, a, b in swaps:
        if f <= frame:
            perm[a], perm[b] = perm.get(b, b), perm.get(a, a)
    return perm


def _run_from(present: np.ndarray, i: int) -> int:
    """End (exclusive) of the run of presence starting at ``i``."""
    j = i
    while j < len(present) and present[j]:
        j += 1
    return j


def _records(online) -> dict[str, _Track]:
    """Each label's record over the window's online estimates."""
    W = len(online)
    by_label: dict[str, list] = {}
    for i, e in enumerate(online):
        for t in e.tracks:
            by_label.setdefault(t.label, [None] * W)[i] = t
    detected = [set(e.assignments) for e in online]
    out = {}
    for lab, row in by_label.items():
        present = np.array([t is not None for t in row])
        first = next(t for t in row if t is not None)
        x = np.stack([(t or first).state for t in row])
        P = np.stack([(t or first).covariance for t in row])
        ex = np.array([0.0 if t is None else t.existence for t in row])
        cl = tuple(None if t is None else t.cluster for t in row)
        rows = tuple(e.assignments.index(lab) if lab in d else -1 for e, d in zip(online, detected))
        out[lab] = _Track(lab, present, x, P, np.array([lab in d for d in detected]), ex, cl, rows)
    return out


# --------------------------------------------------------------------------- snapshots


def snapshot_lag(state: LagState) -> bytes:
    """Serialise a :class:`LagState` exactly: the tracker's state (:func:`tracker.state.snapshot`),
    the window's frames (with truth) and online estimates, and the continued labels."""
    doc = {"v": SNAPSHOT_VERSION, "inner": snapshot(state.inner), "frames": [_frame_doc(f) for f in state.frames],
           "online": [_estimate_doc(e) for e in state.online], "renamed": [list(p) for p in state.renamed],
           "swaps": [list(p) for p in state.swaps]}
    return msgspec.msgpack.encode(doc)


def restore_lag(data: bytes, inner_cls: type) -> LagState:
    """Inverse of :func:`snapshot_lag` for a tracker whose state class is ``inner_cls``."""
    doc = msgspec.msgpack.decode(data)
    if not isinstance(doc, dict) or doc.get("v") != SNAPSHOT_VERSION or "inner" not in doc:
        raise ValueError("not a fixed-lag snapshot (expected a document with the tracker state and its window)")
    return LagState(restore(doc["inner"], inner_cls), tuple(_frame_of(d) for d in doc["frames"]),
                    tuple(_estimate_of(d) for d in doc["online"]), tuple(tuple(p) for p in doc["renamed"]),
                    tuple(tuple(p) for p in doc["swaps"]))


def _frame_doc(f: Frame) -> dict:
    truth = None if f.truth is None else {"ids": list(f.truth.ids), "states": _pack(f.truth.states)}
    return {"frame": f.frame, "stamp_ns": f.stamp_ns, "sensor": f.sensor, "kind": f.kind, "z": _pack(f.z),
            "truth": truth, "pose": None if f.pose is None else list(f.pose), "R": None if f.R is None else _pack(f.R)}


def _frame_of(d: dict) -> Frame:
    truth = None if d["truth"] is None else Truth(tuple(d["truth"]["ids"]), _unpack(d["truth"]["states"]))
    return Frame(d["frame"], d["stamp_ns"], d["sensor"], d["kind"], _unpack(d["z"]), truth,
                 None if d["pose"] is None else tuple(d["pose"]), None if d["R"] is None else _unpack(d["R"]))


def _estimate_doc(e: Estimate) -> dict:
    tracks = [[t.label, _pack(t.state), _pack(t.covariance), float(t.existence), t.cluster] for t in e.tracks]
    return {"frame": e.frame, "stamp_ns": e.stamp_ns, "tracks": tracks, "assignments": list(e.assignments),
            "assignment_prob": [float(p) for p in e.assignment_prob], "diagnostics": dict(e.diagnostics),
            "pmf": None if e.cardinality_pmf is None else _pack(e.cardinality_pmf)}


def _estimate_of(d: dict) -> Estimate:
    tracks = tuple(TrackEstimate(lab, _unpack(x), _unpack(P), ex, cl) for lab, x, P, ex, cl in d["tracks"])
    return Estimate(d["frame"], d["stamp_ns"], tracks, tuple(d["assignments"]), tuple(d["assignment_prob"]),
                    dict(d["diagnostics"]), None if d["pmf"] is None else _unpack(d["pmf"]))
