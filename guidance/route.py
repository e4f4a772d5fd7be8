"""Route documents and pictures for ``scenenav plan`` and the guidance node.

The file formats are in the bottom layer: the assistant map and world manifest are read with
``scenenav.core.formats.assistant_map_file`` / ``world_manifest``, ROUTE.json and the QGC WPL 110
mission are written with ``scenenav.core.formats.route_file``. This module builds their content
from a ``PlannedRoute`` (documented in docs/guidance.md) and draws ROUTE.png (the route over the
assistant map).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from guidance.config import RouteEnd
from guidance.planner import PlannedRoute
from scenenav.core.formats.route_file import ROUTE_FORMAT_VERSION, MavCmd, MavFrame, MissionItem, round_or_none
from scenenav.core.formats.world_manifest import WorldManifest
from scenenav.core.frames import enu_to_geodetic

log = logging.getLogger(__name__)

_MAX_PNG_PIXELS = 1600


def waypoints_geodetic(route: PlannedRoute, world: WorldManifest) -> tuple[np.ndarray, np.ndarray]:
    """Latitude and longitude (degrees) of the route's waypoints."""
    xy = route.waypoints_xy_m
    lat, lon = enu_to_geodetic(xy[:, 0], xy[:, 1], world.origin_lat_deg, world.origin_lon_deg)
    return np.atleast_1d(lat), np.atleast_1d(lon)


def route_to_dict(route: PlannedRoute, world: WorldManifest, home_alt_m: float = 0.0) -> dict:
    """The ROUTE.json document (format_version 1)."""
    lat, lon = waypoints_geodetic(route, world)
    alt = route.cfg.altitude_m
    waypoints = [{"x_m": round(float(x), 3), "y_m": round(float(y), 3), "lat": round(float(la), 8),
                  "lon": round(float(lo), 8), "alt_m": alt}
                 for (x, y), la, lo in zip(route.waypoints_xy_m, lat, lon, strict=False)]
    return {
        "format_version": ROUTE_FORMAT_VERSION,
        "world": world.name,
        "alt_reference": "relative_to_home",
        "home_alt_m": home_alt_m,
        "start_xy_m": [round(float(v), 3) for v in route.waypoints_xy_m[0]],
        "goal_xy_m": [round(float(v), 3) for v in route.waypoints_xy_m[-1]],
        "waypoints": waypoints,
        "length_m": round(route.length_m, 3),
        "min_clearance_m": round_or_none(route.min_clearance_m, 3),
        "shortest_free_length_m": round(route.shortest_free_length_m, 3),
        "length_ratio": round(route.length_ratio, 5),
        "straight_line_bad_fraction": round(route.straight_line_bad_fraction, 5),
        "route_bad_fraction": round(route.route_bad_fraction, 5),
        "planner": route.planner_params(),
        "fallback_used": bool(route.fallback_used),
    }


def mission_items(route: PlannedRoute, world: WorldManifest, home_alt_m: float = 0.0,
                  end: RouteEnd = RouteEnd.NONE) -> list[MissionItem]:
    """The QGC WPL mission: home, takeoff at the start, waypoints, optional land/RTL."""
    lat, lon = waypoints_geodetic(route, world)
    alt = route.cfg.altitude_m
    items = [MissionItem(MavFrame.GLOBAL, MavCmd.NAV_WAYPOINT, lat[0], lon[0], home_alt_m),
             MissionItem(MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_TAKEOFF, lat[0], lon[0], alt)]
    for la, lo in zip(lat[1:], lon[1:], strict=False):
        items.append(MissionItem(MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_WAYPOINT, la, lo, alt))
    if end is RouteEnd.LAND:
        items.append(MissionItem(MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_LAND, lat[-1], lon[-1], 0.0))
    elif end is RouteEnd.RTL:
        items.append(MissionItem(MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_RETURN_TO_LAUNCH, 0.0, 0.0, 0.0))
    return items


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
