"""What changed in the city between the reference day and the capture day.

:func:`plan_changes` draws, from its own random stream, a share of the buildings that were
re-roofed (a new roof tone in the reference), added (built after the reference was taken: on the
capture day, not in the reference, which shows the bare lot) and demolished (in the reference, gone
on the capture day, whose land cover shows the bare lot). :func:`day_scenes` turns the one layout
into the scene of each day; both keep every road, tree and open feature.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from worlds.blocks import Building, RoofStyle
from worlds.city_config import CityConfig
from worlds.drawing import fill_convex
from worlds.materials import FLAT_TONES, GABLE_TONES, UNIFORM_TONES, Material
from worlds.scene import Scene

#: A new roof differs from the old one by at least this much (mean absolute RGB difference, DN).
MIN_RETONE_DN = 30.0


@dataclass(frozen=True)
class Changes:
    """Indices into ``Scene.buildings`` of the buildings that differ between the two days."""

    reroofed: tuple[int, ...]
    new_tones: tuple[tuple[float, float, float], ...]   # the reference's roof tone of each re-roofed
    added: tuple[int, ...]        # on the capture day only
    demolished: tuple[int, ...]   # in the reference only

    @property
    def count(self) -> int:
        return len(self.reroofed) + len(self.added) + len(self.demolished)


def plan_changes(sc: Scene, cfg: CityConfig, rng: np.random.Generator) -> Changes:
    n = len(sc.buildings)
    order = rng.permutation(n)
    k_re = int(round(cfg.reroofed_share * n))
    k_add = int(round(cfg.added_share * n))
    k_dem = int(round(cfg.demolished_share * n))
    reroofed = tuple(sorted(int(i) for i in order[:k_re]))
    added = tuple(sorted(int(i) for i in order[k_re:k_re + k_add]))
    demolished = tuple(sorted(int(i) for i in order[k_re + k_add:k_re + k_add + k_dem]))
    tones = []
    for i in reroofed:
        b = sc.buildings[i]
        palette = GABLE_TONES if b.style in (RoofStyle.GABLE, RoofStyle.HIP) else \
            UNIFORM_TONES + FLAT_TONES if b.style is RoofStyle.UNIFORM else FLAT_TONES
        old = np.array(b.tone[:3], dtype=float)
        cands = [np.array(t, dtype=float) for t in palette]
        far = [t for t in cands if np.abs(t - old).mean() >= MIN_RETONE_DN]
        pick = far[int(rng.integers(len(far)))] if far else \
            np.clip(old + (60.0 if old.mean() < 128 else -60.0), 0, 255)
        pick = np.clip(pick * rng.uniform(0.92, 1.08), 0, 255)
        tones.append((float(pick[0]), float(pick[1]), float(pick[2])))
    return Changes(reroofed=reroofed, new_tones=tuple(tones), added=added, demolished=demolished)


def _without(sc: Scene, gone: tuple[int, ...], material: np.ndarray,
             buildings: list[Building]) -> Scene:
    """``sc`` with the buildings ``gone`` replaced by bare ground (``material`` is changed in place)."""
    for i in gone:
        fill_convex(material, sc.buildings[i].corners, int(Material.GROUND))
    keep = [b for i, b in enumerate(buildings) if i not in set(gone)]
    bbox = (np.array([np.concatenate([b.corners.min(axis=0), b.corners.max(axis=0)]) for b in keep])
            if keep else np.zeros((0, 4)))
    return dataclasses.replace(sc, material=material, buildings=keep, bld_bbox=bbox)


def day_scenes(sc: Scene, changes: Changes) -> tuple[Scene, Scene]:
    """(capture scene, reference scene). The capture scene reuses ``sc.material`` (changed in place)."""
    ref_buildings = list(sc.buildings)
    for i, tone in zip(changes.reroofed, changes.new_tones, strict=True):
        ref_buildings[i] = dataclasses.replace(ref_buildings[i], tone=tone)
    reference = _without(sc, changes.added, sc.material.copy(), ref_buildings)
    capture = _without(sc, changes.demolished, sc.material, list(sc.buildings))
    return capture, reference
