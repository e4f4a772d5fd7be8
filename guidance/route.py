"""Route files: read the assistant map and world manifest, write ROUTE.json, .waypoints and .png.

Inputs are read directly (numpy / json) so that guidance does not depend on perception/ or on
worlds.world:
  * assistant map ``.npz``: key ``probability`` (float, H x W, probability of a true match,
    NaN = unvisited) plus optional metadata (``width``, ``height``, ``m_per_px``, ``world_name``).
  * world ``manifest.json``: ``width_px``, ``height_px``, ``m_per_px``, ``origin_lat_deg``,
    ``origin_lon_deg``, ``name``.
Outputs (documented in docs/guidance.md):
  * ROUTE.json, format_version 1 (waypoints in world metres and WGS-84, altitude relative to home);
  * ROUTE.png beside it: the route over the assistant map;
  * ROUTE.waypoints (QGC WPL 110) for MAVProxy ``wp load`` when asked.
"""

from __future__ import annotations

import enum
import json
import logging
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guidance.config import RouteEnd
from guidance.planner import PlannedRoute
from scenenav.core.errors import UserError
from scenenav.core.frames import enu_to_geodetic

log = logging.getLogger(__name__)

ROUTE_FORMAT_VERSION = 1
WPL_HEADER = "QGC WPL 110"
_MAX_PNG_PIXELS = 1600
# Relative tolerance when comparing m_per_px of the map metadata and of the world manifest.
_SCALE_RTOL = 1e-6


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


@dataclass(frozen=True)
class WorldInfo:
    """The subset of a world's manifest.json that guidance needs."""

    name: str
    width_px: int
    height_px: int
    m_per_px: float
    origin_lat_deg: float
    origin_lon_deg: float


@dataclass(frozen=True)
class AssistantMapData:
    """Probability grid plus the metadata found in the npz (may be empty)."""

    probability: np.ndarray
    metadata: dict


def load_world_manifest(world_dir: str | Path) -> WorldInfo:
    """Read ``<world_dir>/manifest.json`` with one-line errors."""
    path = Path(world_dir) / "manifest.json"
    if not Path(world_dir).is_dir():
        raise UserError(f"--world {world_dir}: no such directory; expected a world directory with manifest.json")
    if not path.is_file():
        raise UserError(f"{path}: no such file; expected the world's manifest.json")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object at the top level")

    def need(key: str, kind: type, positive: bool = False):
        if key not in data:
            raise UserError(f"{path}: missing key '{key}'")
        value = data[key]
        ok = isinstance(value, kind) and not isinstance(value, bool)
        if kind is float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if not ok or (positive and value <= 0):
            expected = {int: "an integer", float: "a number", str: "a string"}[kind]
            if positive:
                expected = "a positive " + expected.split(" ", 1)[1]
            raise UserError(f"{path}: {key} = {value!r}: expected {expected}")
        return kind(value)

    lat = need("origin_lat_deg", float)
    if not -90.0 < lat < 90.0:
        raise UserError(f"{path}: origin_lat_deg = {lat!r}: expected a latitude in (-90, 90) degrees")
    return WorldInfo(name=need("name", str), width_px=need("width_px", int, True),
                     height_px=need("height_px", int, True), m_per_px=need("m_per_px", float, True),
                     origin_lat_deg=lat, origin_lon_deg=need("origin_lon_deg", float))


def _scalar(value):
    arr = np.asarray(value)
    if arr.ndim == 0:
        return arr.item()
    return None


def load_assistant_map(path: str | Path) -> AssistantMapData:
    """Read an assistant-map npz (key ``probability``) with one-line errors."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"--assistant-map {p}: no such file; expected an assistant map .npz")
    try:
        with np.load(p, allow_pickle=False) as npz:
            if "probability" not in npz.files:
                raise UserError(f"{p}: no 'probability' array (found {', '.join(npz.files) or 'nothing'}); "
                                "expected an assistant map .npz")
            prob = npz["probability"]
            meta = {k: _scalar(npz[k]) for k in npz.files if k != "probability"}
    except UserError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise UserError(f"{p}: cannot read as .npz ({type(exc).__name__}: {exc}); "
                        "expected an assistant map written by numpy.savez") from None
    if prob.ndim != 2:
        raise UserError(f"{p}: probability has shape {prob.shape}; expected a 2-D H x W array")
    if not np.issubdtype(prob.dtype, np.floating):
        raise UserError(f"{p}: probability has dtype {prob.dtype}; expected float32 with NaN = unvisited")
    meta = {k: v for k, v in meta.items() if v is not None}
    return AssistantMapData(probability=prob, metadata=meta)


def check_map_matches_world(amap: AssistantMapData, world: WorldInfo, map_path: str | Path) -> None:
    """The map must have the world's size (and scale, if its metadata says)."""
    h, w = amap.probability.shape
    if (w, h) != (world.width_px, world.height_px):
        raise UserError(f"--assistant-map {map_path}: probability is {w}x{h} px (W x H) but world "
                        f"'{world.name}' is {world.width_px}x{world.height_px} px; expected a map of this world")
    meta = amap.metadata
    for key, want in (("width", world.width_px), ("height", world.height_px)):
        if key in meta and isinstance(meta[key], (int, float)) and int(meta[key]) != want:
            raise UserError(f"--assistant-map {map_path}: metadata {key} = {meta[key]} but world "
                            f"'{world.name}' has {want} px; expected a map of this world")
    scale = meta.get("m_per_px")
    if isinstance(scale, (int, float)) and not math.isclose(float(scale), world.m_per_px, rel_tol=_SCALE_RTOL):
        raise UserError(f"--assistant-map {map_path}: m_per_px = {scale} but world '{world.name}' has "
                        f"{world.m_per_px}; expected a map of this world")
    name = meta.get("world_name")
    if isinstance(name, str) and name and name != world.name:
        log.warning("assistant map says world_name=%r, world manifest says %r", name, world.name)


def waypoints_geodetic(route: PlannedRoute, world: WorldInfo) -> tuple[np.ndarray, np.ndarray]:
    """Latitude and longitude (degrees) of the route's waypoints."""
    xy = route.waypoints_xy_m
    lat, lon = enu_to_geodetic(xy[:, 0], xy[:, 1], world.origin_lat_deg, world.origin_lon_deg)
    return np.atleast_1d(lat), np.atleast_1d(lon)


def _round_or_none(value: float, digits: int) -> float | None:
    return round(float(value), digits) if math.isfinite(value) else None


def route_to_dict(route: PlannedRoute, world: WorldInfo, home_alt_m: float = 0.0) -> dict:
    """The ROUTE.json document (format_version 1)."""
    lat, lon = waypoints_geodetic(route, world)
    alt = route.cfg.altitude_m
    waypoints = [{"x_m": round(float(x), 3), "y_m": round(float(y), 3), "lat": round(float(la), 8),
                  "lon": round(float(lo), 8), "alt_m": alt}
                 for (x, y), la, lo in zip(route.waypoints_xy_m, lat, lon)]
    return {
        "format_version": ROUTE_FORMAT_VERSION,
        "world": world.name,
        "alt_reference": "relative_to_home",
        "home_alt_m": home_alt_m,
        "start_xy_m": [round(float(v), 3) for v in route.waypoints_xy_m[0]],
        "goal_xy_m": [round(float(v), 3) for v in route.waypoints_xy_m[-1]],
        "waypoints": waypoints,
        "length_m": round(route.length_m, 3),
        "min_clearance_m": _round_or_none(route.min_clearance_m, 3),
        "shortest_free_length_m": round(route.shortest_free_length_m, 3),
        "length_ratio": round(route.length_ratio, 5),
        "straight_line_bad_fraction": round(route.straight_line_bad_fraction, 5),
        "route_bad_fraction": round(route.route_bad_fraction, 5),
        "planner": route.planner_params(),
        "fallback_used": bool(route.fallback_used),
    }


def write_route_json(path: str | Path, route: PlannedRoute, world: WorldInfo, home_alt_m: float = 0.0) -> dict:
    doc = route_to_dict(route, world, home_alt_m)
    Path(path).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return doc


def _wpl_line(seq: int, current: int, frame: MavFrame, cmd: MavCmd, lat: float, lon: float, alt: float) -> str:
    cols = [str(seq), str(current), str(int(frame)), str(int(cmd)), "0", "0", "0", "0",
            f"{lat:.8f}", f"{lon:.8f}", f"{alt:.3f}", "1"]
    return "\t".join(cols)


def wpl_lines(route: PlannedRoute, world: WorldInfo, home_alt_m: float = 0.0,
              end: RouteEnd = RouteEnd.NONE) -> list[str]:
    """QGC WPL 110 mission: home, takeoff at the start, waypoints, optional land/RTL."""
    lat, lon = waypoints_geodetic(route, world)
    alt = route.cfg.altitude_m
    lines = [WPL_HEADER,
             _wpl_line(0, 1, MavFrame.GLOBAL, MavCmd.NAV_WAYPOINT, lat[0], lon[0], home_alt_m),
             _wpl_line(1, 0, MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_TAKEOFF, lat[0], lon[0], alt)]
    seq = 2
    for la, lo in zip(lat[1:], lon[1:]):
        lines.append(_wpl_line(seq, 0, MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_WAYPOINT, la, lo, alt))
        seq += 1
    if end is RouteEnd.LAND:
        lines.append(_wpl_line(seq, 0, MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_LAND, lat[-1], lon[-1], 0.0))
    elif end is RouteEnd.RTL:
        lines.append(_wpl_line(seq, 0, MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_RETURN_TO_LAUNCH, 0.0, 0.0, 0.0))
    return lines


def write_wpl(path: str | Path, route: PlannedRoute, world: WorldInfo, home_alt_m: float = 0.0,
              end: RouteEnd = RouteEnd.NONE) -> None:
    Path(path).write_text("\n".join(wpl_lines(route, world, home_alt_m, end)) + "\n", encoding="utf-8")


def map_rgb(probability: np.ndarray, threshold: float, stride: int = 1) -> np.ndarray:
    """Display image: black = bad (p < threshold), white = good, gray = unvisited (NaN)."""
    p = probability[::stride, ::stride]
    rgb = np.full(p.shape + (3,), 0.5, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        rgb[p < threshold] = 0.0
        rgb[p >= threshold] = 1.0
    return rgb


def write_route_png(path: str | Path, route: PlannedRoute, probability: np.ndarray, m_per_px: float,
                    title: str = "") -> None:
    """The route over the assistant map (matplotlib, Agg backend)."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from matplotlib.patches import Circle

    h, w = probability.shape
    stride = max(1, int(math.ceil(max(h, w) / _MAX_PNG_PIXELS)))
    half_w, half_h = w * m_per_px / 2.0, h * m_per_px / 2.0
    fig, ax = plt.subplots(figsize=(8, 8 * h / w + 0.6), dpi=120)
    try:
        ax.imshow(map_rgb(probability, route.cfg.bad_probability_threshold, stride),
                  extent=(-half_w, half_w, -half_h, half_h), origin="upper", interpolation="nearest")
        wp = route.waypoints_xy_m
        ax.plot([wp[0, 0], wp[-1, 0]], [wp[0, 1], wp[-1, 1]], "r--", lw=1.2, label="straight line")
        sp = route.shortest_path_xy_m
        ax.plot(sp[:, 0], sp[:, 1], ":", color="orange", lw=1.0, label="shortest free path")
        ax.plot(wp[:, 0], wp[:, 1], "-", color="tab:blue", lw=2.0, label="route")
        ax.plot(wp[:, 0], wp[:, 1], ".", color="tab:blue", ms=4)
        radius = route.cfg.footprint_width_m / 2.0
        if radius > 0:
            ax.add_patch(Circle(tuple(wp[0]), radius, fill=False, ls="-", lw=0.8, color="tab:green"))
        ax.plot(*wp[0], "o", color="tab:green", ms=9, label="start (footprint circle)")
        ax.plot(*wp[-1], "*", color="tab:red", ms=14, label="goal")
        ax.set_xlim(-half_w, half_w)
        ax.set_ylim(-half_h, half_h)
        ax.set_xlabel("x east [m]")
        ax.set_ylabel("y north [m]")
        clear = f"{route.min_clearance_m:.1f} m" if math.isfinite(route.min_clearance_m) else "n/a"
        ax.set_title(title or f"{route.length_m:.0f} m ({route.length_ratio:.2f}x shortest free), "
                              f"min clearance {clear}, {route.method.value}", fontsize=9)
        ax.legend(loc="lower right", fontsize=7, framealpha=0.8)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
