"""The pipeline file: which stages run, with which parameters, on which Zenoh network.

A pipeline file is TOML (or the JSON the launcher writes for its stages) validated into
:class:`PipelineConfig`, a frozen ``msgspec`` struct; ``--set key=value`` overrides use
dotted keys (``--set source.frames=20 --set tracker.tracker='"dpyp"'``), and the keys of
``bnptrack track --set`` (``params.KEY``, ``tracker.KEY`` of the tracker's settings, a bare
KEY) reach the tracker (:func:`apply_pipeline_overrides`).  Every field has a default, so an empty file (or no
file: :func:`default_pipeline`) is the embedded default pipeline::

    synthetic vo2017 source (seed 1)  ->  DDP-EMM tracker (seed 0)  ->  sink (tracks.mcap)

over an embedded Zenoh router that the launcher opens on a free loopback port.

This module does not import zenoh (see :mod:`pipeline.transport`).
"""

from __future__ import annotations

import json
import os
import re
import secrets
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

import msgspec

from bnptrack.sinks.sink import RRD_NAME, TRACKS_NAME
from bnptrack.pipeline.endpoints import check_endpoint
from bnptrack.tracker.config import ConfigError, NonNeg, NonNegInt, PosInt, Positive, apply_overrides, convert, load_toml, split_item
from bnptrack.tracker.input_checks import SIM_SENSOR

__all__ = [
    "RUN_RE",
    "TLS_FILE_FIELDS",
    "TlsConfig",
    "ZenohConfig",
    "SourceConfig",
    "parse_topic_item",
    "check_topic_map",
    "TrackerStageConfig",
    "SinkConfig",
    "sink_outputs",
    "DeliveryConfig",
    "SupervisorConfig",
    "PipelineConfig",
    "default_pipeline",
    "load_pipeline",
    "split_pipeline_overrides",
    "apply_pipeline_overrides",
    "dump_pipeline",
    "check_run_id",
    "run_id_problem",
    "make_run_id",
    "resolve_run",
]

#: A run id is one key-expression chunk: no ``/``, ``*``, ``$``, ``?``, ``#``.
RUN_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,127}$")



#: The fields of :class:`TlsConfig` that name PEM files (in Zenoh: ``transport/link/tls/<name>``).
TLS_FILE_FIELDS = (
    "root_ca_certificate",
    "listen_certificate",
    "listen_private_key",
    "connect_certificate",
    "connect_private_key",
)


class TlsConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """TLS files (PEM).  Empty strings are left out of the Zenoh configuration.

    A client needs ``root_ca_certificate`` (the CA that signed the router's certificate);
    the router needs ``listen_certificate`` and ``listen_private_key``.  With ``mtls`` the
    router also checks client certificates (``connect_certificate`` / ``connect_private_key``
    signed by ``root_ca_certificate``).
    """

    root_ca_certificate: str = ""
    listen_certificate: str = ""
    listen_private_key: str = ""
    connect_certificate: str = ""
    connect_private_key: str = ""
    mtls: bool = False
    verify_name_on_connect: bool = True

    def files(self) -> dict[str, str]:
        """The file fields that are set (:data:`TLS_FILE_FIELDS` order), name -> path."""
        return {name: getattr(self, name) for name in TLS_FILE_FIELDS if getattr(self, name)}


class ZenohConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """How the stages reach each other.

    ``embedded_router`` (the default): the launcher opens a router session listening on
    ``router_listen`` (``tcp/127.0.0.1:0`` = a free loopback port) and the stages connect to
    it as clients.  Otherwise the stages connect to ``connect`` (e.g. a ``bnptrack router``
    on another host).  ``extra`` holds raw Zenoh settings (``"path/to/key" = json5 value``)
    applied to every session the pipeline opens, ``router_extra`` only to the router (e.g.
    ``access_control``).

    ``mode``: ``client`` (the default) stages reach each other through the router; ``peer``
    stages connect to the router too but send their data to each other directly (they learn
    each other's ``listen`` endpoints by gossip; default a free loopback port), which saves a
    hop and the router's work, but a stage that (re)starts while a publisher is live may miss
    that publisher's history (docs/pipeline.md), and peer mode refuses TLS, authentication
    and access control (these need every byte to pass the router).

    Authentication and access control: a session logs in with ``user`` / ``password``
    (Zenoh's usrpwd authentication; the environment variables ``BNPTRACK_ZENOH_USER`` and
    ``BNPTRACK_ZENOH_PASSWORD`` take precedence, so passwords need not be in files); a
    router checks them against ``users_file`` (``user:password`` lines).  ``acl = true``
    gives the router the generated access-control list: the user named like a stage
    (``source``, ``tracker``, ``sink``) may put only on that stage's keys, any other user
    may not put at all (see docs/pipeline.md).  With ``acl`` and the embedded router, the
    launcher generates one password per stage itself.  ``auth`` (the default) does that for
    every launch with the embedded router in client mode: a run is closed to other local
    processes unless ``auth = false`` (peer mode cannot be closed: its stages exchange data
    past the router).
    """

    mode: Literal["client", "peer"] = "client"
    embedded_router: bool = True
    router_listen: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:0"])
    connect: list[str] = msgspec.field(default_factory=list)
    listen: list[str] = msgspec.field(default_factory=list)
    multicast_scouting: bool = False
    connect_timeout_s: NonNeg = 10.0
    tls: TlsConfig = msgspec.field(default_factory=TlsConfig)
    user: str = ""
    password: str = ""
    users_file: str = ""
    acl: bool = False
    auth: bool = True
    extra: dict[str, str] = msgspec.field(default_factory=dict)
    router_extra: dict[str, str] = msgspec.field(default_factory=dict)

    @property
    def secured(self) -> bool:
        """TLS, authentication or access control is configured."""
        return bool(self.acl or self.users_file or self.user or self.tls.files() or self.tls.mtls)

    def check_endpoints(self) -> None:
        """:func:`check_endpoint` of every endpoint, named by its key (``zenoh.connect``)."""
        for key in ("router_listen", "connect", "listen"):
            for endpoint in getattr(self, key):
                check_endpoint(endpoint, f"zenoh.{key}")

    def __post_init__(self) -> None:
        self.check_endpoints()
        if self.mode == "peer" and self.secured:
            raise ValueError(
                "zenoh.mode = 'peer' cannot be combined with TLS, authentication or access "
                "control: peers exchange data directly, past the router that enforces them "
                "(use mode = 'client')"
            )


def parse_topic_item(item: str) -> tuple[str, str]:
    """A channel mapping item ``SRC=/measurements`` (or ``SRC=/truth``) as ``(SRC, DST)``; a
    bare ``SRC`` (``--topic /radar/scan``: a ROS 2 / Foxglove channel whose kind its schema
    gives) means ``SRC=/measurements``; :class:`ValueError` names the item otherwise
    (``--topic`` of ``track`` / ``replay`` and ``source.topics``)."""
    from bnptrack.tracker.messages import TOPIC_MEASUREMENTS, TOPIC_TRUTH

    src, sep, dst = item.partition("=")
    if not sep and src:
        return src, TOPIC_MEASUREMENTS
    if not sep or not src or dst not in (TOPIC_MEASUREMENTS, TOPIC_TRUTH):
        raise ValueError(f"{item!r}: expected SRC={TOPIC_MEASUREMENTS} (or SRC={TOPIC_TRUTH})")
    return src, dst


def check_topic_map(topics: dict[str, str], key: str) -> None:
    """Raise :class:`ValueError` (one line naming ``key``) unless every entry of ``topics``
    is a valid ``SRC=/measurements`` / ``SRC=/truth`` mapping (:func:`parse_topic_item`)."""
    for src, dst in topics.items():
        try:
            parse_topic_item(f"{src}={dst}")
        except ValueError as exc:
            raise ValueError(f"{key}: {exc}") from None


class SourceConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The measurement source.

    ``kind = "synthetic"`` simulates ``scenario`` with ``params`` (+ ``overrides``) and
    ``seed``, like ``bnptrack simulate`` (a generated scenario, ``random`` or ``random-cv``,
    draws its scene from ``seed`` and the ``scene.KEY=V`` items of ``overrides``);
    ``kind = "mcap"`` replays the frames of ``log``.  ``frames`` > 0 stops after that many frames.
    ``start_s`` / ``end_s`` keep the frames whose time stamp is that many seconds after the
    first frame's or more / or less (log time, both ends included); ``start_frame`` /
    ``end_frame`` keep the frame numbers in that range (``replay --start/--end``; seconds and
    frames are not mixed at one end).  ``rate`` paces publication against the
    frames' time stamps (1 = real time, 10 = ten times faster); 0 = as fast as possible.
    ``wait_for`` lists the stages whose liveliness token the source waits for before the
    first frame (``ready_timeout_s`` bounds the wait; 0 = wait forever), ``done_by`` the
    stages whose end of stream it waits for before closing (it serves its cache until then).
    ``topics`` (``kind = "mcap"``): channels of ``log`` read as another topic, ``{SRC =
    "/measurements"}`` or ``{SRC = "/truth"}``, as ``bnptrack track --topic SRC=/measurements``
    (``replay --topic``; the payload must still follow the contract of docs/formats.md).
    """

    kind: Literal["synthetic", "mcap"] = "synthetic"
    scenario: str = "vo2017"
    params: str = "vo2017"
    overrides: list[str] = msgspec.field(default_factory=list)
    snr_db: float | None = None
    seed: NonNegInt = 1
    log: str = ""
    frames: NonNegInt = 0
    start_s: NonNeg | None = None
    end_s: NonNeg | None = None
    start_frame: NonNegInt | None = None
    end_frame: NonNegInt | None = None
    rate: NonNeg = 0.0
    sensor: str = SIM_SENSOR
    wait_for: list[str] = msgspec.field(default_factory=lambda: ["tracker", "sink"])
    ready_timeout_s: NonNeg = 60.0
    done_by: list[str] = msgspec.field(default_factory=lambda: ["sink"])
    topics: dict[str, str] = msgspec.field(default_factory=dict)

    def __post_init__(self) -> None:
        check_topic_map(self.topics, "source.topics")
        if self.topics and self.kind != "mcap":
            raise ValueError("source.topics: maps the channels of an MCAP log: it needs source.kind = 'mcap'")


class TrackerStageConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The tracker stage: any tracker :func:`pipeline.offline.build_tracker` knows.

    ``params`` empty = as ``bnptrack track``: the source's ``bnptrack.scenario`` record,
    else the default set.  ``config`` empty = the preset named like the tracker.
    ``overrides`` are ``bnptrack track --set`` items (``params.KEY=V``, ``tracker.KEY=V``).
    The state is snapshotted to ``<out>/tracker.snap`` every ``snapshot_every`` frames and at
    shutdown; a restarted stage resumes from it (``resume = false`` ignores it).
    ``prior_from``: the ``tracker.snap`` of an earlier run of the same tracker; a stage that does
    not resume starts from that run's prior (the BNP trackers' concentration ``alpha``,
    discount ``d`` and their accumulated likelihood) with no track (``replay --loop
    --keep-prior``).  ``lag``: publish each frame's tracks ``lag`` scans late, re-decided with
    the scans after it (the fixed-lag output of ``bnptrack track --lag``; 0: online).
    """

    tracker: str = "ddp"
    config: str = ""
    params: str = ""
    overrides: list[str] = msgspec.field(default_factory=list)
    seed: NonNegInt = 0
    snapshot_every: PosInt = 50
    resume: bool = True
    prior_from: str = ""
    lag: NonNegInt = 0
    done_by: list[str] = msgspec.field(default_factory=lambda: ["sink"])


class SinkConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The recorder: ``tracks.mcap`` (input channels + ``/tracks``) and, when the Rerun
    sink is installed and ``rerun`` is true, ``run.rrd``.  ``tracks = false`` records the
    input channels only (no tracker needed).  ``view_url``: a Rerun viewer's gRPC URL
    (``rerun+http://HOST:PORT/proxy``) that ``run.rrd``'s rows are streamed to as well
    (``launch --view`` / ``--connect URL``).  ``score``: score the frames that carry truth (OSPA,
    OSPA(2), cardinality error: the progress lines and ``sink.json`` ``scores``; its cost per frame
    is measured in docs/pipeline.md); the Rerun sink's plots need it too.
    ``outputs``: more sinks of :data:`sinks.sink.SINKS` by name, each written to its entry's
    ``filename`` in the output directory (:func:`sink_outputs` picks the sinks)."""

    mcap: bool = True
    rerun: bool = True
    tracks: bool = True
    mcap_name: str = TRACKS_NAME
    rrd_name: str = RRD_NAME
    view_url: str = ""
    score: bool = True
    outputs: list[str] = msgspec.field(default_factory=list)

    def __post_init__(self) -> None:
        from bnptrack.sinks.sink import check_sink_names

        check_sink_names(self.outputs, "sink.outputs")

    def paths(self, out: Path) -> dict[str, Path]:
        """The sinks this section records to in the output directory ``out``, with their files."""
        from bnptrack.sinks.sink import SINKS

        return sink_outputs(out / self.mcap_name if self.mcap else None,
                            out / self.rrd_name if self.rerun else None,
                            self.outputs, lambda name: out / SINKS[name].filename)


def sink_outputs(mcap: Path | None, rerun: Path | None, extra: Sequence[str],
                 place: Callable[[str], Path]) -> dict[str, Path]:
    """The sinks a run records to (names of :data:`sinks.sink.SINKS`, in order) and their
    files: the one place where the options choose them, for the pipeline's sink stage
    (:meth:`SinkConfig.paths`) and ``bnptrack track``.  ``mcap`` (``sink.mcap`` /
    ``--out``): the MCAP log; ``rerun`` (``sink.rerun`` / ``--rrd`` / ``--view`` /
    ``--connect``): the Rerun recording; ``extra`` (``sink.outputs`` / ``--sink NAME``, names
    checked at the edge by :func:`sinks.sink.check_sink_names`): more sinks, each written to
    ``place(name)``."""
    chosen: dict[str, Path] = {}
    if mcap is not None:
        chosen["mcap"] = Path(mcap)
    if rerun is not None:
        chosen["rerun"] = Path(rerun)
    for name in extra:
        chosen.setdefault(name, place(name))
    return chosen


class DeliveryConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Delivery guarantees and their bounds (see docs/pipeline.md).

    ``window``: frames held for reordering; a frame still missing when a frame ``window``
    sequence numbers later arrives is declared a gap (and rejected if it comes later).
    ``cache_frames``: samples each data publisher keeps for late joiners and restarted
    consumers (history).  ``queue_limit``: frames a consumer buffers in memory before it
    drops (and counts) new ones.  ``eos_grace_s``: after end of stream, how long a consumer
    waits without progress for missing frames before declaring them gaps.

    Bounds on what a valid-looking sample can do: a sample whose sequence number is more than
    ``max_seq_ahead`` (at least the catch-up window) past the next one a consumer expects is
    rejected and counted (no frame of a cache can be that far ahead); a frame more than
    ``max_frame_gap`` frame numbers, or ``max_gap_s`` seconds of time stamp, after the previous
    processed frame (or not after it) is rejected and counted by the tracker and the sink
    (:class:`tracker.types.FrameBounds`; ``bnptrack track --max-frame-gap / --max-gap-s``);
    after ``resync_frames`` such frames in a row that agree with each other, the stream
    resynchronises (:class:`tracker.types.FrameGate`, the rule of ``track --resync-frames``).

    ``upstream_gone_s``: a *restarted* sink or tracker (one that finds its earlier process's
    ``.part`` files or snapshot) that sees no live upstream stage for that many seconds, and no
    publisher's cache that answers, stops waiting: it finalizes what it has and exits 3, or
    exits 2 when it has nothing (docs/pipeline.md, "Restart at any moment").
    """

    window: PosInt = 32
    cache_frames: PosInt = 10_000
    queue_limit: PosInt = 100_000
    heartbeat_s: Positive = 0.1
    eos_grace_s: Positive = 2.0
    max_payload_bytes: PosInt = 16 * 2**20
    health_period_s: Positive = 1.0
    max_seq_ahead: PosInt = 100_000
    max_frame_gap: PosInt = 1000
    max_gap_s: Positive = 3600.0
    resync_frames: NonNegInt = 10
    upstream_gone_s: Positive = 5.0

    @property
    def catch_up(self) -> int:
        """The reordering window of a consumer until it has caught up with the history
        (see :class:`pipeline.stages.Sequencer`): what the caches can hold."""
        return max(self.window, self.cache_frames)


class SupervisorConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Launcher policy: restarts of a crashed stage (bounded), and shutdown timeouts."""

    max_restarts: NonNegInt = 3
    restart_backoff_s: NonNeg = 0.5
    stop_timeout_s: Positive = 15.0
    linger_s: Positive = 10.0


class PipelineConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A whole pipeline.  ``run`` empty = generated (``<scenario|log>-<time>-<hex>``);
    ``out`` empty = ``recordings/<run>``."""

    run: str = ""
    out: str = ""
    source: SourceConfig = msgspec.field(default_factory=SourceConfig)
    tracker: TrackerStageConfig = msgspec.field(default_factory=TrackerStageConfig)
    sink: SinkConfig = msgspec.field(default_factory=SinkConfig)
    delivery: DeliveryConfig = msgspec.field(default_factory=DeliveryConfig)
    zenoh: ZenohConfig = msgspec.field(default_factory=ZenohConfig)
    supervisor: SupervisorConfig = msgspec.field(default_factory=SupervisorConfig)
    stages: list[Literal["source", "tracker", "sink"]] = msgspec.field(
        default_factory=lambda: ["source", "tracker", "sink"]
    )

    def __post_init__(self) -> None:
        if self.run and not RUN_RE.match(self.run):
            raise ValueError(run_id_problem(self.run, "run"))
        if len(set(self.stages)) != len(self.stages):
            raise ValueError(f"stages {self.stages!r} lists a stage twice")


def default_pipeline() -> PipelineConfig:
    """The embedded default pipeline (synthetic vo2017 -> ddp -> sink)."""
    return PipelineConfig()


def load_pipeline(path: str | os.PathLike | None, overrides: Sequence[str] = ()) -> PipelineConfig:
    """Load a pipeline file (``.toml``, or ``.json`` as written by the launcher), or the
    default when ``path`` is None, then apply ``key=value`` overrides."""
    if path is None:
        cfg = default_pipeline()
    elif str(path).endswith(".json"):
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except FileNotFoundError:
            raise ConfigError(f"{p}: no such file") from None
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{p}: invalid JSON: {exc}") from None
        cfg = convert(data, PipelineConfig, str(p))
    else:
        cfg = load_toml(path, PipelineConfig)
    return apply_pipeline_overrides(cfg, overrides)


def split_pipeline_overrides(overrides: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Route ``--set`` items of a pipeline command to (pipeline keys, tracker model keys).

    The keys mean what they mean in ``bnptrack track``, plus the pipeline's own tables:

    * ``source.KEY``, ``sink.KEY``, ``delivery.KEY``, ``zenoh.KEY``, ``supervisor.KEY`` and
      the top-level ``run``, ``out``, ``stages``: the pipeline file's keys;
    * ``tracker.KEY`` where KEY is a field of :class:`TrackerStageConfig` (``tracker``,
      ``config``, ``params``, ``overrides``, ``seed``, ...): the tracker stage;
    * ``tracker.KEY`` for any other KEY (a tracker setting, e.g. ``tracker.sweeps``),
      ``params.KEY`` (a model parameter) and a bare ``KEY``: the tracker's ``--set`` items,
      appended to ``tracker.overrides`` and resolved as in ``track`` (a bare KEY: model
      parameters first, then the tracker's settings), so ``--set p_detect=0.9`` sets the
      tracker's model.  (The simulated source's model is ``source.overrides``.)
    """
    top = set(PipelineConfig.__struct_fields__)
    stage_keys = set(TrackerStageConfig.__struct_fields__)
    to_pipe: list[str] = []
    to_model: list[str] = []
    for item in overrides:
        key, _value = split_item(item)
        head, dot, rest = key.partition(".")
        if head == "tracker" and dot and rest.partition(".")[0] not in stage_keys:
            to_model.append(item.strip())
        elif head in top:
            to_pipe.append(item)
        else:
            to_model.append(item.strip())
    return tuple(to_pipe), tuple(to_model)


#: Where an unknown pipeline key's error sends the user.
PIPELINE_KEYS_LISTED_IN = "docs/pipeline.md, 'The pipeline file', lists the keys"


def apply_pipeline_overrides(cfg: PipelineConfig, overrides: Sequence[str]) -> PipelineConfig:
    """Apply ``--set`` items (see :func:`split_pipeline_overrides`); the tracker's items
    are appended to ``tracker.overrides`` (checked by :mod:`pipeline.preflight`)."""
    to_pipe, to_model = split_pipeline_overrides(overrides)
    try:
        cfg = apply_overrides(cfg, to_pipe, listed_in=PIPELINE_KEYS_LISTED_IN)
    except ValueError as exc:  # __post_init__ errors surface as ValidationError -> ConfigError
        raise ConfigError(str(exc)) from None
    if to_model:
        tc = msgspec.structs.replace(cfg.tracker, overrides=[*cfg.tracker.overrides, *to_model])
        cfg = msgspec.structs.replace(cfg, tracker=tc)
    return cfg


def dump_pipeline(cfg: PipelineConfig) -> bytes:
    """JSON of a pipeline (what the launcher hands to its stages)."""
    return msgspec.json.format(msgspec.json.encode(cfg), indent=2)


def run_id_problem(run: str, name: str = "run id") -> str:
    """The one-line error of a run id that is not one Zenoh key chunk (:data:`RUN_RE`), naming it
    as ``name`` (``--run``, ``run``)."""
    return (f"{name} {run!r}: letters, digits, '_', '.', '-' (first a letter or digit), at most 128 "
            "characters (a run id is one Zenoh key chunk)")


def check_run_id(run: str, name: str = "run id") -> str:
    """``run``, unless it is no run id (:func:`run_id_problem`: a :class:`ConfigError`)."""
    if not RUN_RE.match(run):
        raise ConfigError(run_id_problem(run, name))
    return run


def make_run_id(cfg: PipelineConfig) -> str:
    """A fresh run id: the scenario (or log stem), the local time and 4 random hex digits."""
    if cfg.source.kind == "mcap" and cfg.source.log:
        base = Path(cfg.source.log).stem
    else:
        base = cfg.source.scenario
    base = re.sub(r"[^A-Za-z0-9_.\-]", "_", base)[:64] or "run"
    return f"{base}-{time.strftime('%Y%m%d-%H%M%S')}-{secrets.token_hex(2)}"


def resolve_run(cfg: PipelineConfig) -> PipelineConfig:
    """Fill in ``run`` (generated when empty) and ``out`` (``recordings/<run>`` when empty)."""
    run = check_run_id(cfg.run) if cfg.run else make_run_id(cfg)
    out = cfg.out or str(Path("recordings") / run)
    return msgspec.structs.replace(cfg, run=run, out=out)
