"""Frozen-dataclass configs loaded from YAML, with dotted command-line overrides.

Every config is a frozen dataclass whose field names carry their unit (``speed_m_s``,
``rate_hz``). ``load_config(Cls, mapping, source)`` builds one from a mapping, checking that
every key is known and every value has the right type; ``apply_overrides`` applies
``key.sub=value`` strings (``--set camera.rate_hz=5``). Range checks live in each
dataclass's ``__post_init__`` and raise ``ConfigError`` through ``check``.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Mapping, TypeVar

import yaml

from scenenav.core.errors import UserError

if typing.TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")


class ConfigError(UserError):
    """An unknown key, a wrong type or an out-of-range value in a config."""


def check(condition: bool, key: str, value: Any, expected: str) -> None:
    """Raise a one-line ConfigError when ``condition`` is false."""
    if not condition:
        raise ConfigError(f"{key} = {value!r}: expected {expected}")


def is_finite_number(value: Any) -> bool:
    """True for an int or float that is finite (the range checks' base test)."""
    return isinstance(value, (int, float)) and math.isfinite(value)


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _convert(tp: Any, value: Any, key: str, source: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        last: Exception | None = None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, key, source)
            except ConfigError as exc:
                last = exc
        raise last or ConfigError(f"{source}: {key}: unsupported value {value!r}")
    if _is_dataclass_type(tp):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{source}: {key}: expected a mapping, got {value!r}")
        return load_config(tp, value, source, prefix=key + ".")
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{source}: {key} = {value!r}: expected a mapping {{NAME: value}}")
        return {str(_convert(args[0], k, key, source)): _convert(args[1], v, f"{key}.{k}", source)
                for k, v in value.items()}
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{source}: {key} = {value!r}: expected a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{key}[{i}]", source) for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"{source}: {key} = {value!r}: expected a list of {len(args)} values")
        return tuple(_convert(a, v, f"{key}[{i}]", source) for i, (a, v) in enumerate(zip(args, value, strict=False)))
    if isinstance(tp, type) and issubclass(tp, bool):
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{source}: {key} = {value!r}: expected true or false")
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{source}: {key} = {value!r}: expected a number")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: {key} = {value!r}: expected an integer")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{source}: {key} = {value!r}: expected a string")
        return value
    if isinstance(tp, type) and issubclass(tp, __import__("enum").Enum):
        try:
            return tp(value)
        except ValueError:
            allowed = ", ".join(str(m.value) for m in typing.cast(Any, tp))
            raise ConfigError(f"{source}: {key} = {value!r}: expected one of {allowed}") from None
    return value


def load_config(cls: type[T], mapping: Mapping[str, Any] | None, source: str = "config",
                prefix: str = "") -> T:
    """Build the frozen dataclass ``cls`` from ``mapping``; unknown keys are errors."""
    mapping = dict(mapping or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(mapping) - set(fields))
    if unknown:
        known = ", ".join(sorted(fields))
        raise ConfigError(f"{source}: unknown key '{prefix}{unknown[0]}' (known keys: {known})")
    kwargs = {}
    for name, value in mapping.items():
        kwargs[name] = _convert(hints[name], value, prefix + name, source)
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {prefix}{exc}") from None


def load_yaml(path: str | Path) -> dict:
    """Read a YAML mapping from ``path`` with one-line errors for missing or malformed files."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such file (expected a YAML file)")
    try:
        data = parse_yaml(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: cannot read: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise UserError(f"{p}:{where} is not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise UserError(f"{p}: expected a YAML mapping at the top level, got {type(data).__name__}")
    return data


class YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader with two of YAML 1.2's rules: ``1e-4`` and ``2E5`` are numbers (YAML 1.1,
    which PyYAML follows, reads a mantissa without a point as a string; ArduPilot parameters are
    often written so), and a key given twice in one mapping is an error instead of the last one
    silently winning."""

    def construct_mapping(self, node, deep=False):
        seen: dict[Any, int] = {}
        if isinstance(node, yaml.MappingNode):
            for key_node, _value in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node.start_mark.line + 1)
                except TypeError:       # an unhashable key: the base class says so
                    continue
                if first != key_node.start_mark.line + 1:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} appears twice (lines {first} and "
                        f"{key_node.start_mark.line + 1}): keep one", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def parse_yaml(text: str) -> Any:
    """YAML text -> Python values with ``YamlLoader`` (raises ``yaml.YAMLError``)."""
    return yaml.load(text, Loader=YamlLoader)   # noqa: S506 (a SafeLoader subclass)


def _parse_scalar(item: str, text: str) -> Any:
    try:
        return parse_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {item!r}: the value is not valid YAML ({getattr(exc, 'problem', None) or exc}); "
                          "quote it, e.g. --set \"name='@x'\"") from None


def apply_overrides(mapping: Mapping[str, Any], overrides: list[str] | tuple[str, ...]) -> dict:
    """Apply ``a.b.c=value`` overrides (value parsed as YAML) to a nested mapping copy."""
    out = _deep_copy(mapping)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE, e.g. camera.rate_hz=5")
        key, text = item.split("=", 1)
        set_dotted(out, key.strip(), _parse_scalar(item, text))
    return out


def set_dotted(data: dict[str, Any], dotted: str, value: Any) -> None:
    """``data["a"]["b"] = value`` for ``dotted == "a.b"``, creating (or replacing non-mapping)
    intermediate levels."""
    node = data
    parts = dotted.split(".")
    for part in parts[:-1]:
        child = node.get(part)
        if not isinstance(child, dict):
            child = {}
            node[part] = child
        node = child
    node[parts[-1]] = value


def _deep_copy(mapping: Mapping[str, Any]) -> dict:
    return {k: _deep_copy(v) if isinstance(v, Mapping) else v for k, v in mapping.items()}


def to_dict(cfg: Any) -> dict:
    """A config dataclass -> plain nested dict (enums as values), for writing back to YAML/JSON."""
    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, tuple):
            return [conv(x) for x in v]
        if hasattr(v, "value") and v.__class__.__module__ != "builtins" and hasattr(v, "name"):
            return v.value
        return v
    return conv(cfg)
