"""Campaign files (``scenenav campaign``): frozen dataclasses, and their expansion into planned runs.

A campaign file (YAML, docs/campaigns.md) names a ``base`` scenario (relative to the campaign file),
``set`` overrides for every run, a ``grid`` (scenario key -> list of values, or a named axis of labelled
override bundles; the runs are the cross product), ``random`` draws (scenario key -> distribution, with
``draws`` and ``seed``) and ``repeat`` (each point flown N times with seeds derived from the point).
Every run is resolved into a whole ``ScenarioConfig`` here, before any flight starts, so a bad key or
value is one ``error: ...`` line. Its id (and a repetition's derived seed) is a hash of what its
resolved scenario sets differently from the scenario defaults (:func:`canonical_scenario_text`), so the
same run has the same id in every invocation (resume), in every campaign that contains it, and on a
later scenenav that adds a scenario key with a default.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from scenenav.core.config import ConfigError, load_yaml
from scenenav.core.errors import UserError

KNOWN_KEYS = ("name", "description", "base", "set", "grid", "random", "repeat", "timeout_s", "group_by")
RANDOM_KEYS = ("draws", "seed", "keys")
#: Default wall-time limit of one flight (s): the longest shipped scenario (gps_denied, 600 s simulated
#: at a real-time factor of about 4 on this machine, docs/results.md) takes under 3 min; 30 min leaves
#: room for a loaded cluster node. A campaign file sets its own with ``timeout_s``.
DEFAULT_TIMEOUT_S = 1800.0
RUN_ID_CHARS = 12
OVERRIDE_PREFIX = "override."


class DistKind(str, Enum):
    UNIFORM = "uniform"     # [low, high): a float
    NORMAL = "normal"       # [mean, std]: a float
    RANDINT = "randint"     # [low, high], both included: an integer
    CHOICE = "choice"       # [v1, v2, ...]: one of the values, equally likely


@dataclass(frozen=True)
class Distribution:
    kind: DistKind
    params: tuple[Any, ...]

    def draw(self, rng: np.random.Generator) -> Any:
        if self.kind == DistKind.UNIFORM:
            return float(rng.uniform(self.params[0], self.params[1]))
        if self.kind == DistKind.NORMAL:
            return float(rng.normal(self.params[0], self.params[1]))
        if self.kind == DistKind.RANDINT:
            return int(rng.integers(self.params[0], self.params[1], endpoint=True))
        return self.params[int(rng.integers(len(self.params)))]


@dataclass(frozen=True)
class GridAxis:
    """One axis of the grid: ``name`` is a scenario key (``values`` are its values) or, for an axis of
    labelled bundles, a free name whose values each set several scenario keys."""

    name: str
    labels: tuple[Any, ...]                                  # the axis' values as the table shows them
    overrides: tuple[tuple[tuple[str, Any], ...], ...]       # per value: (scenario key, value) pairs


@dataclass(frozen=True)
class RandomSpec:
    draws: int
    seed: int
    keys: tuple[tuple[str, Distribution], ...]


@dataclass(frozen=True)
class CampaignSpec:
    name: str
    path: Path                               # the campaign file
    base: Path | None                        # base scenario (None: the scenario defaults)
    set_overrides: tuple[str, ...]           # KEY=VALUE, as --set takes them
    grid: tuple[GridAxis, ...] = ()
    random: RandomSpec | None = None
    repeat: int = 1
    timeout_s: float = DEFAULT_TIMEOUT_S
    group_by: tuple[str, ...] = ()           # table columns the report groups by
    description: str = ""


@dataclass(frozen=True)
class PlannedRun:
    run_id: str
    index: int
    point: tuple[tuple[str, Any], ...]       # (table column, value): what this run varies
    overrides: tuple[str, ...]               # every KEY=VALUE applied to the base (set + point)
    scenario: dict                           # the resolved scenario (what ``scenenav run`` flies)


def _fail(path: Path, what: str) -> UserError:
    return UserError(f"{path}: {what}")


def override_text(key: str, value: Any) -> str:
    """``key=value`` with the value as JSON (which the YAML parser of --set reads back exactly)."""
    return f"{key}={json.dumps(value)}"


def _parse_set(path: Path, raw: Any) -> tuple[str, ...]:
    if raw is None:
        return ()
    if isinstance(raw, dict):
        return tuple(override_text(str(k), v) for k, v in raw.items())
    if isinstance(raw, list) and all(isinstance(x, str) and "=" in x for x in raw):
        return tuple(raw)
    raise _fail(path, f"set = {raw!r}: expected a mapping {{scenario key: value}} or a list of "
                      "KEY=VALUE strings")


def _parse_grid(path: Path, raw: Any) -> tuple[GridAxis, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, dict) or not raw:
        raise _fail(path, f"grid = {raw!r}: expected a non-empty mapping {{scenario key: [values]}} "
                          "(leave grid out for a campaign without one)")
    axes = []
    for name, values in raw.items():
        if isinstance(values, list):
            if not values:
                raise _fail(path, f"grid.{name}: empty list; expected at least one value")
            axes.append(GridAxis(str(name), tuple(values), tuple(((str(name), v),) for v in values)))
        elif isinstance(values, dict):
            if not values or not all(isinstance(b, dict) and b for b in values.values()):
                raise _fail(path, f"grid.{name}: expected a list of values, or labelled bundles "
                                  "{label: {scenario key: value, ...}, ...} (none empty)")
            axes.append(GridAxis(str(name), tuple(values),
                                 tuple(tuple((str(k), v) for k, v in b.items()) for b in values.values())))
        else:
            raise _fail(path, f"grid.{name} = {values!r}: expected a list of values or labelled bundles")
    return tuple(axes)


def _parse_distribution(path: Path, key: str, raw: Any) -> Distribution:
    kinds = ", ".join(k.value for k in DistKind)
    if not isinstance(raw, dict) or len(raw) != 1:
        raise _fail(path, f"random.keys.{key} = {raw!r}: expected one distribution, e.g. {{uniform: [0, 5]}} "
                          f"(one of {kinds})")
    (kind_name, params), = raw.items()
    try:
        kind = DistKind(kind_name)
    except ValueError:
        raise _fail(path, f"random.keys.{key}: unknown distribution {kind_name!r}; expected one of {kinds}") from None
    ok = isinstance(params, list) and len(params) >= 1
    if kind != DistKind.CHOICE:
        ok = ok and len(params) == 2 and all(isinstance(p, (int, float)) and not isinstance(p, bool)
                                             for p in params)
        if kind == DistKind.RANDINT:
            ok = ok and all(isinstance(p, int) for p in params)
        ok = ok and (params[1] >= params[0] if kind != DistKind.NORMAL else params[1] >= 0)
    if not ok:
        expected = {DistKind.UNIFORM: "[low, high] numbers, low <= high",
                    DistKind.NORMAL: "[mean, std] numbers, std >= 0",
                    DistKind.RANDINT: "[low, high] integers, low <= high",
                    DistKind.CHOICE: "a non-empty list of values"}[kind]
        raise _fail(path, f"random.keys.{key}.{kind.value} = {params!r}: expected {expected}")
    return Distribution(kind, tuple(params))


def _parse_random(path: Path, raw: Any) -> RandomSpec | None:
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise _fail(path, f"random = {raw!r}: expected a mapping with draws, seed and keys")
    unknown = sorted(set(raw) - set(RANDOM_KEYS))
    if unknown:
        raise _fail(path, f"unknown key 'random.{unknown[0]}' (known keys: {', '.join(RANDOM_KEYS)}; "
                          "the scenario keys to draw go under random.keys)")
    draws, seed, keys = raw.get("draws"), raw.get("seed", 0), raw.get("keys")
    if not isinstance(draws, int) or isinstance(draws, bool) or draws < 1:
        raise _fail(path, f"random.draws = {draws!r}: expected an integer >= 1")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise _fail(path, f"random.seed = {seed!r}: expected an integer >= 0")
    if not isinstance(keys, dict) or not keys:
        raise _fail(path, f"random.keys = {keys!r}: expected a non-empty mapping {{scenario key: distribution}}")
    return RandomSpec(draws, seed, tuple((str(k), _parse_distribution(path, str(k), v)) for k, v in keys.items()))


def load_campaign(path: str | Path, extra_sets: tuple[str, ...] = ()) -> CampaignSpec:
    """Read and check a campaign file (one-line UserError on anything wrong)."""
    p = Path(path)
    data = load_yaml(p)
    unknown = sorted(set(data) - set(KNOWN_KEYS))
    if unknown:
        raise _fail(p, f"unknown key '{unknown[0]}' (known keys: {', '.join(KNOWN_KEYS)})")
    base = None
    if data.get("base") is not None:
        if not isinstance(data["base"], str):
            raise _fail(p, f"base = {data['base']!r}: expected a scenario file name (relative to the campaign file)")
        base = (p.parent / data["base"]).resolve()
        if not base.is_file():
            raise _fail(p, f"base = {data['base']!r}: no such scenario file ({base})")
    for item in extra_sets:
        if "=" not in item:
            raise UserError(f"--set {item!r}: expected KEY=VALUE, e.g. duration_s=20")
    repeat = data.get("repeat", 1)
    if not isinstance(repeat, int) or isinstance(repeat, bool) or repeat < 1:
        raise _fail(p, f"repeat = {repeat!r}: expected an integer >= 1")
    timeout_s = data.get("timeout_s", DEFAULT_TIMEOUT_S)
    if isinstance(timeout_s, bool) or not isinstance(timeout_s, (int, float)) or timeout_s <= 0:
        raise _fail(p, f"timeout_s = {timeout_s!r}: expected a positive number of wall seconds per flight")
    grid = _parse_grid(p, data.get("grid"))
    group_by = data.get("group_by")
    if group_by is None:
        group_by = [a.name for a in grid if a.name != "seed"]
    if not isinstance(group_by, list) or not all(isinstance(g, str) for g in group_by):
        raise _fail(p, f"group_by = {group_by!r}: expected a list of grid or random keys")
    random = _parse_random(p, data.get("random"))
    swept = {a.name for a in grid} | {k for k, _ in (random.keys if random else ())}
    if repeat > 1:
        swept.add("repeat")
    for g in group_by:
        if g not in swept:
            raise _fail(p, f"group_by: {g!r} is not swept by this campaign (swept: {', '.join(sorted(swept)) or 'nothing'})")
    name = data.get("name", p.stem)
    if not isinstance(name, str) or not name:
        raise _fail(p, f"name = {name!r}: expected a non-empty string")
    return CampaignSpec(name=name, path=p.resolve(), base=base,
                        set_overrides=_parse_set(p, data.get("set")) + tuple(extra_sets),
                        grid=grid, random=random, repeat=repeat, timeout_s=float(timeout_s),
                        group_by=tuple(group_by), description=str(data.get("description", "")))


def default_scenario() -> dict:
    """The resolved scenario of no file and no overrides (``realism: ideal``, no profile settings): the
    schema's defaults, what :func:`canonical_scenario_text` leaves out."""
    from scenenav.app.scenario import load_scenario, scenario_to_dict
    return scenario_to_dict(load_scenario(None))


_ABSENT = object()


def _json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def _changes(scenario: dict, defaults: dict, path: tuple[str, ...], unset: list[list[str]]) -> dict:
    out: dict[str, Any] = {}
    for key, value in scenario.items():
        default = defaults.get(key, _ABSENT)
        if isinstance(value, dict) and isinstance(default, dict):
            nested = _changes(value, default, (*path, key), unset)
            if nested:
                out[key] = nested
        elif default is _ABSENT or _json(value) != _json(default):
            out[key] = value
    # only a free-form mapping (autopilot.params) can lack a key of its default; a section has them all
    unset.extend([*path, key] for key in defaults if key not in scenario)
    return out


def canonical_scenario_text(scenario: dict, defaults: dict | None = None) -> str:
    """What a run's id and derived seeds hash: canonical JSON of the keys of the resolved ``scenario``
    whose value differs from ``defaults`` (None: :func:`default_scenario`).

    Mappings are compared key by key (a section whose keys all equal the defaults is left out whole);
    lists and other values whole, as JSON (``true`` and ``1`` differ). A key of the defaults that the
    scenario lacks is listed as unset. So a later scenenav that adds a scenario key with a default keeps
    every id and derived seed (the new key is left out, as it equals the new defaults), and a campaign
    resumes instead of flying every run again; any value that differs from the defaults, nested or not,
    changes the text. The trade-off: a changed *default* value changes no id of a run that kept the
    default (its text names no value of that key), so a run flown with the old default counts as
    complete although the new code would fly it differently, and a run that set the new default's value
    now has that run's id; after such a change, fly the campaign in a new ``--out`` folder. The
    defaults are ``realism: ideal``'s, so a profile's settings are part of the text of a run that
    selects it.
    """
    unset: list[list[str]] = []
    changes = _changes(scenario, default_scenario() if defaults is None else defaults, (), unset)
    return _json([changes, sorted(unset)] if unset else changes)


def run_id_of(scenario: dict, defaults: dict | None = None) -> str:
    """The stable id of a run: a hash of its resolved scenario's differences from the scenario defaults
    (:func:`canonical_scenario_text`: unchanged by a new key with a default, changed by any value)."""
    return hashlib.sha256(canonical_scenario_text(scenario, defaults).encode()).hexdigest()[:RUN_ID_CHARS]


def derived_seed(scenario: dict, repetition: int, defaults: dict | None = None) -> int:
    """Seed of repetition ``repetition`` of a point: a hash of the point's resolved scenario's
    differences from the scenario defaults (:func:`canonical_scenario_text`) and ``repetition``, so a
    new key with a default keeps the seeds of a ``repeat`` campaign."""
    text = canonical_scenario_text(scenario, defaults) + f"|repeat={repetition}"
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "big") & 0x7FFFFFFF


def _resolve(spec: CampaignSpec, overrides: tuple[str, ...], where: str) -> dict:
    from scenenav.app.scenario import load_scenario, scenario_to_dict
    try:
        return scenario_to_dict(load_scenario(spec.base, overrides))
    except ConfigError as exc:
        text = str(exc).replace(" (with --set overrides)", "")
        raise UserError(f"{spec.path}: {where}: {text}") from None


def _points(spec: CampaignSpec) -> list[tuple[tuple[tuple[str, Any], ...], tuple[str, ...]]]:
    """(table point, overrides) for every grid x random point, in a stable order."""
    grid_points: list[tuple[tuple[str, Any], ...]] = [()]
    grid_sets: list[tuple[str, ...]] = [()]
    if spec.grid:
        grid_points, grid_sets = [], []
        for combo in itertools.product(*(range(len(a.labels)) for a in spec.grid)):
            grid_points.append(tuple((a.name, a.labels[i]) for a, i in zip(spec.grid, combo, strict=True)))
            grid_sets.append(tuple(override_text(k, v) for a, i in zip(spec.grid, combo, strict=True)
                                   for k, v in a.overrides[i]))
    draws: list[tuple[tuple[str, Any], ...]] = [()]
    if spec.random is not None:
        rng = np.random.default_rng(spec.random.seed)
        draws = [tuple((k, d.draw(rng)) for k, d in spec.random.keys) for _ in range(spec.random.draws)]
    out = []
    for point, sets in zip(grid_points, grid_sets, strict=True):
        for draw in draws:
            out.append((point + draw, sets + tuple(override_text(k, v) for k, v in draw)))
    return out


def expand(spec: CampaignSpec, max_repeat: int | None = None) -> list[PlannedRun]:
    """Every run of the campaign, resolved and checked (a UserError before any flight on a bad one).

    ``max_repeat`` flies only the first repetitions of each point (a reduced campaign whose runs are
    the same runs, same ids, as the full one's)."""
    _resolve(spec, spec.set_overrides, "set")   # the common overrides alone, for a clear message
    defaults = default_scenario()
    runs: list[PlannedRun] = []
    seen: dict[str, int] = {}
    for point, sets in _points(spec):
        overrides = spec.set_overrides + sets
        where = ", ".join(f"{k}={v}" for k, v in point) or "the base scenario"
        scenario = _resolve(spec, overrides, f"run {where}")
        for rep in range(min(spec.repeat, max_repeat or spec.repeat)):
            run_point, run_overrides, resolved = point, overrides, scenario
            if spec.repeat > 1:
                run_overrides = overrides + (override_text("seed", derived_seed(scenario, rep, defaults)),)
                run_point = point + (("repeat", rep),)
                resolved = _resolve(spec, run_overrides, f"run {where}, repeat {rep}")
            rid = run_id_of(resolved, defaults)
            if rid in seen:
                raise UserError(f"{spec.path}: runs {seen[rid]} and {len(runs)} resolve to the same scenario "
                                f"({where}); every run must differ in some scenario key")
            seen[rid] = len(runs)
            runs.append(PlannedRun(rid, len(runs), run_point, run_overrides, resolved))
    return runs


def plan_json(spec: CampaignSpec, runs: list[PlannedRun], cwd: str | None = None) -> dict:
    """The expanded plan as written to ``DIR/plan.json`` before any flight starts."""
    return {"campaign": spec.name, "campaign_file": str(spec.path),
            "base": str(spec.base) if spec.base else None, "set": list(spec.set_overrides),
            "repeat": spec.repeat, "timeout_s": spec.timeout_s, "group_by": list(spec.group_by),
            "cwd": cwd or os.getcwd(),
            "runs": [{"id": r.run_id, "index": r.index,
                      "point": {k: v for k, v in r.point}, "overrides": list(r.overrides)} for r in runs]}

