"""TOML -> frozen dataclasses, with errors that name the file, the key and what was expected.

A dataclass field declares its unit and range with :func:`spec`; :func:`load` walks the
TOML table against the dataclass, refusing unknown keys (with a "did you mean"),
missing keys, wrong types, non-finite numbers and out-of-range values.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


class ConfigError(ValueError):
    """A configuration file is missing, malformed or has a bad value."""


def spec(
    unit: str = "",
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    default: Any = dataclasses.MISSING,
    choices: tuple[str, ...] = (),
) -> Any:
    """Declare a config field: its unit and its admissible range (``lo_open`` excludes ``lo``)."""
    meta = {"unit": unit, "lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices}
    if default is dataclasses.MISSING:
        return dataclasses.field(metadata=meta)
    if isinstance(default, (list, dict)):
        raise TypeError("mutable default")
    return dataclasses.field(default=default, metadata=meta)


def resolve(path: str | Path, base: Path = CONFIG_DIR) -> Path:
    """A config path as given, else relative to ``base`` (the repository's configs/)."""
    p = Path(path)
    if p.is_file():
        return p
    q = base / p
    if q.is_file():
        return q
    raise ConfigError(f"{path}: no such config file (looked in . and {base})")


def read_toml(path: str | Path) -> tuple[Path, dict[str, Any]]:
    p = resolve(path)
    try:
        with p.open("rb") as fh:
            return p, tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from exc


def _expect(meta: Mapping[str, Any]) -> str:
    lo, hi, unit = meta.get("lo"), meta.get("hi"), meta.get("unit", "")
    rng = ""
    if lo is not None and hi is not None:
        rng = f" in {'(' if meta.get('lo_open') else '['}{lo}, {hi}]"
    elif lo is not None:
        rng = f" {'>' if meta.get('lo_open') else '>='} {lo}"
    elif hi is not None:
        rng = f" <= {hi}"
    return f"a finite number{rng}{' ' + unit if unit else ''}"


def _number(value: Any, where: str, meta: Mapping[str, Any], integer: bool) -> float | int:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        kind = "an integer" if integer else _expect(meta)
        raise ConfigError(f"{where}: expected {kind}, got {value!r}")
    if integer and not isinstance(value, int):
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{where}: expected {_expect(meta)}, got {value!r}")
    lo, hi = meta.get("lo"), meta.get("hi")
    too_low = lo is not None and (value <= lo if meta.get("lo_open") else value < lo)
    if too_low or (hi is not None and value > hi):
        raise ConfigError(f"{where}: expected {_expect(meta)}, got {value!r}")
    return int(value) if integer else float(value)


def _convert(tp: Any, value: Any, where: str, meta: Mapping[str, Any]) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return _build(typing.cast(type, tp), value, where)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected an array, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            args = (args[0],) * len(value)
        if len(value) != len(args):
            raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(
            _convert(a, v, f"{where}[{i}]", meta) for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if origin in (typing.Union, types.UnionType):
        members = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _convert(members[0], value, where, meta)
    if tp is float:
        return _number(value, where, meta, integer=False)
    if tp is int:
        return _number(value, where, meta, integer=True)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        choices = meta.get("choices") or ()
        if choices and value not in choices:
            raise ConfigError(f"{where}: expected one of {', '.join(choices)}, got {value!r}")
        return value
    raise TypeError(f"unsupported config type {tp!r} at {where}")


@functools.cache
def _hints_and_fields(cls: type) -> tuple[dict[str, Any], dict[str, dataclasses.Field[Any]]]:
    """A config class's resolved field types and init fields: resolving the annotations
    (``get_type_hints``) is most of a build's cost, and a campaign builds thousands."""
    return typing.get_type_hints(cls), {f.name: f for f in dataclasses.fields(cls) if f.init}


def _build(cls: type[T], table: Mapping[str, Any], where: str, top: bool = False) -> T:
    """``where`` is "file" for a whole file (``top``) or "file: table" for a table in it."""
    assert dataclasses.is_dataclass(cls)
    hints, fields = _hints_and_fields(cls)
    for key in table:
        if key not in fields:
            close = difflib.get_close_matches(key, list(fields), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(f"{where}: unknown key {key!r}{hint}; expected one of {', '.join(fields)}")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        key_where = f"{where}: {name}" if top else f"{where}.{name}"
        if name not in table:
            has_default = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
            if has_default:
                continue
            want = _expect(f.metadata) if hints[name] in (float, int) else "a value"
            raise ConfigError(f"{key_where}: missing key (expected {want})")
        kwargs[name] = _convert(hints[name], table[name], key_where, f.metadata)
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def build(cls: type[T], table: Mapping[str, Any], source: str) -> T:
    """Build ``cls`` from a parsed table; ``source`` (a file name) prefixes every error."""
    return _build(cls, table, source, top=": " not in source)


def load(cls: type[T], path: str | Path) -> T:
    """Load a whole TOML file into ``cls``."""
    p, table = read_toml(path)
    return build(cls, table, str(p))


@dataclasses.dataclass(frozen=True)
class SimParam:
    """A simulator setting (world, sensors) a ground station reads and sets as a MAVLink parameter."""

    name: str
    lo: float
    hi: float
    unit: str
    description: str


def as_table(obj: Any) -> Any:
    """A config dataclass as the TOML-shaped table its loader takes (tuples as lists); the
    inverse of :func:`build` (``build(type(obj), as_table(obj), ...) == obj``)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: as_table(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init}
    if isinstance(obj, tuple):
        return [as_table(v) for v in obj]
    return obj


def to_toml(table: Mapping[str, Any]) -> str:
    """A TOML text of a table of numbers, booleans, strings, arrays and sub-tables (what
    this project's loaders read back), for writing a configuration built in code."""

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"not representable in a config: {v!r}")
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    def emit(t: Mapping[str, Any], prefix: str, out: list[str]) -> None:
        subs = {k: v for k, v in t.items() if isinstance(v, Mapping)}
        out.extend(f"{k} = {value(v)}" for k, v in t.items() if k not in subs and v is not None)
        for k, v in subs.items():
            name = f"{prefix}.{k}" if prefix else k
            out.append(f"\n[{name}]")
            emit(v, name, out)

    lines: list[str] = []
    emit(table, "", lines)
    return "\n".join(lines).lstrip("\n") + "\n"
