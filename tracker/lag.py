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

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bnptrack.tracker.models.params import ModelParams
from bnptrack.tracker.types import Estimate, Frame, TrackEstimate, frame_dt

#: chi-square gate on a measurement's squared Mahalanobis distance (99.9 % for 2 dimensions).
GATE_CHI2 = 13.8


@dataclass(frozen=True)
class LagState:
    """The tracker's state and the window: the last frames and their online estimates (oldest
    first), and the labels published at the last published frame with their replacements."""

    inner: Any
    frames: tuple[Frame, ...] = ()
    online: tuple[Estimate, ...] = ()
    renamed: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class LagStep:
    """One step's output: the online estimate of the new frame and the lagged estimate of the
    frame ``lag`` scans earlier (``None`` for the first ``lag`` frames)."""

    online: Estimate
    lagged: Estimate | None


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


class FixedLag:
    """``tracker`` with its output delayed by ``lag`` scans and re-decided in hindsight."""

    def __init__(self, tracker: Any, params: ModelParams, lag: int, smooth: bool = True,
                 gate: float = GATE_CHI2) -> None:
        if int(lag) < 1:
            raise ValueError(f"FixedLag: lag must be >= 1 scans, got {lag!r}")
        self.tracker, self.params, self.lag, self.smooth, self.gate = tracker, params, int(lag), smooth, gate
        self.name = tracker.name

    def initial_state(self) -> LagState:
        return LagState(self.tracker.initial_state())

    def step(self, state: LagState, frame: Frame, rng: np.random.Generator) -> tuple[LagState, LagStep]:
        inner, est = self.tracker.step(state.inner, frame, rng)
        frames, online = state.frames + (frame,), state.online + (est,)
        if len(frames) <= self.lag:
            return LagState(inner, frames, online, state.renamed), LagStep(est, None)
        lagged, renamed = self._publish(frames, online, dict(state.renamed))
        return LagState(inner, frames[1:], online[1:], renamed), LagStep(est, lagged)

    def flush(self, state: LagState) -> list[Estimate]:
        """The frames still in the window at the end of the stream, oldest first."""
        out, frames, online, renamed = [], state.frames, state.online, dict(state.renamed)
        while frames:
            est, renamed_t = self._publish(frames, online, renamed)
            renamed = dict(renamed_t)
            out.append(est)
            frames, online = frames[1:], online[1:]
        return out

    # ------------------------------------------------------------------ publishing one frame

    def _publish(self, frames, online, renamed: dict[str, str]) -> tuple[Estimate, tuple]:
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
        for tr in tracks.values():
            te = self._existing(tr, frames) if tr.present[0] else self._backfilled(tr, frames, used, assign)
            if te is not None:
                out.append(replace(te, label=renamed.get(tr.label, tr.label)))
        est = online[0]
        assign = [renamed.get(a, a) if a is not None else None for a in assign]
        renamed = {k: v for k, v in renamed.items() if k in tracks}
        diag = dict(est.diagnostics, lag=float(self.lag))
        lagged = Estimate(est.frame, est.stamp_ns, tuple(out), tuple(assign), est.assignment_prob, diag,
                          est.cardinality_pmf)
        return lagged, tuple(sorted(renamed.items()))

    def _existing(self, tr: _Track, frames) -> TrackEstimate | None:
        """A track present at the published frame: dropped when it is dead by the newest frame
        and was not detected since; else its (smoothed) moments."""
        if not tr.present[-1] and not tr.detected.any():
            return None
        run = _run_from(tr.present, 0)
        if not tr.present[-1]:
            run = min(run, int(np.flatnonzero(tr.detected)[-1]) + 1)
        x, P = tr.x[0], tr.P[0]
        if self.smooth and run > 1:
            x, P = self._rts(tr, frames, run)
        return TrackEstimate(tr.label, x, P, float(tr.existence[0]), tr.cluster[0])

    def _rts(self, tr: _Track, frames, run: int) -> tuple[np.ndarray, np.ndarray]:
        """Rauch-Tung-Striebel over window frames ``0 .. run-1``: the smoothed moments at 0."""
        xs, Ps = tr.x[run - 1], tr.P[run - 1]
        for i in range(run - 2, -1, -1):
            m = self.params.motion(self._dt(frames[i], frames[i + 1]))
            x, P = tr.x[i], tr.P[i]
            J = m.jacobian(x[None])[0]
            xp = m.f(x[None])[0]
            Pp = J @ P @ J.T + m.Q
            C = np.linalg.solve(Pp, J @ P).T
            xs = x + C @ (xs - xp)
            Ps = P + C @ (Ps - Pp) @ C.T
        return xs, 0.5 * (Ps + Ps.T)

    def _backfilled(self, tr: _Track, frames, used, assign) -> TrackEstimate | None:
        """A track first reported later in the window, followed back to the published frame
        through unassigned measurements; ``None`` when the chain breaks before it."""
        b = int(np.argmax(tr.present))
        if not tr.present[b]:
            return None
        run = _run_from(tr.present, b)
        x, P = (self._rts(_shift(tr, b), frames[b:], run - b) if self.smooth and run - b > 1 else (tr.x[b], tr.P[b]))
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
        back = self.params.motion(-dt)
        J = back.jacobian(x[None])[0]
        x = back.f(x[None])[0]
        P = J @ (P + self.params.motion(dt).Q) @ J.T
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

    @staticmethod
    def _dt_static(params: ModelParams, a: Frame, b: Frame) -> float:
        return frame_dt(a.frame, a.stamp_ns, b.frame, b.stamp_ns, params.T)

    def _dt(self, a: Frame, b: Frame) -> float:
        return self._dt_static(self.params, a, b)


def _run_from(present: np.ndarray, i: int) -> int:
    """End (exclusive) of the run of presence starting at ``i``."""
    j = i
    while j < len(present) and present[j]:
        j += 1
    return j


def _shift(tr: _Track, b: int) -> _Track:
    return _Track(tr.label, tr.present[b:], tr.x[b:], tr.P[b:], tr.detected[b:], tr.existence[b:], tr.cluster[b:])


def _records(online) -> dict[str, _Track]:
    """Each label's record over the window's online estimates."""
    W = len(online)
    labels: dict[str, None] = {}
    for e in online:
        for t in e.tracks:
            labels.setdefault(t.label)
    out = {}
    for lab in labels:
        present = np.zeros(W, bool)
        detected = np.zeros(W, bool)
        x, P = np.zeros((W, 5)), np.tile(np.eye(5), (W, 1, 1))
        ex, cl = np.zeros(W), [None] * W
        for i, e in enumerate(online):
            detected[i] = lab in e.assignments
            for t in e.tracks:
                if t.label == lab:
                    present[i], x[i], P[i], ex[i], cl[i] = True, t.state, t.covariance, t.existence, t.cluster
                    break
        out[lab] = _Track(lab, present, x, P, detected, ex, tuple(cl))
    return out
