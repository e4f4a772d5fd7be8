"""Route files: ``route.json`` (format_version 1) and QGC WPL 110 missions (``.waypoints``).

``route.json`` is written by ``scenenav plan`` (the planned route, docs/guidance.md) and by the
guidance node in a run folder (``route.json``, ``route-<n>.json`` after the n-th replan); both hold
``format_version``, ``length_m``, ``min_clearance_m`` and ``waypoints`` (each with ``x_m``, ``y_m``
in world ENU metres and ``lat``, ``lon`` in WGS-84 degrees). :func:`read_route_file` reads the part
every reader needs. The WPL writer takes mission items already in geodetic coordinates (MAVProxy
``wp load``; the format is ``QGC WPL 110`` followed by one tab-separated item per line).
"""

from __future__ import annotations

import enum
import json
import math
from dataclasses import dataclass
from pathlib import Path

from scenenav.core.errors import UserError
from scenenav.core.formats.atomic_file import write_atomic

ROUTE_FORMAT_VERSION = 1
WPL_HEADER = "QGC WPL 110"


class MavCmd(enum.IntEnum):
    """MAVLink MAV_CMD values used in the mission (common.xml)."""

    NAV_WAYPOINT = 16
    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22


class MavFrame(enum.IntEnum):
    """MAVLink MAV_FRAME values used in the mission (common.xml)."""

    GLOBAL = 0                 # absolute altitude (AMSL); the home item
    GLOBAL_RELATIVE_ALT = 3    # altitude relative to home


def round_or_none(value: float, digits: int = 3) -> float | None:
    """``value`` rounded to ``digits`` decimals, or None (JSON null) when it is not finite."""
    return round(float(value), digits) if math.isfinite(value) else None


def write_route_json(path: str | Path, doc: dict[str, object]) -> None:
    """Write a route document (indented JSON, newline-terminated) whole: the live view and the
    plots read route files while the guidance node writes them."""
    write_atomic(Path(path), json.dumps(doc, indent=2) + "\n")


@dataclass(frozen=True)
class RouteFile:
    """What every reader of a route.json needs."""

    waypoints_xy_m: tuple[tuple[float, float], ...]
    length_m: float | None
    min_clearance_m: float | None


def read_route_file(path: str | Path) -> RouteFile:
    """Read a route.json (one-line UserError when unreadable or malformed)."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"{p}: cannot read the route file ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise UserError(f"{p}: not a route file (invalid JSON: {exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("waypoints", []), list):
        raise UserError(f"{p}: not a route file (expected an object with a 'waypoints' list)")
    try:
        xy = tuple((float(w["x_m"]), float(w["y_m"])) for w in doc.get("waypoints", []))
    except (KeyError, TypeError, ValueError):
        raise UserError(f"{p}: route waypoints need numeric x_m and y_m") from None

    def number(key: str) -> float | None:
        value = doc.get(key)
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    return RouteFile(waypoints_xy_m=xy, length_m=number("length_m"),
                     min_clearance_m=number("min_clearance_m"))


@dataclass(frozen=True)
class MissionItem:
    """One WPL line's content (the sequence number and current flag come from the position)."""

    frame: MavFrame
    cmd: MavCmd
    lat_deg: float
    lon_deg: float
    alt_m: float


def _wpl_line(seq: int, current: int, item: MissionItem) -> str:
    cols = [str(seq), str(current), str(int(item.frame)), str(int(item.cmd)), "0", "0", "0", "0",
            f"{item.lat_deg:.8f}", f"{item.lon_deg:.8f}", f"{item.alt_m:.3f}", "1"]
    return "\t".join(cols)


def wpl_lines(items: list[MissionItem]) -> list[str]:
    """QGC WPL 110 lines: the header, then the items (the first, the home item, is current)."""
    return [WPL_HEADER] + [_wpl_line(seq, 1 if seq == 0 else 0, item) for seq, item in enumerate(items)]


def write_wpl(path: str | Path, items: list[MissionItem]) -> None:
    """Write a QGC WPL 110 mission file."""
    Path(path).write_text("\n".join(wpl_lines(items)) + "\n", encoding="utf-8")
