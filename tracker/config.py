"""Typed configuration: msgspec structs loaded from TOML with ``key=value`` overrides.

Every configurable thing in bnptrack (model parameter sets, tracker settings, pipeline files)
is a frozen ``msgspec.Struct``.  This module loads one from a TOML file or a built-in name and
applies ``--set key=value`` overrides (dotted keys for nested structs; values are TOML
literals, e.g. ``--set p_detect=0.9 --set gibbs.sweeps=30 --set name='"x"'``; a value that is
not a TOML literal is taken as a plain string).  Errors name the offending key and source.
"""

from __future__ import annotations

import difflib
import json
import re
import tomllib
import types as types_mod
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, TypeVar

import msgspec
import msgspec.inspect

S = TypeVar("S", bound=msgspec.Struct)

# --- constraint aliases: the validated scalar types of every config struct ----------------
NonNegInt = Annotated[int, msgspec.Meta(ge=0)]
PosInt = Annotated[int, msgspec.Meta(ge=1)]
#: The largest value of a non-negative or positive setting: every setting is finite, and its
#: square (a variance of a standard deviation) stays far from overflowing.
FINITE_MAX = 1e12
NonNeg = Annotated[float, msgspec.Meta(ge=0.0, le=FINITE_MAX)]
"""A finite value ``0 <= x <= 1e12``."""
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=FINITE_MAX)]
"""A finite value ``0 < x <= 1e12``."""
#: The largest mean clutter per scan: a million false alarms a scan is no tracking scene, and the
#: simulator draws every one of them (a larger rate would fill the machine's memory).
CLUTTER_MAX = 1e6
ClutterRate = Annotated[float, msgspec.Meta(ge=0.0, le=CLUTTER_MAX)]
"""A mean clutter count per scan, ``0 <= x <= 1e6``."""
#: The most Gibbs sweeps (or chain steps) per frame: the default is 6-30, and each sweep's
#: random numbers are drawn before it (a billion would fill the machine's memory).
SWEEPS_MAX = 10_000
Sweeps = Annotated[int, msgspec.Meta(ge=1, le=SWEEPS_MAX)]
"""A number of sweeps per frame, ``1 <= n <= 10000``."""
#: The most GLMB hypotheses requested or kept per frame: the default is 500-1,000, and every
#: requested hypothesis is sampled and held (a billion would fill the machine's memory).
HYPOTHESES_MAX = 100_000
Hypotheses = Annotated[int, msgspec.Meta(ge=1, le=HYPOTHESES_MAX)]
"""A number of hypotheses per frame, ``1 <= n <= 100000``."""
Prob = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
"""A probability, ``0 <= p <= 1``."""
OpenProb = Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)]
"""A probability strictly inside ``(0, 1)``."""
Fraction = Annotated[float, msgspec.Meta(ge=0.0, lt=1.0)]
"""A fraction in ``[0, 1)`` (a discount, a decay, a threshold below 1)."""
PositiveProb = Annotated[float, msgspec.Meta(gt=0.0, le=1.0)]
"""A positive probability or weight in ``(0, 1]`` (a forgetting factor, a ratio)."""
StateList = Annotated[list[float], msgspec.Meta(min_length=5, max_length=5)]
"""A 5-vector ``[x, vx, y, vy, omega]`` (or its standard deviations) as a list."""
HalfFovDeg = Annotated[float, msgspec.Meta(gt=0.0, le=180.0)]
"""Half-width of a field of view in degrees, ``(0, 180]``."""


@dataclass(frozen=True)
class ArgNames:
    """How an error names the user's inputs: the command line's options (:data:`CLI_NAMES`)
    or a Python call's arguments (:data:`PYTHON_NAMES`).  Each is a ``str.format`` template of
    the value as typed."""

    set_item: str = "--set {!r}"
    """One ``--set`` item."""
    set_all: str = "--set overrides"
    """All of them."""
    params: str = "--params {!r}"
    """The parameter set named."""


CLI_NAMES = ArgNames()
PYTHON_NAMES = ArgNames("overrides item {!r}", "overrides", "params={!r}")


#: An unknown key's error lists the known ones when there are at most this many (else the
#: closest and where the list is).
KNOWN_LISTED = 12


class ConfigError(ValueError):
    """A configuration file, name or override is invalid."""


def parse_value(text: str) -> Any:
    """Parse an override value as a TOML literal, falling back to a plain string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def did_you_mean(key: str, known: Sequence[str], n: int = 1, prefix: str = "", cutoff: float = 0.6) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``known`` to ``key`` (difflib, similarity at
    least ``cutoff``; up to ``n`` of them, closest first: `` (did you mean 'x', 'y' or 'z'?)``),
    else ``""``; each shown after ``prefix`` (the dotted table of a nested key:
    ``'tracker.sweeps'``)."""
    close = [f"'{prefix}{c}'" for c in difflib.get_close_matches(key, list(known), n=n, cutoff=cutoff)]
    if not close:
        return ""
    return f" (did you mean {', '.join(close[:-1])} or {close[-1]}?)" if len(close) > 1 else f" (did you mean {close[0]}?)"


#: Where an unknown key's error sends the user when the known keys are too many to list.
KEYS_LISTED_IN = "docs/models.md and docs/trackers.md list the keys"


@dataclass(frozen=True)
class _Item:
    """One ``--set`` item being applied: how errors name it (``origin``, the key as typed
    ``shown``, its value's text), where the keys are listed, and the struct type it sets."""

    origin: str
    shown: str
    text: str
    listed_in: str
    cls: type
    names: ArgNames


def _set_dotted(data: dict[str, Any], key: str, value: Any, item: _Item) -> None:
    """Set ``data[a][b]...= value`` for ``key = "a.b..."``.  A missing table of a name-keyed
    table (a dict field such as ``sensors``: ``--set sensors.radar0.x=5``) is created; each key
    is checked against the struct type at its place (``item.cls``).  Errors name the key as
    typed and the close known key."""
    parts = key.split(".")
    node, tp = data, _unwrap(msgspec.inspect.type_info(item.cls))
    for i, part in enumerate(parts[:-1]):
        child, child_tp = node.get(part), _unwrap(_child(tp, part))
        if child is None and part not in node and isinstance(tp, msgspec.inspect.DictType) and _is_table(child_tp):
            child = node[part] = {}
        if not isinstance(child, dict):
            raise ConfigError(f"{item.origin}: '{'.'.join(parts[: i + 1])}' is not a table"
                              + (did_you_mean(part, list(node), prefix="".join(f"{q}." for q in parts[:i]))
                                 if part not in node else ""))
        node, tp = child, child_tp
    _check_last(node, tp, parts[-1], value, item)
    node[parts[-1]] = value


def _check_last(node: dict[str, Any], tp: Any, last: str, value: Any, item: _Item) -> None:
    """Raise :class:`ConfigError` unless ``last`` is a key of the table ``node`` (of type ``tp``)
    that may take ``value``: a known field of a struct, any name of a name-keyed table (whose
    tables take a table, not a value)."""
    typed = item.shown
    if isinstance(tp, msgspec.inspect.DictType):
        if _is_table(_unwrap(tp.value_type)) and not isinstance(value, dict):
            fields = _fields(_unwrap(tp.value_type))
            example = item.names.set_item.format(f"{typed}.{_example_key(_unwrap(tp.value_type), value)}={item.text}")
            raise ConfigError(f"{item.origin}: '{typed}' is a table of keys, not a value: set one of its keys, "
                              f"e.g. {example}" + (f" (its keys: {', '.join(fields)})" if fields else ""))
        return
    known = _fields(tp) if isinstance(tp, msgspec.inspect.StructType) else list(node)
    if last in known:
        return
    where = f"known here: {', '.join(sorted(known)) or '(none)'}" if len(known) <= KNOWN_LISTED else item.listed_in
    table = typed.rsplit(".", 1)[0] + "." if "." in typed else ""
    raise ConfigError(f"{item.origin}: unknown key '{typed}'{did_you_mean(last, known, 3, table)} ({where})")


def _example_key(node: Any, value: Any) -> str:
    """The first key of the struct type ``node`` that takes ``value`` (``KEY`` if none does)."""
    fields = msgspec.structs.fields(node.cls) if isinstance(node, msgspec.inspect.StructType) else ()
    return next((f.encode_name for f in fields if _valid(value, f.type)), "KEY")


def _unwrap(node: Any) -> Any:
    """An optional type's non-None member (else ``node``)."""
    while isinstance(node, msgspec.inspect.UnionType):
        node = next((t for t in node.types if not isinstance(t, msgspec.inspect.NoneType)), None)
    return node


def _is_table(node: Any) -> bool:
    """``node`` (a msgspec type) is a table: a struct or a dict."""
    return isinstance(node, (msgspec.inspect.StructType, msgspec.inspect.DictType))


def _fields(node: Any) -> list[str]:
    """The keys of the struct type ``node`` (none for another type)."""
    return [f.encode_name for f in node.fields] if isinstance(node, msgspec.inspect.StructType) else []


def split_item(item: str, names: ArgNames = CLI_NAMES) -> tuple[str, str]:
    """``KEY=VALUE`` -> ``(KEY, VALUE)``, both stripped; :class:`ConfigError` names the item
    (as ``names`` say) when it has no ``=`` or no key (the one parser of every ``--set`` item)."""
    key, sep, value = item.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"{names.set_item.format(item)}: expected key=value")
    return key.strip(), value.strip()


def apply_overrides(obj: S, overrides: Sequence[str], typed: Sequence[str] = (),
                    names: ArgNames = CLI_NAMES, listed_in: str = KEYS_LISTED_IN) -> S:
    """Return a copy of ``obj`` with ``key=value`` overrides applied and re-validated.
    ``typed``: the same items as the user typed them (e.g. ``tracker.sweeps=10`` for
    ``sweeps=10``), named in the errors instead; ``names``: how the errors name the items;
    ``listed_in``: where an unknown key's error says the keys of ``obj`` are documented."""
    if not overrides:
        return obj
    data = msgspec.to_builtins(obj)
    shown = list(typed) if len(typed) == len(overrides) else list(overrides)
    keys = {}
    for item, as_typed in zip(overrides, shown):
        key, text = split_item(item, names)
        _set_dotted(data, key, parse_value(text), _Item(names.set_item.format(as_typed), split_item(as_typed, names)[0],
                                                        text, listed_in, type(obj), names))
        keys[key] = as_typed
    try:
        return msgspec.convert(data, type(obj))
    except msgspec.ValidationError as exc:
        raise ConfigError(_blame(_valid_values(concrete_path(str(exc), data, type(obj)), type(obj)), keys,
                                 names)) from None


_AT = re.compile(r"^(?P<what>.*) - at `\$\.(?P<path>[^`]*)`$")
#: A struct's own check of one key (``__post_init__``): ``[sensors.radar0] kind = 'x' is ...``.
_TABLE_KEY = re.compile(r"^\[(?P<table>[^\]]+)\] (?P<key>[A-Za-z0-9_]+) = ")
#: A struct's own check naming its key first: ``source.scenario: unknown ...``, ``run 'x': ...``.
_LEADING_KEY = re.compile(r"^(?P<key>[A-Za-z_][A-Za-z0-9_.]*)(?=: | ')")


def _blame(message: str, keys: dict[str, str], names: ArgNames) -> str:
    """A validation error of overridden data, naming the ``--set`` item (as typed) whose key
    holds the bad value (``--set 'p_detect=1.5': expected `float` <= 1.0``); all items when
    the value at fault is none of theirs."""
    m, t = _AT.match(message), _TABLE_KEY.match(message)
    path, what = (m["path"], m["what"]) if m else (f"{t['table']}.{t['key']}", message) if t else ("", "")
    lead = _LEADING_KEY.match(message)
    if not path and lead and lead["key"] in keys:  # a struct's own check that names its key first
        path, what = lead["key"], message.removeprefix(f"{lead['key']}: ")
        if what.startswith(f"{path} '") and "': " in what:  # "run 'x': ..." -> "...": the item says the value
            what = what.split("': ", 1)[1]
    if path:
        for key, as_typed in keys.items():
            # the item's own value, or the table holding it (a check across the table's keys)
            if path == key or path.startswith((f"{key}.", f"{key}[")) or key.startswith(f"{path}."):
                return f"{names.set_item.format(as_typed)}: {what[:1].lower()}{what[1:]}"
    return f"{names.set_all}: {message}"


def convert(data: dict[str, Any], cls: type[S], origin: str) -> S:
    """Validate plain data into ``cls``; errors name ``origin`` and the field path."""
    try:
        return msgspec.convert(data, cls)
    except msgspec.ValidationError as exc:
        message = _valid_values(concrete_path(str(exc), data, cls), cls)
        raise ConfigError(f"{origin}: {_unknown_field(message, cls) or message}") from None


_AT_PATH = re.compile(r" - at `\$(?P<path>[^`]*)`$")
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def concrete_path(message: str, data: Any, cls: type) -> str:
    """msgspec's error ``message`` about plain ``data`` validated into ``cls``, with each
    ``[...]`` of its path (a key of a dict: ``$.sensors[...].x``) replaced by the key whose
    value fails (``$.sensors.radar0.x``); ``message`` itself when there is none to replace."""
    m = _AT_PATH.search(message)
    if m is None or "[...]" not in m["path"]:
        return message
    out, node, tp = [], data, cls
    for part in re.findall(r"\.[^.\[\]]+|\[\d+\]|\[\.\.\.\]", m["path"]):
        tp = _py_unwrap(tp)
        args = typing.get_args(tp)
        if part == "[...]" and isinstance(node, dict) and len(args) == 2:
            key = next((k for k, v in node.items() if not _valid(v, args[1])), None)
            if key is None:
                return message
            out.append(f".{key}" if _BARE_KEY.fullmatch(str(key)) else f".{json.dumps(str(key))}")
            node, tp = node[key], args[1]
        elif part.startswith("[") and part != "[...]" and isinstance(node, list) and args:
            node, tp = node[int(part[1:-1])], args[0]
            out.append(part)
        elif part.startswith(".") and isinstance(node, dict) and isinstance(tp, type) and issubclass(tp, msgspec.Struct):
            types = {f.encode_name: f.type for f in msgspec.structs.fields(tp)}
            node, tp = node.get(part[1:]), types.get(part[1:])
            out.append(part)
        else:
            return message
    return f"{message[: m.start()]} - at `${''.join(out)}`"


def _py_unwrap(tp: Any) -> Any:
    """The type inside ``Annotated`` and optional (``X | None``) annotations."""
    while True:
        origin = typing.get_origin(tp)
        if origin is typing.Annotated:
            tp = typing.get_args(tp)[0]
        elif origin in (typing.Union, types_mod.UnionType):
            tp = next(a for a in typing.get_args(tp) if a is not type(None))
        else:
            return tp


def _valid(value: Any, tp: Any) -> bool:
    """``value`` validates as ``tp``."""
    try:
        msgspec.convert(value, tp)
    except msgspec.ValidationError:
        return False
    return True


_BAD_ENUM = re.compile(r"(?P<what>Invalid enum value (?P<value>.*?)) - at `\$(?P<at>[^`]*)`")


def _valid_values(message: str, cls: type) -> str:
    """msgspec's invalid-enum error with the valid values of the field at its path and the
    close one (``Invalid enum value 'mcp', not one of synthetic, mcap (did you mean 'mcap'?)``);
    any other error unchanged."""
    m = _BAD_ENUM.fullmatch(message)
    if m is None:
        return message
    node = _type_at(cls, m["at"])
    values = ([str(v) for v in node.values] if isinstance(node, msgspec.inspect.LiteralType) else
              [str(v.value) for v in node.cls] if isinstance(node, msgspec.inspect.EnumType) else [])
    if not values:
        return message
    typed = m["value"].strip("'\"")
    return (f"{m['what']}, not one of {', '.join(values)}{did_you_mean(typed, values)} - at `${m['at']}`")


_UNKNOWN_FIELD = re.compile(r"Object contains unknown field `(?P<key>[^`]+)`(?: - at `\$(?P<at>[^`]*)`)?")


def _unknown_field(message: str, cls: type) -> str:
    """msgspec's unknown-field error as ``unknown key 'x' in [table] (did you mean 'y'?)``
    (the known keys are those of the struct at that path); ``""`` for any other error."""
    m = _UNKNOWN_FIELD.fullmatch(message)
    if m is None:
        return ""
    key, at = m["key"], (m["at"] or "").lstrip(".")
    known = _fields(_type_at(cls, at))
    where = f" in {at}" if "[" in at else f" in [{at}]" if at else ""
    hint = did_you_mean(key, known) or (f" (known: {', '.join(known)})" if 0 < len(known) <= KNOWN_LISTED else "")
    return f"unknown key '{key}'{where}{hint}"


def _type_at(cls: type, at: str) -> Any:
    """The msgspec type (optional types unwrapped) at the error path ``at`` (``.source.kind``,
    ``sensors.radar0.x``, ``topics[0]``) inside ``cls``."""
    node: Any = msgspec.inspect.type_info(cls)
    for part in re.findall(r"[^.\[\]]+|\[\d+\]", at.lstrip(".")):
        node = _child(node, part)
    return _unwrap(node)


def _child(node: Any, part: str) -> Any:
    """The type of ``part`` (a field name, a dict key or a ``[i]`` index) inside ``node``."""
    ins = msgspec.inspect
    node = _unwrap(node)  # an optional table: its non-None member
    if isinstance(node, ins.StructType):
        return next((f.type for f in node.fields if f.encode_name == part), None)
    if isinstance(node, ins.DictType):
        return node.value_type
    if isinstance(node, (ins.ListType, ins.TupleType, ins.VarTupleType)) and part.startswith("["):
        return getattr(node, "item_type", None)
    return None


def read_toml(path: str | Path) -> dict[str, Any]:
    """The plain data of a TOML file; :class:`ConfigError` names a missing or malformed file."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: a folder, not a TOML file") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a TOML file (binary data{_looks_like(path)})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None


def _looks_like(path: Path) -> str:
    """``"; it is an MCAP log"`` for a file starting with the MCAP magic, else ``""``."""
    with open(path, "rb") as f:
        return "; it is an MCAP log" if f.read(5) == b"\x89MCAP" else ""


def load_toml(path: str | Path, cls: type[S]) -> S:
    """Load and validate a TOML file into ``cls``."""
    return convert(read_toml(path), cls, str(path))
