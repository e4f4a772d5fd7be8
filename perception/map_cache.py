"""Whole-world assistant maps: built for a world folder (``build_world_map``), and cached per
(reference map, CNN weights, stride, altitude, FOV; and the DSM when the map is built with relief)
(``cached_assistant_map``).

The stride (the spacing of the rated cells) is asked in metres of ground and turned into whole
pixels of the world being built (``scenenav.core.formats.assistant_map_file.stride_px_for``): 5.3 m
is 10 px on the default 0.53 m/px world and 26 px on a world imported at 0.2 m/px, which a pixel
stride of 10 would have rated 7x as densely for the same ~115 m camera footprint. The map file and
the cache key keep the pixel stride used.

What is classified per cell: on a flat world (or with ``relief`` off) the camera-footprint crop of
the chosen reference map (``reference``: default / orthophoto / perspective, perception/capture.py),
as before. On a world with a surface model and ``relief`` on (the default), the nadir capture a
drone would take over the cell centre, north-up at the altitude, rendered with relief from the
world (``perception.capture.CaptureScene.camera_image``): the image the online CNN classifies in
flight, with its leaning buildings and hidden streets, instead of the reference's flat view.

A scenario whose guidance plans over "the world's assistant map" without naming a file gets one from
here: ``$SCENENAV_CACHE_DIR/assistant-maps/<world>-<hash>.npz`` (``~/.cache/scenenav`` by default),
where the hash covers the reference image bytes, the weights file bytes, the stride, the altitude and
the camera field of view. Building the default world at 5.3 m (10 px) takes about 10 s on one core; the
second run reads the file. Writing goes through a temporary file renamed into place, under a build
lock (``scenenav.core.build_lock``): runs asking at once get one build, the others wait for it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2

from scenenav.core.build_lock import exclusive_build
from scenenav.core.errors import UserError
from scenenav.core.formats.assistant_map_file import (
    BUILD_STRIDE_M,
    WORLD_MAP_STRIDE_M,
    check_stride_m,
    stride_px_for,
)

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


def cache_key(world_dir: Path, weights: Path, stride_px: int, altitude_m: float, fov_deg: float,
              relief: bool = True, reference: str = "default") -> str:
    """Hex digest naming a cached map (changes whenever any input that shapes the map changes; a
    flat world's map with the default reference keeps the key it had before relief existed)."""
    from scenenav.core.formats.world_manifest import (
        DSM_FILE,
        ORTHOPHOTO_FILE,
        REFERENCE_FILE,
        read_manifest,
        reference_file,
    )
    man = read_manifest(world_dir)
    h = hashlib.sha256()
    h.update(_file_digest(world_dir / REFERENCE_FILE).encode())
    h.update(_file_digest(weights).encode())
    h.update(f"{int(stride_px)}|{float(altitude_m):.3f}|{float(fov_deg):.3f}".encode())
    if relief and man.has_dsm:
        h.update(b"relief")
        for name in (DSM_FILE, ORTHOPHOTO_FILE):
            h.update(_file_digest(world_dir / name).encode())
    elif reference != "default" or man.reference.kind.value != "orthophoto":
        kind = man.reference.kind.value if reference == "default" else reference
        h.update(f"reference={kind}".encode())
        if kind == "perspective":
            h.update(_file_digest(world_dir / reference_file(man, kind)).encode())
    return h.hexdigest()[:16]


def build_world_map(world_dir: str, out: str, stride_m: float = BUILD_STRIDE_M, altitude_m: float = 100.0,
                    fov_deg: float = 60.0, weights: str | None = None, batch_size: int = 256,
                    progress: bool = True, png: bool = True, relief: bool = True,
                    reference: str = "default"):
    """Build the whole assistant map of the world folder ``world_dir`` with the CNN ``weights``
    (default: the shipped ones) and write it to ``out`` (.npz, and a Figure-6 PNG beside it with
    ``png``). ``stride_m``: cell spacing on the ground, whole pixels of this world (module
    docstring; the map's ``stride_px`` says which). ``relief`` / ``reference``: what is classified
    (module docstring). Returns (AssistantMap, build seconds). Used by ``scenenav assistant-map build``."""
    from perception.assistant_map import RenderMode, build_assistant_map
    from perception.capture import CaptureScene, CaptureSettings
    from perception.cnn import MatchClassifier
    from perception.matchability import CAMERA_PX
    from worlds.world import load_world
    check_stride_m(stride_m, "--stride-m")
    if not (5.0 <= altitude_m <= 1000.0):
        raise UserError(f"--altitude-m {altitude_m}: expected 5 to 1000 m")
    out_path = Path(out)
    if out_path.suffix != ".npz":
        raise UserError(f"--out {out}: expected a .npz file name")
    world = load_world(world_dir)
    stride_px = stride_px_for(stride_m, world.m_per_px, "--stride-m")
    clf = MatchClassifier.from_file(weights) if weights else MatchClassifier.default()
    scene = CaptureScene.from_world(world, CaptureSettings(relief=relief, reference=reference))
    reference_rgb = world.reference_map(scene.reference_kind)
    gray = cv2.cvtColor(reference_rgb, cv2.COLOR_RGB2GRAY)
    capture = None
    if scene.relief:
        def capture(u: float, v: float):
            # the camera's image, resized for the CNN as the pipeline resizes it in flight
            img = scene.camera_image(u, v, 0.0, altitude_m, fov_deg, CAMERA_PX)
            if clf.input_px == CAMERA_PX:
                return img
            return cv2.resize(img, (clf.input_px, clf.input_px), interpolation=cv2.INTER_AREA)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(unit="crop", desc="assistant map")

    def on_progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()
    t0 = time.perf_counter()
    amap = build_assistant_map(gray, clf.predict_proba, world.m_per_px, altitude_m=altitude_m,
                               fov_deg=fov_deg, stride_px=stride_px, batch_size=batch_size,
                               progress=on_progress, cnn_input_px=clf.input_px,
                               world_name=world.manifest.name,
                               model_id=str(getattr(clf.meta, "training_record_id", "")),
                               method="offline-relief" if scene.relief else "offline", capture=capture)
    elapsed = time.perf_counter() - t0
    if bar is not None:
        bar.close()
    out_path.parent.mkdir(parents=True, exist_ok=True)
    amap.save(out_path)
    if png:
        amap.render_png(out_path.with_suffix(".png"), RenderMode.BINARY)
    return amap, elapsed


def build_notice(world_dir: Path, stride_m: float, stride_px: int) -> str:
    """The line said before a first build: what is built, how big (cells ``stride_m`` apart, which
    is ``stride_px`` on this world), that it is kept."""
    try:
        manifest = json.loads((world_dir / "manifest.json").read_text())
        w, h = int(manifest["width_px"]), int(manifest["height_px"])
        size = (f"{w}x{h} px, about {-(-w // stride_px) * -(-h // stride_px):,} CNN ratings "
                f"{stride_m:g} m ({stride_px} px) apart; ")
    except (OSError, ValueError, KeyError, TypeError):
        size = ""
    return (f"building the assistant map of {world_dir.name} ({size}first use on this machine: it is "
            "cached for later runs); this can take minutes on a large world, Ctrl-C stops it")


def cached_assistant_map(world_dir: str | Path, stride_m: float = WORLD_MAP_STRIDE_M,
                         altitude_m: float = 100.0, fov_deg: float = 60.0,
                         weights: str | Path | None = None, progress: bool = False,
                         relief: bool = True, reference: str = "default",
                         announce: Callable[[str], None] | None = None) -> Path:
    """Path of the world's assistant map built with the CNN ``weights`` (default: the shipped ones),
    its cells ``stride_m`` apart on the ground (whole pixels of this world: module docstring);
    built (with a progress bar if asked) and cached on first use. ``announce`` is told one line
    before a build starts (a large world takes minutes)."""
    from perception.shipped import DEFAULT_WEIGHTS_PATH
    from scenenav.core.formats.world_manifest import read_manifest
    from worlds.default import cache_root
    world_dir = Path(world_dir)
    weights_path = Path(weights) if weights else DEFAULT_WEIGHTS_PATH
    # the key hashes the pixel stride actually used (5.3 m on the default world: 10 px, as before)
    stride_px = stride_px_for(stride_m, read_manifest(world_dir).m_per_px)
    key = cache_key(world_dir, weights_path, stride_px, altitude_m, fov_deg, relief, reference)
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
    with exclusive_build(cache_root(), final.name,
                         lambda: log.info("the assistant map of %s is being built by another process: "
                                          "waiting", world_dir.name)):
        if final.is_file():
            return final
        _build_into(final, world_dir, weights_path, stride_m, stride_px, altitude_m, fov_deg, progress,
                    relief, reference, announce)
    return final


def _build_into(final: Path, world_dir: Path, weights_path: Path, stride_m: float, stride_px: int,
                altitude_m: float, fov_deg: float, progress: bool, relief: bool, reference: str,
                announce: Callable[[str], None] | None) -> None:
    """Build the map into a temporary file of ``final``'s folder and rename it into place
    (``stride_px``: ``stride_m`` on this world, as the build converts it)."""
    folder = final.parent
    log.info("building the assistant map of %s (stride %g m = %d px, first use) -> %s", world_dir.name,
             stride_m, stride_px, final)
    if announce is not None:
        announce(build_notice(world_dir, stride_m, stride_px))
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.stem}-", suffix=".npz", dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        _, elapsed = build_world_map(str(world_dir), str(tmp), stride_m=stride_m, altitude_m=altitude_m,
                                     fov_deg=fov_deg, weights=str(weights_path), progress=progress,
                                     png=False, relief=relief, reference=reference)
        os.replace(tmp, final)
    finally:
        tmp.unlink(missing_ok=True)
    log.info("assistant map built in %.1f s", elapsed)
