"""Resolving what a tracking run uses: model parameters, tracker settings, ``--set`` overrides,
the tracker itself and the output record (:func:`tracker_setup`).

``bnptrack track``, the pipeline's tracker stage and the experiments all build their tracker
through :func:`tracker_setup`, so the order "params -> settings -> overrides -> tracker ->
metadata" is written once.  Scenarios (simulation) are opened by
:func:`sources.scenarios.open_scenario`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from bnptrack.sources.frame_window import WINDOW_KEYS, FrameWindow
from bnptrack.sources.scenarios import adapting_scenario, format_overrides, parse_overrides, with_snr
from bnptrack.tracker.config import CLI_NAMES, ArgNames, ConfigError, apply_overrides, did_you_mean, load_toml, split_item
from bnptrack.tracker.models.params import ModelParams, load_params
from bnptrack.tracker.registry import TRACKERS

__all__ = [
    "DEFAULT_PARAMS",
    "TRACKERS",
    "ParamsChoice",
    "TrackerSetup",
    "run_params",
    "tracker_setup",
    "resolve_params",
    "resolve_config",
    "split_overrides",
    "apply_split_overrides",
    "window_overrides",
    "build_tracker",
    "tracker_settings_fields",
]

#: Parameter set used when neither ``--params`` nor the log says which one.
DEFAULT_PARAMS = "vo2017"


# --------------------------------------------------------------------------- overrides


def tracker_settings_fields(config_cls: type[msgspec.Struct] | None = None) -> tuple[str, ...]:
    """The settings fields of ``config_cls``; ``None``: of every tracker of the registry
    (:mod:`tracker.registry`), in registry order without repeats."""
    if config_cls is not None:
        return tuple(config_cls.__struct_fields__)
    from bnptrack.tracker.registry import kind

    classes = dict.fromkeys(kind(name).config_cls for name in TRACKERS)
    return tuple(dict.fromkeys(f for cls in classes for f in cls.__struct_fields__))


def split_overrides(
    overrides: Sequence[str], config_cls: type[msgspec.Struct] | None = None, names: ArgNames = CLI_NAMES
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Route ``--set`` items to (model parameters, tracker settings).

    ``params.KEY=V`` goes to :class:`ModelParams`, ``tracker.KEY=V`` to the tracker's settings
    (``config_cls``; ``None``: a field of any registered tracker's settings); a bare ``KEY=V``
    goes to whichever has the field (``ModelParams`` first).  Raises :class:`ConfigError`
    naming the key (and the item, as ``names`` say) when neither has it: the closest keys and
    where the full list is.
    """
    p_fields, t_fields = tuple(ModelParams.__struct_fields__), tracker_settings_fields(config_cls)
    to_params: list[str] = []
    to_tracker: list[str] = []
    for item in overrides:
        key, value = split_item(item, names)
        head, dot, rest = key.partition(".")
        if dot and head == "params":
            to_params.append(f"{rest}={value}")
        elif dot and head == "tracker":
            to_tracker.append(f"{rest}={value}")
        elif head in p_fields:
            to_params.append(f"{key}={value}")
        elif head in t_fields:
            to_tracker.append(f"{key}={value}")
        else:
            raise ConfigError(
                f"{names.set_item.format(item)}: unknown key '{key}'{did_you_mean(head, p_fields + t_fields, 3)}: "
                "not a model parameter nor a tracker setting (docs/models.md lists the model parameters, "
                "docs/trackers.md the tracker settings); use params.KEY or tracker.KEY to be explicit"
            )
    return tuple(to_params), tuple(to_tracker)


def window_overrides(overrides: Sequence[str], window: FrameWindow) -> tuple[FrameWindow, tuple[str, ...]]:
    """Take the ``source.KEY=V`` items of an offline command's ``--set`` (the keys of
    :class:`sources.frame_window.FrameWindow`, as in ``replay``'s pipeline file) and apply them
    to ``window``; return it (checked) and the other items.  ``source.`` keys that only a
    pipeline has (``rate``, ``log``, ...) and ``sink.`` keys are :class:`ConfigError` naming the
    item and what the command uses instead."""
    rest: list[str] = []
    for item in overrides:
        key, value = split_item(item)
        head, dot, name = key.partition(".")
        if dot and head == "source":
            if name not in WINDOW_KEYS:
                raise ConfigError(f"--set {item!r}: an offline run reads its log's frames as fast as it can; "
                                  f"its source keys are {', '.join(WINDOW_KEYS)}")
            try:
                window = apply_overrides(window, [f"{name}={value}"])
            except ConfigError as exc:  # "--set overrides: Expected ... at $.frames": name the item
                raise ConfigError(f"--set {item!r}: {str(exc).partition(': ')[2]}") from None
        elif dot and head == "sink":
            raise ConfigError(f"--set {item!r}: an offline run chooses its outputs with --out, --rrd and --sink")
        else:
            rest.append(item)
    try:
        window.check("source.")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return window, tuple(rest)


def apply_split_overrides(
    params: ModelParams, config: msgspec.Struct, overrides: Sequence[str], names: ArgNames = CLI_NAMES
) -> tuple[ModelParams, msgspec.Struct]:
    """Apply ``--set`` overrides to both structs (see :func:`split_overrides`); errors name
    the items as ``names`` say."""
    p_over, t_over = split_overrides(overrides, type(config), names)
    typed = {"params": [], "tracker": []}  # each item as the user typed it, for the errors
    for item in overrides:
        head, dot, _ = split_item(item, names)[0].partition(".")
        dest = head if dot and head in typed else ("params" if head in ModelParams.__struct_fields__ else "tracker")
        typed[dest].append(item)
    return (apply_overrides(params, p_over, typed["params"], names, "docs/models.md lists the keys"),
            apply_overrides(config, t_over, typed["tracker"], names, "docs/trackers.md lists the keys"))


# --------------------------------------------------------------------------- params


@dataclass(frozen=True)
class ParamsChoice:
    """The model parameters a command uses, and where they came from.

    ``source`` is the built-in name or file path; ``reason`` a short human explanation
    (e.g. ``"from --params"``, ``"from the log's bnptrack.scenario record"``).
    """

    params: ModelParams
    source: str
    reason: str
    overrides: tuple[str, ...] = ()
    warning: str | None = None
    """What the user should know before tracking (one line), e.g. an unknown scenario."""

    def describe(self, final: ModelParams | None = None, overrides: Sequence[str] = ()) -> str:
        """One line: source, reason, the log's overrides, extra ``--set`` items and the SNR
        of ``final`` (the parameters after those items; default: :attr:`params`)."""
        final = self.params if final is None else final
        extra = []
        if self.overrides:
            extra.append("log overrides " + " ".join(self.overrides))
        if overrides:
            extra.append("--set " + " ".join(overrides))
        set_keys = {o.partition("=")[0].strip() for o in overrides}
        if final.snr_db is not None and "snr_db" not in set_keys:
            extra.append(f"snr_db {final.snr_db:g}")
        tail = f"; {'; '.join(extra)}" if extra else ""
        return f"{self.source} ({self.reason}{tail})"


def resolve_params(
    params_arg: str | None, metadata: Mapping[str, str] | None, names: ArgNames = CLI_NAMES
) -> ParamsChoice:
    """Model parameters for tracking a log.

    1. ``params_arg`` (``--params NAME|FILE.toml``) when given;
    2. else the log's ``bnptrack.scenario`` record: its ``params`` value, its ``overrides``
       (the ``--set`` items used when simulating) and its ``snr_db``;
    3. else the :data:`DEFAULT_PARAMS` set.

    When the record names a known scenario, its defaults are applied as ``simulate`` applied
    them (:meth:`Scenario.adapt_params`: birth regions, none for the generated families, SNR,
    range clutter), in every case.
    """
    meta = dict(metadata or {})
    if params_arg:
        choice = ParamsChoice(load_params(params_arg, names=names), params_arg,
                              f"from {names.params.format(params_arg)}")
    elif meta.get("params"):
        choice = _params_from_record(meta)
    else:
        why = (
            "default: the log has no bnptrack.scenario record"
            if metadata is None
            else "default: the log's bnptrack.scenario record names no params"
        )
        choice = ParamsChoice(load_params(DEFAULT_PARAMS), DEFAULT_PARAMS, why)
    return _adapt_to_scenario(choice, meta.get("scenario"))


def _params_from_record(meta: Mapping[str, str]) -> ParamsChoice:
    name = meta["params"]
    overrides = parse_overrides(meta.get("overrides"))
    try:
        p = load_params(name, overrides)
        snr = meta.get("snr_db")
        p = with_snr(p, float(snr) if snr not in (None, "") else None)
    except (ConfigError, ValueError) as exc:
        raise ConfigError(
            f"params {name!r} named by the log's bnptrack.scenario record: {exc} "
            "(pass --params NAME|FILE.toml)"
        ) from None
    return ParamsChoice(p, name, "from the log's bnptrack.scenario record", overrides)


def _adapt_to_scenario(choice: ParamsChoice, scenario: str | None) -> ParamsChoice:
    """Apply the defaults of the scenario a log's record names.  An unknown name changes
    nothing, and says so: its birth regions, SNR and clutter defaults cannot be applied."""
    if not scenario:
        return choice
    try:
        sc = adapting_scenario(scenario)
    except ConfigError:
        return ParamsChoice(choice.params, choice.source, f"{choice.reason}; scenario {scenario!r}: unknown",
                            choice.overrides,
                            f"the log's record names an unknown scenario {scenario!r}, so no scenario defaults "
                            "(birth regions, SNR, range clutter) are applied; give --params FILE.toml with "
                            "[[birth]] regions if new objects appear only in known places")
    params = sc.adapt_params(choice.params)
    regions = f"{len(params.birth)} birth regions" if params.birth else "no birth regions"
    return ParamsChoice(params, choice.source, f"{choice.reason}; scenario {scenario}: {regions}",
                        choice.overrides)


# --------------------------------------------------------------------------- tracker config


def resolve_config(tracker: str, config_arg: str | None) -> tuple[msgspec.Struct, str]:
    """Tracker settings: a preset name or a TOML file of the tracker's settings fields;
    default: the preset named like the tracker.  Returns ``(config, description)``."""
    from bnptrack.tracker.registry import kind

    try:
        k = kind(tracker)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if not config_arg:
        return k.presets[tracker], f"preset {tracker} (default for --tracker {tracker})"
    if config_arg in k.presets:
        return k.presets[config_arg], f"preset {config_arg}"
    if config_arg.endswith(".toml") or Path(config_arg).exists():
        return load_toml(config_arg, k.config_cls), f"file {config_arg}"
    raise ConfigError(
        f"--config {config_arg!r}: not a preset of {tracker} ({', '.join(k.presets)}) nor a .toml file"
    )


def build_tracker(name: str, params: ModelParams, config: msgspec.Struct):
    """The tracker ``name`` (see :mod:`tracker.registry`) with these parameters and settings."""
    from bnptrack.tracker.registry import build

    try:
        return build(name, params, config)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


# --------------------------------------------------------------------------- the one resolver


@dataclass(frozen=True)
class TrackerSetup:
    """A tracker ready to run, and how it was chosen (:func:`tracker_setup`)."""

    tracker: Any
    """The built tracker (:class:`tracker.registry.Tracker`)."""
    name: str
    params: ModelParams
    """The model parameters after the ``--set`` items."""
    config: msgspec.Struct
    """The tracker settings after the ``--set`` items."""
    choice: ParamsChoice
    config_desc: str
    overrides: tuple[str, ...]
    metadata: dict[str, str]
    """The output's ``bnptrack.scenario`` record: the input's plus tracker, tracker_seed,
    tracker_params, tracker_config and (with overrides) tracker_overrides."""

    @property
    def set_sensors(self) -> dict[str, str]:
        """The sensors whose ``[sensors.NAME]`` table only the ``--set`` items declare: name ->
        the first such item, as typed (named by :func:`tracker.input_checks.check_frames`)."""
        out: dict[str, str] = {}
        for item in self.overrides:
            parts = split_item(item)[0].removeprefix("params.").split(".")
            if len(parts) >= 2 and parts[0] == "sensors" and parts[1] not in self.choice.params.sensors:
                out.setdefault(parts[1], item)
        return out

    def describe_params(self) -> str:
        """The params line of ``bnptrack track``'s header (with the ``--set`` items of the params)."""
        p_over, _ = split_overrides(self.overrides, type(self.config))
        return self.choice.describe(self.params, p_over)

    def describe_config(self) -> str:
        """The config line of ``bnptrack track``'s header (with the ``--set`` items of the settings)."""
        _, t_over = split_overrides(self.overrides, type(self.config))
        return self.config_desc + (f"; --set {' '.join(t_over)}" if t_over else "")


def tracker_setup(
    tracker: str,
    *,
    params: str | ModelParams | None = None,
    config: str | None = None,
    overrides: Sequence[str] = (),
    metadata: Mapping[str, str] | None = None,
    seed: int = 0,
    names: ArgNames = CLI_NAMES,
) -> TrackerSetup:
    """Resolve and build tracker ``tracker`` (a :mod:`tracker.registry` name).

    1. model parameters: ``params`` (a name or TOML file; a :class:`ModelParams` is used as
       given), else the input's ``metadata`` record (:func:`resolve_params`);
    2. settings: the preset or TOML file ``config``, default the preset named like the tracker;
    3. the ``--set`` items ``overrides`` (:func:`split_overrides`);
    4. the tracker (:func:`build_tracker`) and the output record (input ``metadata`` plus the
       tracker's name, ``seed``, params source, config and overrides).

    Raises :class:`ConfigError` for anything that does not resolve, naming ``params`` and
    ``overrides`` as ``names`` say (the command line's options, or a Python call's arguments).
    """
    if isinstance(params, ModelParams):
        choice = ParamsChoice(params, "given", "given by the caller")
    else:
        choice = resolve_params(params or None, metadata, names)
    settings, config_desc = resolve_config(tracker, config or None)
    final_params, settings = apply_split_overrides(choice.params, settings, overrides, names)
    built = build_tracker(tracker, final_params, settings)
    out_meta = dict(metadata or {})
    out_meta.update(tracker=tracker, tracker_seed=str(seed), tracker_params=choice.source,
                    tracker_config=config or tracker)
    if overrides:
        out_meta["tracker_overrides"] = format_overrides(overrides)
    return TrackerSetup(built, tracker, final_params, settings, choice, config_desc, tuple(overrides), out_meta)


def run_params(record: Mapping[str, str] | None, announced: Mapping[str, Any] | None) -> ModelParams | None:
    """The model parameters a run's tracker used, for a consumer of its output (the sink
    stage draws the sensor's field of view with them): ``announced``, the tracker's
    :func:`tracker_setup` result as builtins (its ``info``), else the input ``record``
    resolved as :func:`resolve_params` does; ``None`` if neither resolves."""
    try:
        if announced is not None:
            return msgspec.convert(announced, ModelParams)
        return resolve_params(None, record).params
    except (ConfigError, ValueError, msgspec.ValidationError):
        return None
