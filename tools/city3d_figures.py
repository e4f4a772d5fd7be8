"""Write the pictures of docs/worlds.md for the 3-D city (docs/img/city3d-*.png).

    PYTHONPATH=. python tools/city3d_figures.py [--seed 0] [--out docs/img]

* ``city3d-dsm.png``: a hillshade of the DSM beside the orthophoto (the whole default world at 40 %);
* ``city3d-reference.png``: the orthophoto reference beside the perspective reference (500 m) around
  the tallest building far from the map centre, at full resolution, with the centre's direction marked;
* ``city3d-winter.png``: the summer reference beside the winter reference of the same crop.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np

from worlds.generator import CityConfig, generate_world


def hillshade(dsm_m: np.ndarray, m_per_px: float, azimuth_deg: float = 315.0,
              elevation_deg: float = 45.0) -> np.ndarray:
    """Grey uint8 hillshade (light from the north-west, 45 degrees up)."""
    gy, gx = np.gradient(dsm_m.astype(np.float64), m_per_px)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    shade = np.sin(el) * np.cos(slope) + np.cos(el) * np.sin(slope) * np.cos(az - aspect)
    tint = 0.35 + 0.65 * np.clip(shade, 0.0, 1.0)
    tint *= 0.6 + 0.4 * np.clip(dsm_m / 30.0, 0.0, 1.0)      # higher = brighter
    return np.clip(tint * 255.0, 0, 255).astype(np.uint8)


def _side_by_side(panels: list[np.ndarray], gap: int = 6) -> np.ndarray:
    h = max(p.shape[0] for p in panels)
    sep = np.full((h, gap, 3), 255, dtype=np.uint8)
    out = []
    for i, p in enumerate(panels):
        if p.ndim == 2:
            p = np.repeat(p[:, :, None], 3, axis=2)
        out += ([sep] if i else []) + [p]
    return np.hstack(out)


def _write(path: Path, rgb: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {path} ({path.stat().st_size // 1024} KB)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="city seed (default 0, the default world)")
    ap.add_argument("--out", default="docs/img", help="folder for the PNGs (default docs/img)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = CityConfig(seed=args.seed)
    world = generate_world(cfg)
    dsm = world.dsm_m
    assert dsm is not None and world.reference_perspective is not None
    mpp = world.m_per_px
    half = (world.width_px * 2 // 5, world.height_px * 2 // 5)
    _write(out / "city3d-dsm.png", _side_by_side([
        cv2.resize(hillshade(dsm, mpp), half, interpolation=cv2.INTER_AREA),
        cv2.resize(world.orthophoto, half, interpolation=cv2.INTER_AREA) // 4 * 4]))   # < 300 KB
    # the crop: around the tallest pixel at least 150 m from the centre
    H, W = dsm.shape
    vv, uu = np.mgrid[0:H, 0:W]
    far = np.hypot(uu + 0.5 - W / 2, vv + 0.5 - H / 2) * mpp > 150.0
    r, c = np.unravel_index(int(np.argmax(np.where(far, dsm, 0.0))), dsm.shape)
    size = 200
    y0 = int(np.clip(r - size // 2, 0, H - size))
    x0 = int(np.clip(c - size // 2, 0, W - size))
    crops = [np.ascontiguousarray(img[y0:y0 + size, x0:x0 + size])
             for img in (world.reference, world.reference_perspective)]
    # an arrow towards the map centre on the perspective crop
    d = np.array([W / 2 - (x0 + size / 2), H / 2 - (y0 + size / 2)])
    d = d / max(1e-9, float(np.hypot(*d))) * 30
    cv2.arrowedLine(crops[1], (size // 2, size // 2), (int(size // 2 + d[0]), int(size // 2 + d[1])),
                    (255, 0, 0), 2, tipLength=0.3)
    big = [cv2.resize(c_, (2 * size, 2 * size), interpolation=cv2.INTER_NEAREST) for c_ in crops]
    _write(out / "city3d-reference.png", _side_by_side(big))
    winter = generate_world(dataclasses.replace(cfg, season="winter"))
    w_crops = [np.ascontiguousarray(img[y0:y0 + 2 * size, x0 - size // 2:x0 + 3 * size // 2])
               if x0 >= size // 2 else np.ascontiguousarray(img[y0:y0 + 2 * size, :2 * size])
               for img in (world.reference, winter.reference)]
    _write(out / "city3d-winter.png", _side_by_side(w_crops))
    print(f"tallest building off-centre at pixel ({c}, {r}): {dsm[r, c]:.1f} m, "
          f"{math.hypot(c + 0.5 - W / 2, r + 0.5 - H / 2) * mpp:.0f} m from the centre")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
