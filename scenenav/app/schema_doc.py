"""Render the scenario schema (every key, type, default and comment) as Markdown.

``python -m scenenav.app.schema_doc > docs/scenarios-schema.md``; a test checks the committed page is
up to date, so the documentation never drifts from the dataclasses.
"""

from __future__ import annotations

import dataclasses
import enum
import inspect
import re
import types
import typing

from scenenav.app.scenario import ScenarioConfig


def _comments(cls: type) -> dict[str, str]:
    """Trailing ``# comments`` of each field line in the dataclass source."""
    out: dict[str, str] = {}
    try:
        src = inspect.getsource(cls)
    except (OSError, TypeError):
        return out
    for line in src.splitlines():
        m = re.match(r"\s+(\w+):[^#]*#\s*(.+)$", line)
        if m:
            out[m.group(1)] = m.group(2).strip()
    return out


def _type_text(tp) -> str:
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return " \\| ".join(f"`{m.value}`" for m in tp)
    origin = typing.get_origin(tp)
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_text(args[0])}"
        return f"list of {len(args)} {_type_text(args[0])}"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_text(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp)).replace("|", "\\|")


def _default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        v = f.default
    elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        v = f.default_factory()  # type: ignore[misc]
    else:
        return ""
    if isinstance(v, enum.Enum):
        v = v.value
    if isinstance(v, tuple):
        v = [list(x) if isinstance(x, tuple) else x for x in v]
    return f"`{v}`"


def rows(cls: type, prefix: str = "") -> list[str]:
    out = []
    hints = typing.get_type_hints(cls)
    comments = _comments(cls)
    nested = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            nested.append((prefix + f.name, tp))
            continue
        out.append(f"| `{prefix}{f.name}` | {_type_text(tp)} | {_default(f)} | {comments.get(f.name, '')} |")
    for name, tp in nested:
        out.extend(rows(tp, name + "."))
    return out


def render() -> str:
    head = ["# Scenario schema (generated)", "",
            "Generated from `scenenav/app/scenario.py` and `sitl/config.py` by "
            "`python -m scenenav.app.schema_doc`. Every key is optional; unknown keys are errors.", "",
            "| key | type | default | meaning |", "|---|---|---|---|"]
    return "\n".join(head + rows(ScenarioConfig)) + "\n"


if __name__ == "__main__":
    print(render(), end="")
