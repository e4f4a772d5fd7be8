"""``scenenav experiment relief``: what relief does to scene matching (issue 11, "Done when").

The project's own matcher (the perception pipeline's alignment and NCC, ``perception.alignment`` +
``perception.ncc_search.SceneMatcher`` with the ``PerceptionConfig`` the perception node uses) with
ideal sensors (the true heading and altitude, no photometric noise beyond the other day's), at N
seeded positions away from the map edge, nadir, at 100 m, a random heading each, three comparisons:

* ``flat-ortho``: the capture of the world without its heights vs the orthophoto reference;
* ``relief-ortho``: the capture of the 3-D city (perspective, leaning buildings, facades, occlusion)
  vs the orthophoto reference;
* ``relief-perspective``: the same 3-D capture vs the reference taken in perspective from
  ``manifest.reference.camera_height_m`` (500 m) above the map centre, as the paper's.

All three render through the same camera (``perception.capture.CaptureScene`` over
``worlds.view_renderer.CityRenderer``; the flat one with every height 0), so they differ only in
relief and reference. Each capture is matched over the whole reference (``SceneMatcher``'s global
search, the re-acquisition the node runs when it has no track), or with ``--window-px R`` in the
tracker's kind of window: the template plus R px on each side around the true match position (a
tracked flight's view: no false match can land further than R px off); its error is the distance
from the true match position, i.e. after undoing the reference misregistration the world states. Per
comparison: median error, RMS of the errors up to 5 m, share over 5 m and over 20 m, also per bin
of the mean building height in the camera footprint (scenenav/app/height_split.py).

Writes ``relief.json`` and ``relief.md`` to ``--out`` (docs/relief-baseline.md is this table run
on the default world and fresh seeds); ``--json`` prints the JSON document alone.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import numpy as np
from tqdm import tqdm

from scenenav.app.height_split import GROSS_ERROR_M, footprint_mean_height_m, split_by_height
from scenenav.core.camera_geometry import ground_footprint_m
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

#: The paper's capture (section 6.1): 200 x 200 px, 60 degree field of view, from 100 m.
ALTITUDE_M = 100.0
FOV_DEG = 60.0
CAMERA_PX = 200
#: Issue 11: 300 positions on the default world (900 x 1000 px), 600 on bigger worlds.
POSITIONS_DEFAULT_WORLD = 300
POSITIONS_BIGGER_WORLD = 600
DEFAULT_WORLD_AREA_PX = 900 * 1000
#: Positions keep the whole footprint (turned any way) and this much more inside the map.
EDGE_MARGIN_M = 10.0
THRESHOLD_M = 5.0


class Comparison(str, Enum):
    """The three comparisons of issue 11."""

    FLAT_ORTHO = "flat-ortho"
    RELIEF_ORTHO = "relief-ortho"
    RELIEF_PERSPECTIVE = "relief-perspective"

    @property
    def title(self) -> str:
        return {"flat-ortho": "flat capture vs ortho reference",
                "relief-ortho": "3-D capture vs ortho reference",
                "relief-perspective": "3-D capture vs perspective reference"}[self.value]


@dataclass(frozen=True)
class Position:
    """One capture pose: nadir point (continuous map pixels), compass heading."""

    u_px: float
    v_px: float
    heading_rad: float


def default_positions(world) -> int:
    """300 on the default world's size or smaller, 600 on bigger worlds (issue 11)."""
    return POSITIONS_DEFAULT_WORLD if world.width_px * world.height_px <= DEFAULT_WORLD_AREA_PX \
        else POSITIONS_BIGGER_WORLD


def sample_positions(world, n: int, seed: int, altitude_m: float = ALTITUDE_M,
                     fov_deg: float = FOV_DEG) -> list[Position]:
    """``n`` seeded poses whose footprint (turned any way) stays ``EDGE_MARGIN_M`` inside the map."""
    half = ground_footprint_m(altitude_m, fov_deg) / math.sqrt(2.0) + EDGE_MARGIN_M
    margin_px = half / world.m_per_px
    if 2 * margin_px >= min(world.width_px, world.height_px):
        raise UserError(f"world {world.manifest.name!r}: {world.width_px}x{world.height_px} px at "
                        f"{world.m_per_px} m/px is too small for captures from {altitude_m:g} m "
                        f"(expected both sides > {2 * margin_px:.0f} px)")
    rng = np.random.default_rng([seed, 11_005])
    u = rng.uniform(margin_px, world.width_px - margin_px, n)
    v = rng.uniform(margin_px, world.height_px - margin_px, n)
    h = rng.uniform(0.0, 2.0 * math.pi, n)
    return [Position(float(a), float(b), float(c)) for a, b, c in zip(u, v, h, strict=True)]


def _scenes(world) -> dict[Comparison, object]:
    """The capture scene of each comparison the world allows (see the module docstring)."""
    from perception.alignment import to_gray_float32
    from perception.capture import CaptureScene
    from scenenav.core.formats.world_manifest import ReferenceKind
    info = world.manifest.reference
    ortho_ref = to_gray_float32(world.reference_map(ReferenceKind.ORTHOPHOTO))
    cam_gray = to_gray_float32(world.orthophoto)
    common = dict(camera_gray=cam_gray, m_per_px=world.m_per_px, camera_rgb=world.orthophoto,
                  facade_rgb=world.facade_rgb, reference_info=info)
    zeros = np.zeros((world.height_px, world.width_px), np.float32)
    out: dict[Comparison, object] = {
        Comparison.FLAT_ORTHO: CaptureScene(reference_gray=ortho_ref, heights_m=zeros,
                                            reference_kind=ReferenceKind.ORTHOPHOTO, **common)}
    if world.dsm_m is not None:
        relief = CaptureScene(reference_gray=ortho_ref, heights_m=world.dsm_m,
                              reference_kind=ReferenceKind.ORTHOPHOTO, **common)
        out[Comparison.RELIEF_ORTHO] = relief
        if world.reference_perspective is not None:
            out[Comparison.RELIEF_PERSPECTIVE] = relief.with_reference(
                to_gray_float32(world.reference_perspective), ReferenceKind.PERSPECTIVE)
    return out


def _skipped(world) -> dict[str, str]:
    why = {}
    if world.dsm_m is None:
        why[Comparison.RELIEF_ORTHO.value] = "the world has no DSM (flat)"
        why[Comparison.RELIEF_PERSPECTIVE.value] = "the world has no DSM (flat)"
    elif world.reference_perspective is None:
        why[Comparison.RELIEF_PERSPECTIVE.value] = "the world has no perspective reference"
    return why


def run_relief(world_spec: str | None = None, out: str | Path | None = None, seed: int = 0,
               positions: int | None = None, progress: bool = True, window_px: int | None = None) -> dict:
    """Run the comparison; returns the JSON document (also written to ``out`` when given).
    ``window_px``: search a window of the template plus this many px around the true match
    position instead of the whole map (None: global search)."""
    from perception.alignment import align_capture
    from perception.config import PerceptionConfig
    from perception.ncc_search import SceneMatcher
    from worlds.default import is_generated_spec, load_world_spec
    from worlds.world import load_world
    spec = world_spec or "default"
    world = load_world_spec(spec) if is_generated_spec(spec) else load_world(spec)
    n = positions if positions is not None else default_positions(world)
    if n < 1:
        raise UserError(f"--positions {n}: expected at least 1")
    out_dir = Path(out) if out is not None else None
    if out_dir is not None:
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"--out {out_dir}: cannot create the folder ({exc.strerror})") from None
    poses = sample_positions(world, n, seed)
    cfg = PerceptionConfig(fov_deg=FOV_DEG)          # the perception node's configuration
    x, y = world.pixel_to_world(np.array([p.u_px for p in poses]), np.array([p.v_px for p in poses]))
    heading = np.array([p.heading_rad for p in poses])
    heights = (np.zeros(n) if world.dsm_m is None else
               footprint_mean_height_m(world.dsm_m, world.m_per_px, x, y, heading, ALTITUDE_M, FOV_DEG))
    scenes = _scenes(world)
    results = {}
    t0 = time.perf_counter()
    for comp, scene in scenes.items():
        matcher = SceneMatcher(scene.reference_gray, scene.m_per_px, cfg.matcher)
        errors = np.empty(n)
        peaks = np.empty(n)
        tu, tv = scene.true_match_uv(np.array([p.u_px for p in poses]), np.array([p.v_px for p in poses]))
        bar = tqdm(poses, desc=comp.value, unit="pos", disable=not progress, leave=False)
        for i, p in enumerate(bar):
            cam = scene.camera_image(p.u_px, p.v_px, p.heading_rad, ALTITUDE_M, FOV_DEG, CAMERA_PX)
            aligned = align_capture(cam, p.heading_rad, ALTITUDE_M, FOV_DEG, scene.m_per_px, cfg.crop_mode,
                                    (matcher.width_px, matcher.height_px))
            centre = None if window_px is None else (float(tu[i]), float(tv[i]))
            m = matcher.match(aligned.template, centre, window_px,
                              mask=None if aligned.mask_is_full else aligned.mask)
            if m.flat_template:
                errors[i], peaks[i] = math.inf, math.nan
                continue
            errors[i] = math.hypot(m.position_px[0] - tu[i], m.position_px[1] - tv[i]) * scene.m_per_px
            peaks[i] = m.peak
        split = split_by_height(errors, heights, THRESHOLD_M, GROSS_ERROR_M)
        results[comp.value] = {"title": comp.title, "reference": scene.reference_kind.value,
                               "peak_median": float(np.nanmedian(peaks)) if np.isfinite(peaks).any() else None,
                               **split.to_dict()}
    doc = {
        "world": world.manifest.name,
        "world_size_px": [world.width_px, world.height_px],
        "m_per_px": world.m_per_px,
        "world_has_dsm": world.manifest.has_dsm,
        "reference_camera_height_m": world.manifest.reference.camera_height_m,
        "positions": n, "seed": seed, "altitude_m": ALTITUDE_M, "fov_deg": FOV_DEG, "camera_px": CAMERA_PX,
        "matcher": "perception.ncc_search.SceneMatcher, "
                   + ("global search" if window_px is None else
                      f"window of the template + {window_px} px around the true match")
                   + f", PerceptionConfig() defaults ({cfg.matcher.ncc_method.value}, {cfg.crop_mode.value})",
        "window_px": window_px,
        "sensors": "ideal: true heading and altitude",
        "errors": "against the true match position (reference misregistration undone)",
        "misregistration_max_m": float(np.max(np.hypot(*world.manifest.reference.offset_m(x, y)))),
        "mean_footprint_height_m": float(np.mean(heights)),
        "comparisons": results,
        "skipped": _skipped(world),
        "wall_time_s": round(time.perf_counter() - t0, 1),
    }
    if out_dir is not None:
        (out_dir / "relief.json").write_text(json.dumps(_strict(doc), indent=2) + "\n")
        (out_dir / "relief.md").write_text(relief_markdown(doc))
    return doc


def _strict(obj):
    from scenenav.app.json_output import strict
    return strict(obj)


def _pct(v) -> str:
    return "—" if v is None else f"{100.0 * v:.1f}"


def _m(v) -> str:
    return "—" if v is None else f"{v:.2f}"


def relief_markdown(doc: dict) -> str:
    """The comparison as markdown: one table overall, one per comparison split by height."""
    lines = [f"# Relief comparison — world `{doc['world']}` ({doc['world_size_px'][0]}x{doc['world_size_px'][1]} px, "
             f"{doc['positions']} positions, seed {doc['seed']})", "",
             f"Matcher: {doc['matcher']}. Sensors: {doc['sensors']}. Captures {doc['camera_px']} px, "
             f"{doc['fov_deg']:g} deg, nadir from {doc['altitude_m']:g} m, random heading. Errors "
             f"{doc['errors']} (largest misregistration here {doc['misregistration_max_m']:.2f} m). "
             f"RMS over the errors up to {THRESHOLD_M:g} m; false = over {THRESHOLD_M:g} m.", "",
             "| comparison | n | median (m) | RMS ≤ 5 m (m) | > 5 m (%) | > 20 m (%) |",
             "|---|---|---|---|---|---|"]
    for res in doc["comparisons"].values():
        o = res["overall"]
        lines.append(f"| {res['title']} | {o['n']} | {_m(o['median_m'])} | {_m(o['rms_up_to_threshold_m'])} "
                     f"| {_pct(o['share_over_threshold'])} | {_pct(o['share_over_gross'])} |")
    for key, why in doc["skipped"].items():
        lines.append(f"| {Comparison(key).title} | — | skipped: {why} | | | |")
    lines += ["", "By mean building height in the camera footprint:", "",
              "| comparison | height bin | n | median (m) | RMS ≤ 5 m (m) | > 5 m (%) | > 20 m (%) |",
              "|---|---|---|---|---|---|---|"]
    for res in doc["comparisons"].values():
        for b in res["bins"]:
            lines.append(f"| {res['title']} | {b['label']} | {b['n']} | {_m(b['median_m'])} "
                         f"| {_m(b['rms_up_to_threshold_m'])} | {_pct(b['share_over_threshold'])} "
                         f"| {_pct(b['share_over_gross'])} |")
    lines += ["", f"Generated by `scenenav experiment relief` in {doc['wall_time_s']:.0f} s."]
    return "\n".join(lines) + "\n"
