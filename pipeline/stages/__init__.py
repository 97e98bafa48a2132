"""The pipeline's stage loops: source, tracker and sink around the pure pieces.

Modules: :mod:`~pipeline.stages.delivery` (Intake, Sequencer, fetching holes; the bus's
:class:`~pipeline.events.Event` is in :mod:`pipeline.events`),
:mod:`~pipeline.stages.health` (counters, control messages), :mod:`~pipeline.stages.recovery`
(snapshot, journal glue, ``.part`` files, atomic writes), :mod:`~pipeline.stages.salvage` (a
restarted stage whose upstream is gone), :mod:`~pipeline.stages.base` (exit
codes, the injectable clock, StageContext, StageBase) and one module per stage
(:mod:`~pipeline.stages.source`, :mod:`~pipeline.stages.tracker`, :mod:`~pipeline.stages.sink`).

Nothing here imports zenoh.  A stage talks to a *bus* with the interface of
:class:`pipeline.transport.Bus` (``declare``, ``publish``, ``subscribe``, ``recv``,
``declare_alive``, ``alive``, ``wait_alive`` (liveliness tokens ``alive`` and ``ready``),
``dropped``, ``misses``, ``backlog``); the
tests and the benchmark's in-process baseline use :class:`pipeline.membus.MemoryBus`.

Delivery contract (see docs/pipeline.md):

* every data sample carries the codec's JSON payload (its ``run`` must be the stage's run)
  and an attachment ``{"seq": n, "t": publish_ns, "frame": k}``; ``seq`` numbers the
  source's frames 0, 1, 2, ... (``frame`` numbers may skip); ``/tracks`` of frame ``seq``
  carries the same ``seq``;
* a consumer validates each sample (:class:`Intake`: size, attachment, schema, NaN/inf,
  run id), rejects bad ones with a log line, a counter and a copy on ``deadletter``;
* a :class:`Sequencer` per stream drops duplicates, reorders within ``delivery.window``
  sequence numbers and declares a *gap* for a frame still missing when the window has
  moved past it (or after end of stream and ``eos_grace_s`` without progress); a frame
  arriving after its gap was declared is rejected as *late*.  All of this depends only on
  the order in which samples arrive, never on timing, except the end-of-stream grace;
* the tracker processes frames in sequence order (predicting through gaps), snapshots its
  state atomically every ``snapshot_every`` frames and on shutdown, and resumes from the
  snapshot when restarted.
"""

from __future__ import annotations

from bnptrack.pipeline.stages.base import (
    EXIT_CONFIG,
    EXIT_CRASH,
    EXIT_DATA,
    EXIT_IO,
    EXIT_OK,
    EXIT_STOPPED,
    Clock,
    ManualClock,
    StageBase,
    StageContext,
    StageIOError,
    SystemClock,
)
from bnptrack.pipeline.events import Event
from bnptrack.pipeline.stages.delivery import GAP, NO_TRUTH, Accepted, HoleWatch, Intake, Sequencer
from bnptrack.pipeline.stages.health import Counters, EndOfStream, StageInfo
from bnptrack.pipeline.stages.recovery import (
    JOURNAL_NAME,
    PRIOR_FIELDS,
    SNAPSHOT_NAME,
    SUMMARY_NAME,
    BackgroundWriter,
    Snapshot,
    commit_parts,
    keep_prior,
    part_path,
    read_snapshot,
    sync_parts,
    write_atomic,
)
from bnptrack.pipeline.stages.salvage import UpstreamGone, UpstreamWatch, salvage_part
from bnptrack.pipeline.stages.sink import SinkStage
from bnptrack.pipeline.stages.source import SourceStage, source_frames, window_frames
from bnptrack.pipeline.stages.tracker import TrackerStage, build_stage_tracker

__all__ = [
    "EXIT_OK", "EXIT_CRASH", "EXIT_CONFIG", "EXIT_DATA", "EXIT_STOPPED", "EXIT_IO", "StageIOError",
    "Clock", "SystemClock", "ManualClock", "StageContext", "StageBase",
    "Event", "GAP", "NO_TRUTH", "Sequencer", "HoleWatch", "Intake", "Accepted",
    "Counters", "StageInfo", "EndOfStream",
    "BackgroundWriter", "Snapshot", "write_atomic", "read_snapshot", "commit_parts", "part_path", "sync_parts", "keep_prior",
    "PRIOR_FIELDS", "UpstreamGone", "UpstreamWatch", "salvage_part",
    "SNAPSHOT_NAME", "JOURNAL_NAME", "SUMMARY_NAME",
    "SourceStage", "TrackerStage", "SinkStage", "STAGES", "source_frames", "window_frames", "build_stage_tracker",
]

#: The stage class of each role.
STAGES: dict[str, type[StageBase]] = {"source": SourceStage, "tracker": TrackerStage, "sink": SinkStage}
