"""The tracker stage's warm-up: the tracker's imports, numba's set-up and every kernel the
tracker can hit, run before the first frame so that no frame pays for a compile or a load
(docs/pipeline.md, Performance)."""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np

from bnptrack.tracker.numerics import preload

__all__ = ["compiled_kernels", "contest_frames", "preload_tracker", "warm_up_contests", "warm_up_tracker",
           "warm_tracker_imports"]

log = logging.getLogger("bnptrack.stage")


def warm_tracker_imports(name: str) -> None:
    """Import the modules of tracker ``name`` through the tracker registry (its entry
    imports them), whatever tracker it is; an unknown name is left to the build to report."""
    from bnptrack.tracker import registry

    try:
        registry.kind(name)
    except ValueError:
        pass


def preload_tracker() -> None:
    """numba's import and set-up (:func:`tracker.numerics.preload`): what the first frames
    would otherwise pay in the loop (the large frames' :data:`LAZY_IMPORTS` come later, in the
    background, when a frame is large: :meth:`TrackerStage._lazy_imports_due`)."""
    preload()


# -- warm-up: every kernel the tracker can hit, before the first frame ------------------
# A numba kernel is compiled (cold cache: 2-4 s) or loaded from the kernel cache (warm: 20-40 ms)
# at its first call.  tracker.registry.warm_up (a few frames of each measurement kind's example
# rows) reaches births, updates and deaths but never two clusters that prefer one measurement:
# the JPDA* assignment's contested path (bnp._update_kernels.jpda_solve, tracker._lsap), first hit at
# vo2017's frame 4 inside a paced run, nor the two-level trackers' group kernels (frames 2-23).
# The contests below add, per kind, two objects born apart that close in, then one measurement
# between them (both clusters prefer it), then empty frames (deaths).  The trackers are pure:
# the warm-up changes no result (the run starts from initial_state()).

#: Closest approach of the two contested objects along the kind's last column (metres of range
#: for ``bearing_range`` and ``range``) before the single measurement between them, as
#: multiples of :data:`UNIT`: a spread, so that at least one makes two clusters that both prefer
#: the middle measurement whatever the configured sensor's noise (a pair that merged into one
#: cluster, or two clusters that do not both gate the measurement, cost a few frames and
#: nothing else).
CONTEST_SEPARATIONS = (2.0, 4.0, 6.0)
#: The scale of the contest frames: 10 m (vo2017's range noise std).
UNIT = 10.0
#: Frames with both objects 20 units apart (two births), then they approach by one unit per
#: frame each, then ``CONTEST`` frames with one measurement between them, then
#: ``EMPTY_FRAMES`` empty frames (misses, deaths).
BORN_FRAMES, START_GAP, CONTEST, EMPTY_FRAMES = 5, 20.0, 2, 3


def contest_frames(kind: str, example: tuple[float, ...], closest: float) -> Iterator[object]:
    """Frames 1.. of one contest on measurement kind ``kind``, one second apart: two objects
    ``START_GAP`` units apart in the last column around ``example`` (``BORN_FRAMES`` frames),
    closing in by one unit each per frame until ``closest`` units apart, one measurement
    half-way (``CONTEST`` frames), then nothing (``EMPTY_FRAMES`` frames)."""
    from bnptrack.tracker.types import Frame

    base = np.asarray(example, dtype=float)
    axis = np.zeros_like(base)
    axis[-1] = UNIT
    gaps = [START_GAP] * BORN_FRAMES + list(np.arange(START_GAP - 2.0, closest - 1e-9, -2.0))
    rows = [np.stack([base - axis * g / 2, base + axis * g / 2]) for g in gaps]
    rows += [base[None, :]] * CONTEST + [np.zeros((0, base.size))] * EMPTY_FRAMES
    for k, z in enumerate(rows, start=1):
        yield Frame(k, k * 10**9, "warm-up", kind, z)


def warm_up_contests(tracker: object) -> None:
    """Step ``tracker`` (from ``initial_state()`` each time) through :func:`contest_frames` for
    every measurement kind with example rows and every separation of
    :data:`CONTEST_SEPARATIONS`.  A kind whose step raises (a tracker without that kind's
    model, say) is left alone."""
    from bnptrack.tracker.models.measurement import KINDS

    rng = np.random.default_rng(0)
    for name, entry in KINDS.items():
        if not entry.examples:
            continue
        for sep in CONTEST_SEPARATIONS:
            state = tracker.initial_state()
            try:
                for frame in contest_frames(name, entry.examples[0], sep):
                    state, _ = tracker.step(state, frame, rng)
            except Exception:  # noqa: BLE001 - this kind is not the tracker's: nothing to warm
                break


def compiled_kernels() -> dict[str, int]:
    """``module.function -> number of compiled signatures`` of every numba kernel of the
    loaded ``bnptrack.tracker`` modules (a kernel not yet called counts 0; without numba, or
    with ``BNPTRACK_NO_JIT=1``, empty).  A kernel whose count grows during the frames was
    compiled or loaded from the kernel cache inside a frame: what the warm-up is for."""
    out: dict[str, int] = {}
    for mod_name, mod in list(sys.modules.items()):
        if not mod_name.startswith("bnptrack.tracker") or mod is None:
            continue
        for value in list(vars(mod).values()):
            py = getattr(value, "py_func", None)
            if py is None or getattr(py, "__module__", None) != mod_name:
                continue
            sigs = getattr(value, "signatures", None)
            if sigs is not None:
                out[f"{mod_name}.{py.__name__}"] = len(sigs)
            elif type(value).__name__ == "_LazyKernel":
                out[f"{mod_name}.{py.__name__}"] = 0
    return out


def warm_up_tracker(tracker: Any) -> None:
    """Run a few throw-away steps of the built ``tracker`` on dummy frames so that lazily
    compiled kernels (numba) and caches are ready before the first real frame: the registry's
    warm-up, then the contests of :func:`warm_up_contests` (two close objects, one
    measurement between them: the paths the registry's frames miss).  The tracker is
    a pure function of its inputs, so this changes no result (the real run starts from
    ``initial_state()``)."""
    import time

    from bnptrack.tracker.registry import warm_up

    t0 = time.perf_counter()
    try:
        warm_up(tracker)
    except Exception as exc:  # a tracker without a range model, say: warm-up is optional
        log.debug("tracker warm-up skipped: %s", exc)
    warm_up_contests(tracker)  # the contested assignment, the group kernels (above)
    if log.isEnabledFor(logging.DEBUG):
        log.debug("tracker warm-up took %.2f s; %d kernel(s) ready", time.perf_counter() - t0,
                  sum(1 for n in compiled_kernels().values() if n))
