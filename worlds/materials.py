"""Surface materials of the material raster, their land-cover classes and their look.

Every pixel of a city's material raster holds one :class:`Material`; :data:`MATERIAL_TO_COVER` maps
it onto the :class:`~worlds.landcover.LandCover` ground truth, and the tables below give each
material its base colour and structural-texture amplitudes (the rendering's palette), plus the roof
tones and car colours the layout and the traffic draw from.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from worlds.landcover import LandCover


class Material(IntEnum):
    """Internal surface materials of the rendering; each maps onto one LandCover class."""

    GROUND = 0         # paved yards, bare ground
    SIDEWALK = 1
    KERB = 2
    ROAD = 3
    MARKING = 4        # lane markings and zebra crossings (on the carriageway)
    SQUARE = 5
    PARKING = 6
    PARKING_LINE = 7
    GRASS = 8
    FOREST = 9
    WATER = 10
    SAND = 11          # beaches, embankments
    ROOF_TEXTURED = 12
    ROOF_UNIFORM = 13


MATERIAL_TO_COVER = np.zeros(256, dtype=np.uint8)
for _m, _c in {
    Material.GROUND: LandCover.UNKNOWN, Material.SIDEWALK: LandCover.UNKNOWN,
    Material.KERB: LandCover.UNKNOWN, Material.ROAD: LandCover.ROAD,
    Material.MARKING: LandCover.ROAD, Material.SQUARE: LandCover.SQUARE,
    Material.PARKING: LandCover.PARKING, Material.PARKING_LINE: LandCover.PARKING,
    Material.GRASS: LandCover.GRASS, Material.FOREST: LandCover.FOREST,
    Material.WATER: LandCover.WATER, Material.SAND: LandCover.UNKNOWN,
    Material.ROOF_TEXTURED: LandCover.BUILDING_TEXTURED,
    Material.ROOF_UNIFORM: LandCover.BUILDING_UNIFORM,
}.items():
    MATERIAL_TO_COVER[int(_m)] = int(_c)

# Base colour (RGB) and structural-texture amplitudes (DN) per material: fine (pixel), medium
# (~3 m) and coarse (~25 m) noise. Natural materials (grass, forest, water) get their texture from
# the day's own random stream instead (see worlds/rendering.py).
_MATERIAL_STYLE = {
    #                      base RGB          fine  med  coarse
    Material.GROUND:       ((146, 140, 128), 7.0, 7.0, 9.0),
    Material.SIDEWALK:     ((170, 167, 160), 5.0, 3.0, 5.0),
    Material.KERB:         ((198, 196, 190), 4.0, 0.0, 0.0),
    Material.ROAD:         ((84, 85, 88), 5.0, 4.0, 7.0),
    Material.MARKING:      ((222, 222, 212), 6.0, 8.0, 0.0),
    Material.SQUARE:       ((160, 156, 148), 1.2, 0.0, 0.0),
    Material.PARKING:      ((96, 96, 99), 5.0, 4.0, 6.0),
    Material.PARKING_LINE: ((214, 214, 204), 6.0, 0.0, 0.0),
    Material.GRASS:        ((92, 128, 58), 0.0, 0.0, 0.0),
    Material.FOREST:       ((46, 76, 38), 0.0, 0.0, 0.0),
    Material.WATER:        ((40, 66, 78), 0.0, 0.0, 0.0),
    Material.SAND:         ((186, 172, 138), 6.0, 5.0, 6.0),
    Material.ROOF_TEXTURED: ((150, 150, 150), 6.0, 4.0, 0.0),
    Material.ROOF_UNIFORM: ((188, 188, 184), 0.8, 0.0, 0.0),
}
BASE_RGB = np.zeros((256, 3), dtype=np.float32)
AMP_FINE = np.zeros(256, dtype=np.float32)
AMP_MED = np.zeros(256, dtype=np.float32)
AMP_COARSE = np.zeros(256, dtype=np.float32)
for _m, (_rgb, _f, _md, _co) in _MATERIAL_STYLE.items():
    BASE_RGB[int(_m)] = _rgb
    AMP_FINE[int(_m)] = _f
    AMP_MED[int(_m)] = _md
    AMP_COARSE[int(_m)] = _co

GRASS_LUSH = np.array([82, 126, 52], dtype=np.float32)
GRASS_DRY = np.array([136, 138, 78], dtype=np.float32)
FOREST_BASE = np.array([44, 74, 36], dtype=np.float32)
WATER_BASE = np.array([38, 64, 76], dtype=np.float32)
#: Winter: fresh snow seen from above (albedo 0.8-0.9, slightly blue), and leaf-off branches.
SNOW_RGB = np.array([232, 236, 242], dtype=np.float32)
BRANCH_RGB = np.array([104, 96, 86], dtype=np.float32)

GABLE_TONES = ((168, 86, 64), (142, 72, 58), (96, 96, 104), (118, 94, 78), (128, 126, 122),
                (104, 136, 122))
GABLE_WEIGHTS = (0.34, 0.18, 0.2, 0.14, 0.1, 0.04)
FLAT_TONES = ((176, 172, 164), (128, 126, 122), (206, 204, 198), (150, 146, 138), (96, 96, 104))
FLAT_WEIGHTS = (0.3, 0.22, 0.18, 0.2, 0.1)
UNIFORM_TONES = ((192, 192, 188), (172, 180, 188), (206, 206, 200))
CAR_COLOURS = ((236, 236, 234), (30, 30, 34), (162, 164, 168), (92, 94, 98), (150, 32, 30),
                (34, 54, 120), (200, 182, 70))
CAR_WEIGHTS = (0.25, 0.2, 0.24, 0.1, 0.08, 0.08, 0.05)

# Wall colours (RGB) by wall material: the base colour of a facade in diffuse daylight. They are a
# shade darker than the roofs (walls face the sky only half and the sun at a grazing angle; measured
# facade albedos: plaster 0.4-0.6, brick 0.2-0.35, concrete 0.3-0.4, glass curtain walls 0.1-0.2,
# Taha, "Urban climates and heat islands: albedo", Energy and Buildings 25, 1997).
FACADE_PALETTE: dict[str, tuple[tuple[int, int, int], ...]] = {
    "plaster": ((186, 176, 156), (194, 188, 178), (178, 154, 112), (160, 168, 162), (176, 150, 132)),
    "brick": ((140, 78, 58), (116, 68, 52), (152, 100, 74)),
    "concrete": ((140, 138, 132), (118, 116, 112), (150, 146, 136)),
    "glass": ((62, 84, 100), (76, 96, 106), (54, 66, 82)),
    "metal": ((156, 160, 164), (112, 122, 132), (136, 136, 128)),
}
#: Side colour of tree crowns (dark green: the shaded inside of the canopy).
TREE_FACADE_RGB = (30, 50, 26)
