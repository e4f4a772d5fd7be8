"""``scenenav world ...``: generate, import, inspect and preview world folders."""

from __future__ import annotations

import argparse
import logging
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from scenenav.app.arg_types import positive_float
from scenenav.core.errors import UserError
from worlds.ground import DEFAULT_GROUND_WINDOW_M, DsmKind
from worlds.importer import DEFAULT_REFERENCE_HEIGHT_M
from worlds.landcover import LANDCOVER_COLOURS_RGB, JunctionKind, LandCover, colourise, cover_shares
from worlds.world import World, load_world

log = logging.getLogger(__name__)

#: Marker colours (RGB) of junction kinds in previews.
JUNCTION_COLOURS_RGB: dict[JunctionKind, tuple[int, int, int]] = {
    JunctionKind.CROSS: (255, 0, 0),
    JunctionKind.TEE: (255, 140, 0),
    JunctionKind.WYE: (255, 0, 255),
    JunctionKind.CORNER: (0, 200, 255),
    JunctionKind.BEND: (255, 255, 0),
}


def parse_origin(text: str) -> tuple[float, float]:
    """'LAT,LON' in degrees -> (lat, lon); UserError otherwise."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        lat, lon = float(parts[0]), float(parts[1])
    except ValueError:
        raise UserError(f"--origin {text!r}: expected LAT,LON in degrees, e.g. 48.137,11.575") from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise UserError(f"--origin {text!r}: expected latitude in [-90, 90] and longitude in "
                        f"[-180, 180] degrees")
    return lat, lon


def check_world_out(out: str, force: bool) -> None:
    """``--out`` of generate / import: a new or empty folder, or (with ``--force``) one to replace.
    Checked before any work: an import may take minutes, and a typo must not overwrite a world."""
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder (expected a new folder for the world)")
    if p.is_dir() and any(p.iterdir()) and not force:
        what = "a world" if (p / "manifest.json").is_file() else "other files"
        raise UserError(f"--out {out}: folder exists and holds {what} (choose a new --out, or pass "
                        "--force to write the world into it, replacing the world files there)")


def _generate(args: argparse.Namespace) -> int:
    from worlds.generator import CityConfig, generate_world
    kwargs = {"seed": args.seed}
    for key in ("width_px", "height_px", "m_per_px"):
        if getattr(args, key) is not None:
            kwargs[key] = getattr(args, key)
    if args.origin is not None:
        kwargs["origin_lat_deg"], kwargs["origin_lon_deg"] = parse_origin(args.origin)
    for key in ("reference_kind", "reference_height_m", "season"):
        if getattr(args, key) is not None:
            kwargs[key] = getattr(args, key)
    cfg = CityConfig(**kwargs)
    check_world_out(args.out, args.force)
    world = generate_world(cfg, name=args.name)
    world.save(args.out)
    ref = world.manifest.reference
    print(f"wrote {args.out}: {world.width_px}x{world.height_px} px at {world.m_per_px} m/px, "
          f"{len(world.junctions or ())} junctions; reference: {ref.kind.value} "
          f"(perspective from {ref.camera_height_m:.0f} m), {ref.season}, "
          f"{ref.changed_buildings} buildings changed")
    return 0


def _import(args: argparse.Namespace) -> int:
    from worlds.importer import import_world
    origin = parse_origin(args.origin) if args.origin is not None else None
    check_world_out(args.out, args.force)
    world = import_world(Path(args.image), args.m_per_px, Path(args.out),
                         reference=Path(args.reference) if args.reference else None,
                         origin_lat_lon=origin, name=args.name,
                         dsm=Path(args.dsm) if args.dsm else None, dsm_kind=args.dsm_kind,
                         dtm=Path(args.dtm) if args.dtm else None,
                         ground_window_m=args.ground_window_m, progress=not args.quiet,
                         reference_height_m=args.reference_height_m)
    m = world.manifest
    if m.source_crs is not None:
        crs = m.source_crs if len(m.source_crs) <= 40 else m.source_crs[:37] + "..."
        geo = (f"from {crs} onto a local grid centred on {m.origin_lat_deg:.6f}, "
               f"{m.origin_lon_deg:.6f} (north up)")
    else:
        geo = "not georeferenced: a plain image, north up"
    heights = (f"DSM up to {float(world.dsm_m.max()):.1f} m" if world.dsm_m is not None
               else "no DSM: the world is flat")
    if m.reference.camera_height_m is not None:
        heights += f", reference also rendered in perspective from {m.reference.camera_height_m:g} m"
    print(f"wrote {args.out}: {world.width_px}x{world.height_px} px at {world.m_per_px:.4g} m/px, {geo}; "
          f"{heights}; missing ground truth: {', '.join(m.missing_ground_truth) or 'none'}")
    return 0


def describe(world: World) -> str:
    """Human-readable summary: manifest, land-cover shares, junction counts."""
    m = world.manifest
    lines = [
        f"name:        {m.name}",
        f"source:      {m.source}" + (f" (seed {m.seed})" if m.seed is not None else ""),
        f"size:        {m.width_px} x {m.height_px} px = {m.width_px * m.m_per_px:.0f} x "
        f"{m.height_px * m.m_per_px:.0f} m at {m.m_per_px} m/px",
        f"origin:      {m.origin_lat_deg:.6f}, {m.origin_lon_deg:.6f} deg (map centre)",
        f"missing:     {', '.join(m.missing_ground_truth) or 'none'}",
    ]
    if m.source_crs is not None:
        lines.append(f"source crs:  {m.source_crs if len(m.source_crs) <= 60 else m.source_crs[:57] + '...'}")
        lines.append(f"local grid:  {m.local_projection}")
    if world.dsm_m is not None:
        raised = world.dsm_m > 0
        lines.append(f"surface:     DSM up to {float(world.dsm_m.max()):.1f} m, "
                     f"{100.0 * float(raised.mean()):.1f} % of the map raised"
                     + (f" (mean {float(world.dsm_m[raised].mean()):.1f} m)" if raised.any() else ""))
    else:
        lines.append("surface:     flat (no DSM)")
    ref = m.reference
    xs = (np.arange(0, m.width_px + 1, max(1, m.width_px // 16)) - m.width_px / 2) * m.m_per_px
    ys = (m.height_px / 2 - np.arange(0, m.height_px + 1, max(1, m.height_px // 16))) * m.m_per_px
    dx, dy = ref.offset_m(*np.meshgrid(xs, ys))
    off = np.hypot(dx, dy)
    lines.append(f"reference:   uses the {ref.kind.value} one"
                 + (f" (perspective image taken from {ref.camera_height_m:.0f} m)" if ref.camera_height_m else "")
                 + f", {ref.season}, misregistration {off.min():.2f}..{off.max():.2f} m, "
                 f"{ref.changed_buildings} buildings changed")
    if world.landcover is not None:
        lines.append("land cover:")
        for cover, share in cover_shares(world.landcover).items():
            lines.append(f"  {cover.name.lower():18s} {100.0 * share:5.1f} %")
    if world.junctions is not None:
        counts = Counter(j.kind for j in world.junctions)
        lines.append(f"junctions:   {len(world.junctions)}")
        for kind in JunctionKind:
            lines.append(f"  {kind.value:18s} {counts.get(kind, 0)}")
    return "\n".join(lines)


def _world_of(spec: str) -> World:
    """The world a scenario's ``world`` value names: a folder, ``default`` or ``generated:KEY=VALUE,...``
    (generated and cached on first use, as a run does)."""
    from worlds.default import is_generated_spec, world_folder
    return load_world(world_folder(spec) if is_generated_spec(spec) else spec)


def _info(args: argparse.Namespace) -> int:
    print(describe(_world_of(args.dir)))
    return 0


#: Colour map of the heights panel of a world without land cover (OpenCV's; low dark, high yellow).
HEIGHTS_COLOUR_MAP = cv2.COLORMAP_VIRIDIS


def has_landcover_info(world: World) -> bool:
    """Whether the world classifies its ground: a land-cover raster (manifest ``has_landcover``;
    imported worlds have none) with at least one pixel not ``UNKNOWN``."""
    return world.landcover is not None and bool(np.any(world.landcover != LandCover.UNKNOWN))


def heights_image(dsm_m: np.ndarray) -> tuple[np.ndarray, float]:
    """A DSM's heights above the ground as an RGB uint8 image (``HEIGHTS_COLOUR_MAP``, 0 m darkest,
    the highest point brightest) and that highest height in metres."""
    top_m = float(dsm_m.max()) if dsm_m.size else 0.0
    scaled = np.clip(np.asarray(dsm_m, dtype=np.float32) / max(top_m, 1e-6), 0.0, 1.0)
    bgr = cv2.applyColorMap(np.rint(scaled * 255.0).astype(np.uint8), HEIGHTS_COLOUR_MAP)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), top_m


def preview_third_panel(world: World) -> tuple[np.ndarray, tuple[str, ...]] | None:
    """The preview's third panel and its title lines: the land-cover map (untitled: its colours are
    documented), else the DSM heights (titled with what they are and their range), else None (a
    flat world without land cover: an empty panel would say nothing)."""
    if has_landcover_info(world):
        assert world.landcover is not None
        return colourise(world.landcover), ()
    if world.dsm_m is not None:
        img, top_m = heights_image(world.dsm_m)
        return img, ("no land cover: DSM heights above ground",
                     f"0 m (dark) to {top_m:.1f} m (yellow)")
    return None


def draw_title(panel: np.ndarray, lines: tuple[str, ...]) -> None:
    """Write ``lines`` in black on a white band across the top of ``panel`` (RGB, in place), sized
    to fit its width."""
    if not lines:
        return
    width_px = panel.shape[1]
    font, thickness = cv2.FONT_HERSHEY_SIMPLEX, 1
    widest_px = max(cv2.getTextSize(text, font, 1.0, thickness)[0][0] for text in lines)
    font_scale = max(0.3, min(1.0, 0.94 * width_px / max(widest_px, 1)))   # tiny panels: clipped
    line_px = int(round(34 * font_scale)) + 2
    band_px = min(panel.shape[0], line_px * len(lines) + 6)
    panel[:band_px] = 255
    for k, text in enumerate(lines):
        cv2.putText(panel, text, (max(2, int(0.03 * width_px)), line_px * (k + 1)), font, font_scale,
                    (0, 0, 0), thickness, cv2.LINE_AA)


def render_preview(world: World, max_width_px: int) -> np.ndarray:
    """Orthophoto | reference | land cover with junction markers, side by side (RGB uint8). A world
    without land cover (an imported one) shows its DSM heights in the third place, titled; a flat
    one without land cover has no third panel (``preview_third_panel``)."""
    third = preview_third_panel(world)
    panels = [world.orthophoto, world.reference] + ([third[0]] if third is not None else [])
    scale = min(1.0, max_width_px / float(len(panels) * world.width_px))
    if scale < 1.0:
        size = (max(1, int(world.width_px * scale)), max(1, int(world.height_px * scale)))
        panels = [cv2.resize(p, size, interpolation=cv2.INTER_AREA) for p in panels]
    panels = [np.ascontiguousarray(p) for p in panels]
    radius = max(3, int(round(8 * max(scale, 0.5))))
    marked = [panels[0]] + panels[2:]          # the reference is another day's: not marked
    for j in world.junctions or ():
        centre = (int(j.u_px * scale), int(j.v_px * scale))
        colour = JUNCTION_COLOURS_RGB[j.kind]
        for p in marked:
            cv2.circle(p, centre, radius, colour, 2)
        cv2.putText(marked[-1], str(j.arms), (centre[0] + radius, centre[1] - radius),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    if third is not None:
        draw_title(panels[2], third[1])        # after scaling: legible at any preview width
    sep = np.full((panels[0].shape[0], 4, 3), 255, dtype=np.uint8)
    row: list[np.ndarray] = []
    for p in panels:
        row += [sep, p] if row else [p]
    return np.hstack(row)


def _preview(args: argparse.Namespace) -> int:
    world = _world_of(args.dir)
    img = render_preview(world, args.max_width_px)
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise UserError(f"--out {out}: expected a .png file name")
    ok = cv2.imwrite(str(out), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    if not ok:
        raise UserError(f"--out {out}: cannot write (does the folder exist?)")
    print(f"wrote {out} ({img.shape[1]}x{img.shape[0]} px)")
    return 0


WORLD_ARG_HELP = ("world folder, or what a scenario's world key takes: default, or generated:seed=N,... "
                  "(generated and cached on first use)")


def register(subparsers) -> None:
    """Add ``world`` and its subcommands to the top-level ``scenenav`` parser."""
    legend = ", ".join(f"{c.value}={c.name.lower()}" for c in LandCover)
    p = subparsers.add_parser(
        "world", help="generate, import, inspect and preview world folders",
        description="World folders hold manifest.json, orthophoto.png (what the drone camera sees), "
                    "reference.png (the reference map, 'another day'), landcover.png and junctions.json "
                    "(ground truth of generated worlds). See docs/worlds.md.")
    sub = p.add_subparsers(dest="world_command", required=True, metavar="SUBCOMMAND")

    g = sub.add_parser("generate", help="generate a procedural city world",
                       description="Generate a procedural 3-D city (roads with junctions, buildings with "
                                   "heights, trees, lakes, forests, squares, parking, uniform-roof "
                                   "districts) and write the world folder: orthophoto, surface model "
                                   "(dsm.png, facade.png), land cover, junctions and the reference map "
                                   "of another day both as a true orthophoto and in perspective, with a "
                                   "stated misregistration and some changed buildings. The same options "
                                   "always give the same world. See docs/worlds.md.")
    g.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    g.add_argument("--out", required=True, metavar="DIR", help="world folder to write")
    g.add_argument("--force", action="store_true",
                    help="write into an --out folder that is not empty (its world files are replaced)")
    g.add_argument("--width-px", type=int, default=None, metavar="PX",
                   help="map width in pixels (default 900; 256..16384)")
    g.add_argument("--height-px", type=int, default=None, metavar="PX",
                   help="map height in pixels (default 1000; 256..16384)")
    g.add_argument("--m-per-px", type=positive_float, default=None, metavar="M",
                   help="ground resolution in metres per pixel (default 0.53, as in the seed paper)")
    g.add_argument("--origin", default=None, metavar="LAT,LON",
                   help="geodetic position of the map centre in degrees (default 48.1372,11.5755)")
    g.add_argument("--name", default=None, help="world name stored in the manifest")
    g.add_argument("--reference", dest="reference_kind", choices=("orthophoto", "perspective"), default=None,
                   help="the reference map perception uses (manifest reference.kind; both are always "
                        "written): 'orthophoto' = reference.png, the other day seen straight down "
                        "everywhere (roofs over their footprints); 'perspective' (default, as the seed "
                        "paper's) = reference_perspective.png, the other day seen from "
                        "--reference-height-m above the map centre, roofs leaning away from the centre")
    g.add_argument("--reference-height-m", type=positive_float, default=None, metavar="M",
                   help="height of the perspective reference's eye above the map centre in metres "
                        "(default 500, the seed paper's section 6.1; 50..20000)")
    g.add_argument("--season", choices=("summer", "winter"), default=None,
                   help="season of the reference day (default summer); winter: leaf-off trees, snow on "
                        "grass and flat roofs (a bad matching area, seed paper section 4.2), a low sun")
    g.set_defaults(func=_generate)

    i = sub.add_parser(
        "import", help="make a world folder from an orthophoto (PNG/JPEG, or a GeoTIFF with a DSM)",
        description="Import an orthophoto as a world. A GeoTIFF (or any raster GDAL reads) with a CRS is "
                    "reprojected (rasterio; bilinear, or area average when coarsening) onto a local grid: "
                    "azimuthal equidistant on WGS-84 centred on the image centre, north up, so grid north "
                    "is true north and metres are ground metres whatever the source CRS (UTM, Web "
                    "Mercator, geographic); the geodetic origin is the image centre and the manifest "
                    "records the source CRS. Pixels with no source data are black. A PNG/JPEG (or a TIFF "
                    "without CRS) is used pixel for pixel at --m-per-px, north up. Imported worlds have no "
                    "land cover and no junction ground truth; without --reference the image is also the "
                    "reference map; with --dsm the reference is also rendered in perspective from "
                    "--reference-height-m (what the paper and realistic profiles match against); without "
                    "--dsm the world is flat (and the manifest says so). "
                    "See docs/worlds.md, 'Real places'.")
    i.add_argument("image", metavar="IMAGE",
                   help="orthophoto: a GeoTIFF with a CRS, or a north-up PNG/JPEG/TIFF (>= 256 px a side)")
    i.add_argument("--m-per-px", type=positive_float, default=None, metavar="M",
                   help="ground resolution of the world in metres per pixel (required for plain images; "
                        "GeoTIFF default: the source's ground resolution at its centre)")
    i.add_argument("--out", required=True, metavar="DIR", help="world folder to write")
    i.add_argument("--force", action="store_true",
                    help="write into an --out folder that is not empty (its world files are replaced)")
    i.add_argument("--reference", default=None, metavar="IMAGE2",
                   help="reference map of the same area (another day/sensor): georeferenced, or "
                        "pixel-aligned with IMAGE at the same size")
    i.add_argument("--origin", default=None, metavar="LAT,LON",
                   help="plain images only: geodetic position of the image centre in degrees "
                        "(default: unknown, 0,0); a GeoTIFF's origin comes from its CRS")
    i.add_argument("--dsm", default=None, metavar="RASTER",
                   help="surface model in metres (GeoTIFF, reprojected bilinearly onto the world grid; or "
                        "pixel-aligned with IMAGE): gives the world its heights; nodata -> 0")
    i.add_argument("--dsm-kind", choices=[k.value for k in DsmKind], default=DsmKind.NDSM.value,
                   help="ndsm (default): heights above the ground, used as they are; dsm: elevations, "
                        "from which the ground (--dtm, or an estimate) is subtracted; negatives -> 0")
    i.add_argument("--dtm", default=None, metavar="RASTER",
                   help="ground elevations under a --dsm-kind dsm raster (default: estimated from the DSM "
                        "by a morphological opening, see --ground-window-m)")
    i.add_argument("--ground-window-m", type=positive_float, default=DEFAULT_GROUND_WINDOW_M, metavar="M",
                   help=f"window of the ground estimate of a DSM without --dtm: objects narrower than this "
                        f"are raised above the ground (default {DEFAULT_GROUND_WINDOW_M:g} m)")
    i.add_argument("--reference-height-m", type=float, default=DEFAULT_REFERENCE_HEIGHT_M, metavar="M",
                   help="with --dsm: also render the reference in perspective from M above the map centre "
                        "(reference_perspective.png, what the paper and realistic profiles match against: "
                        f"the paper's reference was taken from 500 m; default {DEFAULT_REFERENCE_HEIGHT_M:g}; "
                        "0: none). A flat world needs none: its perspective view is its orthophoto")
    i.add_argument("--name", default=None, help="world name (default: the image file name)")
    i.add_argument("--quiet", action="store_true", help="no progress bar")
    i.set_defaults(func=_import)

    n = sub.add_parser("info", help="print a world's manifest, land-cover shares and junction counts",
                       description=f"Print a world's manifest, land-cover shares and junction counts. "
                                   f"Land-cover classes: {legend}.")
    n.add_argument("dir", metavar="WORLD", help=WORLD_ARG_HELP)
    n.set_defaults(func=_info)

    v = sub.add_parser("preview", help="write orthophoto | reference | land cover side by side",
                       description="Write a PNG with the orthophoto, the reference map and the land-cover "
                                   "map (colours in docs/worlds.md) side by side; junctions are circled "
                                   "(red cross, orange tee, magenta wye, cyan corner, yellow bend) and "
                                   "labelled with their arm count. A world without land cover (an "
                                   "imported one) shows its DSM heights above the ground in the third "
                                   "place instead (titled, with their range), or, when it is flat too, "
                                   "only the orthophoto and the reference.")
    v.add_argument("dir", metavar="WORLD", help=WORLD_ARG_HELP)
    v.add_argument("--out", required=True, metavar="PNG", help="preview image to write (.png)")
    v.add_argument("--max-width-px", type=int, default=3000, metavar="PX",
                   help="downscale so the whole preview is at most this wide (default 3000)")
    v.set_defaults(func=_preview)


__all__ = ["register", "describe", "render_preview", "preview_third_panel", "has_landcover_info",
           "heights_image", "draw_title", "parse_origin", "JUNCTION_COLOURS_RGB", "HEIGHTS_COLOUR_MAP",
           "LANDCOVER_COLOURS_RGB"]
