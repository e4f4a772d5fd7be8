"""Tests of the worlds package: generator, world files, import, default world, CLI."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from scenenav.core import frames
from scenenav.core.config import ConfigError
from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import WorldManifest
from worlds.generator import CityConfig, generate_world
from worlds.landcover import BAD_MATCHING_COVERS, Junction, JunctionKind, LandCover, classify_arms, cover_shares
from worlds.world import World, load_world

FOOTPRINT_PX = 217   # camera footprint at 100 m (60 deg FOV) at 0.53 m/px


# default_world (the cached default world) and small_world (seed 3, 600x600 px, generated once per
# session): tests/conftest.py


# ------------------------------------------------------------------------------------------------
# junction classification and ground truth

@pytest.mark.parametrize("angles_deg, expected", [
    ([0, 90, 180, 270], JunctionKind.CROSS),
    ([10, 80, 175, 260, 300], JunctionKind.CROSS),
    ([0, 90, 180], JunctionKind.TEE),
    ([0, 120, 240], JunctionKind.WYE),
    ([0, 45, 180], JunctionKind.WYE),
    ([0, 90], JunctionKind.CORNER),
    ([0, 140], JunctionKind.BEND),
    ([0, 178], None),
    ([30], None),
])
def test_classify_arms(angles_deg, expected):
    assert classify_arms(np.radians(angles_deg)) == expected


def test_every_junction_kind_present_with_consistent_arm_counts(default_world, small_world):
    for world in (default_world, small_world):
        kinds = {j.kind for j in world.junctions}
        assert kinds == set(JunctionKind), f"{world.manifest.name}: kinds {kinds}"
        for j in world.junctions:
            assert 0 <= j.u_px < world.width_px and 0 <= j.v_px < world.height_px
            if j.kind is JunctionKind.CROSS:
                assert j.arms >= 4
            elif j.kind in (JunctionKind.TEE, JunctionKind.WYE):
                assert j.arms == 3
            else:
                assert j.arms == 2


def _road_arms_on_circle(road: np.ndarray, u: float, v: float, r: float) -> int:
    """Number of separate road crossings on a circle of radius r around (u, v).

    Gaps and runs shorter than 3 px of arc are raster staircase noise where the circle grazes a
    road edge, not arms.
    """
    n = 1440
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    on = road[np.floor(v + r * np.sin(t)).astype(int), np.floor(u + r * np.cos(t)).astype(int)]
    if on.all() or not on.any():
        return int(on.all())
    on = np.roll(on, -int(np.argmin(on)))            # start on a non-road sample
    edges = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
    runs = [(bool(seg[0]), len(seg)) for seg in np.split(on, edges)]
    min_len = 3.0 / (2.0 * np.pi * r / n)
    merged: list[list] = []
    for value, length in runs:                     # fill short gaps
        if not value and length < min_len and merged and merged[-1][0]:
            merged[-1][1] += length
            continue
        if merged and merged[-1][0] == value:
            merged[-1][1] += length
        else:
            merged.append([value, length])
    if len(merged) > 1 and merged[0][0] == merged[-1][0]:   # cyclic: join the ends
        merged[0][1] += merged.pop()[1]
    return sum(1 for value, length in merged if value and length >= min_len)


def test_junction_arms_match_the_road_mask(default_world, small_world):
    checked = {kind: 0 for kind in JunctionKind}
    for world in (default_world, small_world):
        road = world.landcover == LandCover.ROAD
        pos = np.array([(j.u_px, j.v_px) for j in world.junctions])
        r_max, r_min = 25.0 / world.m_per_px, 18.0 / world.m_per_px
        for i, j in enumerate(world.junctions):
            d = np.hypot(*(pos - pos[i]).T)
            d[i] = np.inf
            r = min(0.45 * d.min(), r_max)
            m = 2.2 * r   # graph nodes just outside the map are not in the junction list
            if r < r_min or not (m <= j.u_px <= world.width_px - m and m <= j.v_px <= world.height_px - m):
                continue
            assert _road_arms_on_circle(road, j.u_px, j.v_px, r) == j.arms, \
                f"{world.manifest.name}: {j} (circle radius {r:.0f} px)"
            checked[j.kind] += 1
    assert sum(checked.values()) >= 10, checked
    assert sum(1 for n in checked.values() if n) >= 3, checked


# ------------------------------------------------------------------------------------------------
# land cover

def test_landcover_shares_are_sane(default_world):
    shares = cover_shares(default_world.landcover)
    bounds = {
        LandCover.UNKNOWN: (0.05, 0.45), LandCover.ROAD: (0.08, 0.35),
        LandCover.BUILDING_TEXTURED: (0.03, 0.40), LandCover.BUILDING_UNIFORM: (0.005, 0.15),
        LandCover.SQUARE: (0.005, 0.10), LandCover.PARKING: (0.005, 0.10),
        LandCover.GRASS: (0.003, 0.30), LandCover.FOREST: (0.04, 0.25), LandCover.WATER: (0.04, 0.25),
    }
    for cover, (lo, hi) in bounds.items():
        assert lo <= shares[cover] <= hi, f"{cover.name}: {shares[cover]:.3f} not in [{lo}, {hi}]"
    bad = sum(shares[c] for c in BAD_MATCHING_COVERS)
    assert bad < 0.55, f"bad-matching covers take {bad:.2f} of the map"   # mostly city


def _window_shares(mask: np.ndarray, size: int) -> np.ndarray:
    """Share of ``mask`` in the size x size window centred on each pixel (0 near the border)."""
    share = cv2.boxFilter(mask.astype(np.float32), -1, (size, size), normalize=True,
                          borderType=cv2.BORDER_CONSTANT)
    half = size // 2
    share[:half + 1] = 0
    share[-half - 1:] = 0
    share[:, :half + 1] = 0
    share[:, -half - 1:] = 0
    return share


def _best_window(mask: np.ndarray, size: int) -> tuple[float, int, int]:
    """Largest share of ``mask`` in a size x size window fully inside the map, and its centre."""
    share = _window_shares(mask, size)
    v, u = np.unravel_index(int(np.argmax(share)), share.shape)
    return float(share[v, u]), int(u), int(v)


def test_default_world_has_lake_and_forest_larger_than_the_camera_footprint(default_world):
    for cover in (LandCover.WATER, LandCover.FOREST):
        share, _, _ = _best_window(default_world.landcover == cover, FOOTPRINT_PX + 20)
        assert share > 0.98, f"no {cover.name} area larger than the footprint ({share:.2f})"


def test_landcover_agrees_with_the_image(default_world):
    rgb = default_world.orthophoto.astype(float)
    lc = default_world.landcover

    def mean(cover):
        return rgb[lc == cover].mean(axis=0)

    water, forest, grass, road = (mean(LandCover.WATER), mean(LandCover.FOREST), mean(LandCover.GRASS),
                                  mean(LandCover.ROAD))
    assert water[2] > water[0] and water.mean() < 90
    assert forest[1] > forest[0] and forest[1] > forest[2]
    assert grass[1] > grass[0] and grass[1] > grass[2]
    assert abs(road[0] - road[2]) < 15 and 60 < road.mean() < 130      # grey asphalt
    assert mean(LandCover.SQUARE).mean() > road.mean() + 30             # light paving


# ------------------------------------------------------------------------------------------------
# determinism

def test_generation_is_deterministic():
    # 400 px square: the session's small_world (600 px) costs 2.5x the CPU per generation
    cfg = CityConfig(seed=3, width_px=400, height_px=400)
    first, again = generate_world(cfg), generate_world(cfg)
    for name in ("orthophoto", "reference", "landcover", "heights_m"):
        assert np.array_equal(getattr(first, name), getattr(again, name)), name
    assert again.junctions == first.junctions and len(first.junctions) > 0
    other = generate_world(dataclasses.replace(cfg, seed=4))
    assert not np.array_equal(other.landcover, first.landcover)
    assert not np.array_equal(other.orthophoto, first.orthophoto)


def test_config_ranges_are_checked():
    with pytest.raises(ConfigError, match="width_px"):
        CityConfig(width_px=10)
    with pytest.raises(ConfigError, match="m_per_px"):
        CityConfig(m_per_px=0.0)
    with pytest.raises(ConfigError, match="water_share"):
        CityConfig(water_share=0.9)


# ------------------------------------------------------------------------------------------------
# the reference map: matching is realistically imperfect

def _match(ortho: np.ndarray, ref: np.ndarray, u: float, v: float, size: int,
           world: World | None = None) -> tuple[float, float]:
    """Peak position error (px) and peak value of an orthophoto crop matched against the reference.

    With ``world``, the error is measured from where the reference's stated misregistration puts
    the crop (``manifest.reference.offset_m``), not from the crop's own place.
    """
    x0, y0 = int(u) - size // 2, int(v) - size // 2
    tmpl = ortho[y0:y0 + size, x0:x0 + size]
    res = cv2.matchTemplate(ref, tmpl, cv2.TM_CCOEFF_NORMED)
    _, peak, _, loc = cv2.minMaxLoc(res)
    du = dv = 0.0
    if world is not None:
        dx, dy = world.manifest.reference.offset_m(*world.pixel_to_world(u, v))
        du, dv = dx / world.m_per_px, -dy / world.m_per_px
    return float(math.hypot(loc[0] - x0 - du, loc[1] - y0 - dv)), float(peak)


def test_ncc_matches_city_but_not_lake_or_forest(default_world):
    ortho = cv2.cvtColor(default_world.orthophoto, cv2.COLOR_RGB2GRAY).astype(np.float32)
    ref = cv2.cvtColor(default_world.reference, cv2.COLOR_RGB2GRAY).astype(np.float32)
    lc = default_world.landcover
    h, w = lc.shape
    half = FOOTPRINT_PX // 2 + 1
    bad = np.isin(lc, [int(c) for c in BAD_MATCHING_COVERS])
    # city: crops centred on the junctions with the least bad-matching cover around them
    city = []
    for j in default_world.junctions:
        if half <= j.u_px <= w - half and half <= j.v_px <= h - half:
            y0, x0 = int(j.v_px) - half, int(j.u_px) - half
            city.append((bad[y0:y0 + FOOTPRINT_PX, x0:x0 + FOOTPRINT_PX].mean(), j))
    city = [j for share, j in sorted(city, key=lambda c: c[0])[:5] if share < 0.5]
    assert len(city) == 5, "fewer than 5 junction-centred crops over city"
    peaks = []
    for j in city:
        err, peak = _match(ortho, ref, j.u_px, j.v_px, FOOTPRINT_PX, default_world)
        assert err <= 2.0, f"city crop at {j} matched {err:.1f} px away (peak {peak:.2f})"
        peaks.append(peak)
    # lake and forest: crops entirely over water/canopy are wrong or weak (a sliver of shore in
    # the crop is enough to lock on, as in reality)
    for cover in (LandCover.WATER, LandCover.FOREST):
        share = _window_shares(lc == cover, FOOTPRINT_PX)
        vs, us = np.nonzero(share > 0.99995)
        assert len(vs) > 0, f"no footprint-sized {cover.name} area"
        for k in np.linspace(0, len(vs) - 1, 3).astype(int):
            err, peak = _match(ortho, ref, us[k] + 0.5, vs[k] + 0.5, FOOTPRINT_PX, default_world)
            assert err > 2.0 or peak < 0.5 * min(peaks), \
                f"{cover.name} crop matched too well: error {err:.1f} px, peak {peak:.2f}"


def test_reference_differs_from_orthophoto_on_another_day(default_world):
    diff = np.abs(default_world.orthophoto.astype(int) - default_world.reference.astype(int))
    assert diff.mean() > 5.0
    lc = default_world.landcover
    roads = lc == LandCover.ROAD
    # roads are geometrically identical: dark in both images at the same place
    assert np.corrcoef(default_world.orthophoto[..., 1][::4, ::4].ravel(),
                       default_world.reference[..., 1][::4, ::4].ravel())[0, 1] > 0.6
    assert roads.any()


# ------------------------------------------------------------------------------------------------
# world files

def test_save_load_round_trip(tmp_path, small_world):
    small_world.save(tmp_path / "w")
    names = sorted(p.name for p in (tmp_path / "w").iterdir())
    assert names == ["dsm.png", "facade.png", "junctions.json", "landcover.png", "manifest.json",
                     "orthophoto.png", "reference.png", "reference_perspective.png"]
    back = load_world(tmp_path / "w")
    assert back.manifest == small_world.manifest and back.manifest.has_dsm
    assert np.array_equal(back.orthophoto, small_world.orthophoto)
    assert np.array_equal(back.reference, small_world.reference)
    assert np.array_equal(back.reference_perspective, small_world.reference_perspective)
    assert np.array_equal(back.facade_rgb, small_world.facade_rgb)
    assert np.abs(back.dsm_m - small_world.dsm_m).max() <= 0.005 + 1e-6     # 1 cm steps, rounded
    assert np.array_equal(back.landcover, small_world.landcover)
    assert back.junctions == small_world.junctions
    assert WorldManifest.from_json(small_world.manifest.to_json()) == small_world.manifest


def _one_line_error(fn, match: str) -> None:
    with pytest.raises(UserError, match=match) as info:
        fn()
    assert "\n" not in str(info.value)


def test_load_errors_are_one_line_user_errors(tmp_path, small_world):
    _one_line_error(lambda: load_world(tmp_path / "nope"), "no such world folder")
    (tmp_path / "empty").mkdir()
    _one_line_error(lambda: load_world(tmp_path / "empty"), "manifest.json")

    d = tmp_path / "w"
    small_world.save(d)
    png = (d / "orthophoto.png").read_bytes()
    (d / "orthophoto.png").write_bytes(png[: len(png) // 2])
    _one_line_error(lambda: load_world(d), "orthophoto.png")
    (d / "orthophoto.png").write_bytes(png)

    ok, small = cv2.imencode(".png", np.zeros((100, 120, 3), np.uint8))
    ref = (d / "reference.png").read_bytes()
    (d / "reference.png").write_bytes(small.tobytes())
    _one_line_error(lambda: load_world(d), "does not match the manifest")
    (d / "reference.png").write_bytes(ref)

    manifest = json.loads((d / "manifest.json").read_text())
    (d / "manifest.json").write_text("{not json")
    _one_line_error(lambda: load_world(d), "not valid JSON")
    (d / "manifest.json").write_text(json.dumps({**manifest, "m_per_px": -1}))
    _one_line_error(lambda: load_world(d), "m_per_px")
    del manifest["width_px"]
    (d / "manifest.json").write_text(json.dumps(manifest))
    _one_line_error(lambda: load_world(d), "width_px")


# ------------------------------------------------------------------------------------------------
# import

def _write_png(path, img_rgb):
    assert cv2.imwrite(str(path), cv2.cvtColor(img_rgb, cv2.COLOR_RGB2BGR))


def test_import_with_and_without_reference(tmp_path, small_world):
    from worlds.importer import import_world
    img = np.ascontiguousarray(small_world.orthophoto[:300, :320])
    ref = np.ascontiguousarray(small_world.reference[:300, :320])
    _write_png(tmp_path / "a.png", img)
    _write_png(tmp_path / "b.png", ref)

    world = import_world(tmp_path / "a.png", 0.5, tmp_path / "w1")
    assert (world.width_px, world.height_px, world.m_per_px) == (320, 300, 0.5)
    assert np.array_equal(world.reference, img) and np.array_equal(world.orthophoto, img)
    assert world.landcover is None and world.junctions is None
    # without a DSM an imported world is flat and says so
    assert set(world.manifest.missing_ground_truth) == {"landcover", "junctions", "geodetic_origin", "dsm"}
    assert not world.manifest.has_dsm and world.dsm_m is None
    back = load_world(tmp_path / "w1")
    assert back.manifest.source == "imported" and back.landcover is None
    assert sorted(p.name for p in (tmp_path / "w1").iterdir()) == [
        "manifest.json", "orthophoto.png", "reference.png"]

    world = import_world(tmp_path / "a.png", 0.5, tmp_path / "w2", reference=tmp_path / "b.png",
                         origin_lat_lon=(47.0, 8.0), name="zurich")
    assert np.array_equal(load_world(tmp_path / "w2").reference, ref)
    assert world.manifest.missing_ground_truth == ("landcover", "junctions", "dsm")
    assert (world.manifest.origin_lat_deg, world.manifest.name) == (47.0, "zurich")


def test_import_errors(tmp_path, small_world):
    from worlds.importer import import_world
    _write_png(tmp_path / "a.png", np.ascontiguousarray(small_world.orthophoto[:300, :320]))
    _write_png(tmp_path / "tiny.png", np.ascontiguousarray(small_world.orthophoto[:200, :320]))
    _write_png(tmp_path / "other.png", np.ascontiguousarray(small_world.orthophoto[:310, :320]))
    (tmp_path / "junk.png").write_bytes(b"this is not an image")
    out = tmp_path / "w"
    _one_line_error(lambda: import_world(tmp_path / "missing.png", 0.5, out), "no such image")
    _one_line_error(lambda: import_world(tmp_path / "junk.png", 0.5, out), "unreadable")
    _one_line_error(lambda: import_world(tmp_path / "tiny.png", 0.5, out), "too small")
    _one_line_error(lambda: import_world(tmp_path / "a.png", 0.5, out, reference=tmp_path / "other.png"),
                    "does not match")
    _one_line_error(lambda: import_world(tmp_path / "a.png", 0.0, out), "m-per-px")
    assert not out.exists()


# ------------------------------------------------------------------------------------------------
# frames

def test_frames_round_trip(small_world):
    w = small_world
    assert w.pixel_to_world(w.width_px / 2, w.height_px / 2) == (0.0, 0.0)
    x, y = w.pixel_to_world(0.0, 0.0)            # north-west corner
    assert x == pytest.approx(-w.width_px / 2 * w.m_per_px)
    assert y == pytest.approx(w.height_px / 2 * w.m_per_px)
    xs, ys = np.array([-120.3, 0.0, 55.5]), np.array([10.0, -77.7, 0.25])
    u, v = w.world_to_pixel(xs, ys)
    assert np.allclose(w.pixel_to_world(u, v), (xs, ys))
    assert frames.world_to_pixel(1.0, 2.0, 600, 600, 0.53) == w.world_to_pixel(1.0, 2.0)


def test_junction_json_round_trip():
    j = Junction(u_px=12.5, v_px=3.25, arms=3, kind=JunctionKind.WYE)
    assert Junction.from_dict(json.loads(json.dumps(j.to_dict()))) == j
    with pytest.raises(ValueError):
        Junction.from_dict({"u_px": 1, "v_px": 2, "arms": 1, "kind": "tee"})


# ------------------------------------------------------------------------------------------------
# default world and CLI

def test_default_world_is_cached(tmp_path, monkeypatch, default_world):
    """The default world's cache folder is named for the generator's version and source, and a
    cached world is loaded, not generated again. (Generating into the cache, atomically, is
    test_generated_world_spec_is_cached_by_config's, with a small world: the default one costs
    20 s of CPU, and the session's default_world fixture generates it on a fresh machine anyway.)"""
    import shutil

    from worlds import default
    cached = default.default_world_dir()
    monkeypatch.setenv("SCENENAV_CACHE_DIR", str(tmp_path / "cache"))
    d = default.default_world_dir()
    assert d.parent == tmp_path / "cache" / "worlds" and d.name == cached.name
    assert d.name.startswith(f"default-v{default.GENERATOR_VERSION}-")
    shutil.copytree(cached, d)

    def no_generation(*_a, **_k):
        raise AssertionError("a cached world was generated again")

    from worlds import generator
    monkeypatch.setattr(generator, "generate_world", no_generation)   # default imports it when needed
    first = default.load_default_world()
    assert np.array_equal(first.orthophoto, default_world.orthophoto)
    assert np.array_equal(first.reference, default_world.reference)
    assert [p.name for p in d.parent.iterdir()] == [d.name]


def _worlds_imports(path: Path) -> set[str]:
    """Modules of the worlds package that a source file imports (by file name)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("worlds."):
            names.add(node.module.split(".")[1] + ".py")
        elif isinstance(node, ast.Import):
            names.update(a.name.split(".")[1] + ".py" for a in node.names if a.name.startswith("worlds."))
    return names


def test_generator_sources_are_every_module_the_generator_imports():
    from worlds import generator
    here = Path(generator.__file__).resolve().parent
    seen, todo = set(), ["generator.py"]
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo.extend(_worlds_imports(here / name))
    assert set(generator.GENERATOR_SOURCES) == seen


def test_default_world_cache_name_changes_with_any_generator_source(tmp_path):
    import shutil

    from worlds import default, generator
    here = Path(generator.__file__).resolve().parent
    for name in generator.GENERATOR_SOURCES:
        shutil.copy(here / name, tmp_path / name)
    base = default._generator_fingerprint(tmp_path)
    assert base == default._generator_fingerprint()
    for name in generator.GENERATOR_SOURCES:
        original = (tmp_path / name).read_bytes()
        (tmp_path / name).write_bytes(original + b"\n")
        assert default._generator_fingerprint(tmp_path) != base, name
        (tmp_path / name).write_bytes(original)


def test_generated_world_spec_is_cached_by_config(tmp_path, monkeypatch):
    from worlds import default
    from worlds.generator import CityConfig
    monkeypatch.setenv("SCENENAV_CACHE_DIR", str(tmp_path / "cache"))
    spec = "generated:seed=4,width_px=300,height_px=260,water_share=0.2"
    cfg = default.parse_generated_spec(spec)
    assert cfg == CityConfig(seed=4, width_px=300, height_px=260, water_share=0.2)
    folder = default.world_folder(spec)
    assert (folder / "manifest.json").is_file() and folder.name.startswith("generated-s4-300x260-")
    assert [p.name for p in folder.parent.iterdir()] == [folder.name]   # no temporary folders left
    world = default.load_world_spec(spec)
    assert world.width_px == 300 and world.manifest.name == "generated-s4"
    other = default.world_folder("generated:seed=4,width_px=300,height_px=260")
    assert other != folder                          # another configuration, another folder
    assert default.world_folder(str(tmp_path)) == tmp_path   # a plain folder is left alone
    with pytest.raises(UserError, match="lake_diametre"):
        default.parse_generated_spec("generated:lake_diametre=3")


def _cli(argv: list[str]) -> int:
    from scenenav.app.commands.world import register
    parser = argparse.ArgumentParser(prog="scenenav")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_generate_info_preview_import(tmp_path, capsys, small_world):
    out = tmp_path / "gen"
    assert _cli(["world", "generate", "--seed", "7", "--width-px", "400", "--height-px", "400",
                 "--origin", "52.52,13.405", "--out", str(out)]) == 0
    world = load_world(out)
    assert world.manifest.seed == 7 and world.manifest.origin_lat_deg == 52.52
    assert _cli(["world", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "junctions:" in text and "water" in text and "surface:     DSM up to" in text
    assert _cli(["world", "preview", str(out), "--out", str(tmp_path / "p.png")]) == 0
    assert cv2.imread(str(tmp_path / "p.png")).shape[1] > 3 * 400
    _write_png(tmp_path / "a.png", np.ascontiguousarray(small_world.orthophoto[:300, :300]))
    assert _cli(["world", "import", str(tmp_path / "a.png"), "--m-per-px", "0.53",
                 "--out", str(tmp_path / "imp")]) == 0
    assert "missing ground truth" in capsys.readouterr().out
    with pytest.raises(UserError, match="origin"):
        _cli(["world", "generate", "--origin", "north", "--out", str(tmp_path / "x")])
    assert _cli(["world", "generate", "--seed", "7", "--width-px", "300", "--height-px", "300",
                 "--reference", "orthophoto", "--reference-height-m", "800", "--season", "winter",
                 "--out", str(tmp_path / "w")]) == 0
    ref = load_world(tmp_path / "w").manifest.reference
    assert (ref.kind.value, ref.camera_height_m, ref.season) == ("orthophoto", 800.0, "winter")
    with pytest.raises(UserError, match="reference_height_m"):
        _cli(["world", "generate", "--reference-height-m", "10", "--out", str(tmp_path / "y")])
    with pytest.raises(UserError):
        _cli(["world", "info", str(tmp_path / "nothing")])


def test_the_first_use_of_a_generated_world_is_the_world_every_later_use_loads(tmp_path, monkeypatch):
    # the generator's in-memory world differs slightly from its saved files (the DSM is stored
    # quantised): the run that generates it must fly the cached copy, as every later run does
    from worlds import default
    monkeypatch.setenv("SCENENAV_CACHE_DIR", str(tmp_path / "cache"))
    spec = "generated:seed=6,width_px=300,height_px=280"
    first = default.load_world_spec(spec)            # generates and caches
    again = default.load_world_spec(spec)            # loads the cache
    for name in ("orthophoto", "reference", "landcover", "dsm_m", "facade_rgb"):
        a, b = getattr(first, name), getattr(again, name)
        assert (a is None) == (b is None), name
        if a is not None:
            assert a.dtype == b.dtype and np.array_equal(a, b), name


def test_world_info_and_preview_take_what_a_scenario_world_key_takes(tmp_path, monkeypatch, capsys):
    # `scenenav world info generated:seed=N,...` (and `default`) name the world a scenario flies:
    # generated and cached on first use, as a run does; a bad spec is one clear error
    monkeypatch.setenv("SCENENAV_CACHE_DIR", str(tmp_path / "cache"))
    spec = "generated:seed=6,width_px=300,height_px=280"
    assert _cli(["world", "info", spec]) == 0
    text = capsys.readouterr().out
    assert "300 x 280 px" in text and "junctions:" in text
    assert _cli(["world", "preview", spec, "--out", str(tmp_path / "p.png")]) == 0
    assert cv2.imread(str(tmp_path / "p.png")) is not None
    with pytest.raises((UserError, ConfigError), match="seed"):
        _cli(["world", "info", "generated:seed=oops"])
