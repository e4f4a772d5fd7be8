"""Whole-world assistant maps built once per (reference map, CNN weights, stride, altitude) and cached.

A scenario whose guidance plans over "the world's assistant map" without naming a file gets one from
here: ``$SCENENAV_CACHE_DIR/assistant-maps/<world>-<hash>.npz`` (``~/.cache/scenenav`` by default),
where the hash covers the reference image bytes, the weights file bytes, the stride, the altitude and
the camera field of view. Building the default world at stride 10 takes about 10 s on one core; the
second run reads the file. Writing goes through a temporary file renamed into place, so concurrent
runs are safe.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from pathlib import Path

from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

CACHE_SUBDIR = "assistant-maps"


def _file_digest(path: Path) -> str:
    h = hashlib.sha256()
    try:
        with path.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return h.hexdigest()


def cache_key(world_dir: Path, weights: Path, stride_px: int, altitude_m: float, fov_deg: float) -> str:
    """Hex digest naming a cached map (changes whenever any input that shapes the map changes)."""
    from worlds.world import REFERENCE_FILE
    h = hashlib.sha256()
    h.update(_file_digest(world_dir / REFERENCE_FILE).encode())
    h.update(_file_digest(weights).encode())
    h.update(f"{int(stride_px)}|{float(altitude_m):.3f}|{float(fov_deg):.3f}".encode())
    return h.hexdigest()[:16]


def cached_assistant_map(world_dir: str | Path, stride_px: int = 10, altitude_m: float = 100.0,
                         fov_deg: float = 60.0, weights: str | Path | None = None,
                         progress: bool = False) -> Path:
    """Path of the world's assistant map built with the CNN ``weights`` (default: the shipped ones);
    built (with a progress bar if asked) and cached on first use."""
    from perception.cnn import DEFAULT_WEIGHTS_PATH
    from scenenav.app.commands.assistant_map import build
    from worlds.default import cache_root
    world_dir = Path(world_dir)
    weights_path = Path(weights) if weights else DEFAULT_WEIGHTS_PATH
    key = cache_key(world_dir, weights_path, stride_px, altitude_m, fov_deg)
    folder = cache_root() / CACHE_SUBDIR
    final = folder / f"{world_dir.name}-{key}.npz"
    if final.is_file():
        log.info("assistant map from the cache: %s", final)
        return final
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{folder}: cannot create the assistant-map cache ({exc.strerror}); "
                        "set SCENENAV_CACHE_DIR to a writable folder") from None
    log.info("building the assistant map of %s (stride %d px, first use) -> %s", world_dir.name,
             stride_px, final)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.stem}-", suffix=".npz", dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        _, elapsed = build(str(world_dir), str(tmp), stride_px=stride_px, altitude_m=altitude_m,
                           fov_deg=fov_deg, weights=str(weights_path), progress=progress, png=False)
        os.replace(tmp, final)
    finally:
        tmp.unlink(missing_ok=True)
    log.info("assistant map built in %.1f s", elapsed)
    return final
