"""The "other day": capture conditions of the orthophoto and of the reference map.

A generated world is rendered twice from the same layout (``worlds/generator.py``): once as the
orthophoto the drone flies over ("day A", near-neutral) and once as the reference map, the same
area captured on another day. The reference differs the way a real archive image differs:

* a different sun (azimuth and elevation), hence different shadows and roof-facet shading;
* natural surfaces (grass, forest canopy, water ripples) get fresh texture from a different random
  stream, parked and moving cars are different; roads and buildings are geometrically identical;
* illumination and sensor: haze, gamma, contrast, brightness, colour balance, optical blur,
  sensor noise and a JPEG compression round trip.

This module holds the day conditions and the photometric pipeline, plus the seamless noise fields
both renderings draw their textures from. It does not import the generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np

#: Standard deviation of bicubically upsampled unit white noise (measured), used to renormalise.
_CUBIC_UPSAMPLE_STD = 0.858
#: Standard deviation of the sum of two independent uniform bytes: sqrt(2 * (256**2 - 1) / 12).
_TRIANGLE_STD = 104.5


class NoiseField:
    """Zero-mean unit-variance white noise over an unbounded set of rows, in fixed 64-row blocks.

    Block ``b`` is always drawn from ``default_rng([*key, b + offset])``, so any row range can be
    produced on its own and strips rendered separately join without seams, for any strip size.
    """

    BLOCK_ROWS = 64
    _ROW_OFFSET = 1 << 24  # keeps block numbers of negative rows non-negative for SeedSequence

    def __init__(self, key: tuple[int, ...], width: int) -> None:
        self.key = tuple(int(k) for k in key)
        self.width = int(width)

    def rows(self, r0: int, r1: int) -> np.ndarray:
        """Rows [r0, r1) as a float32 (r1 - r0, width) array (r0 may be negative)."""
        n = self.BLOCK_ROWS
        b0 = r0 // n
        b1 = (r1 - 1) // n
        count = (b1 - b0 + 1) * n * self.width
        raw = np.empty((2, count), dtype=np.uint8)
        size = n * self.width
        for i, b in enumerate(range(b0, b1 + 1)):
            rng = np.random.default_rng([*self.key, b + self._ROW_OFFSET])
            block = np.frombuffer(rng.bytes(2 * size), dtype=np.uint8)
            raw[:, i * size:(i + 1) * size] = block.reshape(2, size)
        # The sum of two uniform bytes is triangular (mean 255, std 104.5); after any blur it is
        # indistinguishable from Gaussian noise, and it is several times faster to draw.
        x = raw[0].astype(np.float32)
        x += raw[1]
        x -= 255.0
        x *= 1.0 / _TRIANGLE_STD
        full = x.reshape(-1, self.width)
        return full[r0 - b0 * n: r1 - b0 * n]


class SmoothNoise:
    """Band-limited noise with unit std and feature size ~``scale_px`` (bicubic coarse grid)."""

    _PAD = 2

    def __init__(self, key: tuple[int, ...], width: int, scale_px: float) -> None:
        self.scale = max(1, int(round(scale_px)))
        self.width = int(width)
        self.coarse_width = self.width // self.scale + 2 * self._PAD + 2
        self._grid = NoiseField(key, self.coarse_width)

    def rows(self, r0: int, r1: int) -> np.ndarray:
        s = self.scale
        if s == 1:
            return self._grid.rows(r0, r1)[:, self._PAD:self._PAD + self.width]
        c0 = r0 // s - self._PAD
        c1 = (r1 - 1) // s + self._PAD + 1
        grid = self._grid.rows(c0, c1)
        up: np.ndarray = cv2.resize(grid, (self.coarse_width * s, (c1 - c0) * s), interpolation=cv2.INTER_CUBIC)
        y0 = r0 - c0 * s
        x0 = self._PAD * s
        out = up[y0:y0 + (r1 - r0), x0:x0 + self.width]
        out *= 1.0 / _CUBIC_UPSAMPLE_STD
        return out


class Season(str, Enum):
    """The season of a capture: ``winter`` has leaf-off trees and snow on grass and flat roofs."""

    SUMMER = "summer"
    WINTER = "winter"


#: Share of the sunlight a tree crown stops: a summer crown ~0.9 (foliage lets sun flecks through),
#: a leaf-off crown ~0.35 (branches only; crown porosity of deciduous trees in winter 0.5-0.8,
#: Heisler, "Effects of individual trees on the solar radiation climate", J. Clim. Appl. Met. 1986).
TREE_OPACITY = {Season.SUMMER: 0.9, Season.WINTER: 0.35}


@dataclass(frozen=True)
class DayConditions:
    """Everything that differs between two captures of the same area."""

    name: str
    nature_seed: int           # random stream for grass/forest/water texture
    traffic_seed: int          # random stream for cars
    sensor_seed: int           # random stream for sensor noise
    sun_azimuth_deg: float     # compass, clockwise from north, direction *to* the sun
    sun_elevation_deg: float
    shadow_strength: float     # fraction of light removed in full shadow
    gamma: float
    contrast: float
    brightness_dn: float
    gains_rgb: tuple[float, float, float]
    haze: float                # 0..1 blend towards a bright grey veil
    blur_sigma_px: float
    noise_sigma_dn: float
    jpeg_quality: int | None   # None: no compression
    grass_dryness: float       # 0 lush green .. 1 dry yellow
    water_wave_dir_deg: float
    water_wave_m: float
    season: Season = Season.SUMMER

    @property
    def tree_opacity(self) -> float:
        return TREE_OPACITY[Season(self.season)]

    def sun_vector_px(self) -> np.ndarray:
        """Unit horizontal vector towards the sun in image axes (u right = east, v down = south)."""
        az = math.radians(self.sun_azimuth_deg)
        return np.array([math.sin(az), -math.cos(az)])

    def shadow_offset_px(self, height_m: float, m_per_px: float) -> np.ndarray:
        """Image offset (du, dv) of the shadow of a point ``height_m`` above the ground."""
        length_px = height_m / math.tan(math.radians(self.sun_elevation_deg)) / m_per_px
        return -self.sun_vector_px() * length_px


def capture_day(rng: np.random.Generator) -> DayConditions:
    """Conditions of the orthophoto: clear midday-ish sun, mild optics and noise, no JPEG."""
    return DayConditions(
        name="capture", nature_seed=int(rng.integers(1 << 31)),
        traffic_seed=int(rng.integers(1 << 31)), sensor_seed=int(rng.integers(1 << 31)),
        sun_azimuth_deg=float(rng.uniform(125.0, 165.0)),
        sun_elevation_deg=float(rng.uniform(42.0, 58.0)),
        shadow_strength=float(rng.uniform(0.48, 0.56)),
        gamma=1.0, contrast=1.0, brightness_dn=0.0, gains_rgb=(1.0, 1.0, 1.0), haze=0.0,
        blur_sigma_px=0.6, noise_sigma_dn=1.5, jpeg_quality=None,
        grass_dryness=float(rng.uniform(0.0, 0.3)),
        water_wave_dir_deg=float(rng.uniform(0.0, 180.0)),
        water_wave_m=float(rng.uniform(2.0, 3.5)),
    )


def other_day(rng: np.random.Generator, capture: DayConditions,
              season: Season = Season.SUMMER) -> DayConditions:
    """Conditions of the reference map: another time of day, another camera, ``season``.

    A winter sun is lower: 18-30 degrees (the noon sun at 48 degrees north in December-February,
    NOAA solar calculator), against 36-62 degrees in summer.
    """
    season = Season(season)
    gains = tuple(float(g) for g in rng.uniform(0.9, 1.1, size=3))
    return DayConditions(
        name="reference", nature_seed=int(rng.integers(1 << 31)),
        traffic_seed=int(rng.integers(1 << 31)), sensor_seed=int(rng.integers(1 << 31)),
        sun_azimuth_deg=float((capture.sun_azimuth_deg + rng.choice([-1.0, 1.0])
                               * rng.uniform(40.0, 80.0)) % 360.0),
        sun_elevation_deg=float(rng.uniform(36.0, 62.0) if season is Season.SUMMER
                                else rng.uniform(18.0, 30.0)),
        shadow_strength=float(rng.uniform(0.35, 0.55)),
        gamma=float(rng.uniform(0.78, 1.3)),
        contrast=float(rng.uniform(0.8, 1.12)),
        brightness_dn=float(rng.uniform(-12.0, 12.0)),
        gains_rgb=(gains[0], gains[1], gains[2]),
        haze=float(rng.uniform(0.0, 0.1)),
        blur_sigma_px=float(rng.uniform(0.9, 1.4)),
        noise_sigma_dn=float(rng.uniform(3.0, 5.0)),
        jpeg_quality=int(rng.integers(55, 76)),
        grass_dryness=float(rng.uniform(0.3, 0.9)),
        water_wave_dir_deg=float((capture.water_wave_dir_deg + rng.uniform(40.0, 140.0)) % 180.0),
        water_wave_m=float(rng.uniform(1.5, 4.0)),
        season=season,
    )


def tone_map(rgb: np.ndarray, day: DayConditions) -> np.ndarray:
    """Haze, gamma, contrast, brightness and colour balance on a float32 RGB array (0..255)."""
    x = np.clip(rgb, 0.0, 255.0)
    x *= 1.0 / 255.0
    if day.haze > 0.0:
        x *= 1.0 - day.haze
        x += day.haze * 0.82
    if day.gamma != 1.0:
        np.power(x, day.gamma, out=x)
    if day.contrast != 1.0 or day.brightness_dn != 0.0:
        x -= 0.5
        x *= day.contrast
        x += 0.5 + day.brightness_dn / 255.0
    x *= np.asarray(day.gains_rgb, dtype=np.float32) * 255.0
    return x


def jpeg_round_trip(rgb: np.ndarray, quality: int) -> np.ndarray:
    """Encode to JPEG and decode again (uint8 RGB in, uint8 RGB out)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    bgr = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if bgr is None:
        raise RuntimeError("JPEG decoding failed")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


_JPEG_PAD_ROWS = 16   # one JPEG MCU row: decoding uses the neighbouring MCU rows


def finish_strip(canvas: np.ndarray, top: int, rows: int, r0: int, day: DayConditions,
                 sensor: NoiseField) -> np.ndarray:
    """Photometry of one rendered strip -> uint8 RGB rows [r0, r0 + rows).

    ``canvas`` is float32 (h, W, 3) covering image rows [r0 - top, r0 - top + h): the extra rows
    are a margin so the optical blur and the JPEG round trip have no seams between strips.
    ``r0`` must be a multiple of 16 so JPEG blocks line up with those of a whole-image encode.
    ``sensor`` is a NoiseField of width 3 * W.
    """
    x = tone_map(canvas, day)
    if day.blur_sigma_px > 0.0:
        x = cv2.GaussianBlur(x, (0, 0), day.blur_sigma_px, borderType=cv2.BORDER_REFLECT)
    pad_top = min(_JPEG_PAD_ROWS, top) if day.jpeg_quality is not None else 0
    pad_bottom = min(_JPEG_PAD_ROWS, x.shape[0] - top - rows) if day.jpeg_quality is not None else 0
    core = x[top - pad_top:top + rows + pad_bottom]
    n = core.shape[0]
    if day.noise_sigma_dn > 0.0:
        noise = sensor.rows(r0 - pad_top, r0 - pad_top + n).reshape(n, -1, 3)
        core += noise * day.noise_sigma_dn
    out = np.clip(core + 0.5, 0.0, 255.0).astype(np.uint8)
    if day.jpeg_quality is not None:
        out = jpeg_round_trip(out, day.jpeg_quality)
    return out[pad_top:pad_top + rows]
