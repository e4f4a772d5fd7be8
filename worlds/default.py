"""The default world: ``CityConfig()`` (seed 0), generated once and cached on disk.

Location: ``$SCENENAV_CACHE_DIR/worlds/default-v<N>`` (``~/.cache/scenenav`` when the variable is
unset), where N is the generator version, so a changed generator never serves a stale world.
Generation writes into a temporary sibling folder that is renamed into place, so several processes
asking at once are safe: one rename wins, the others load the winner's folder.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from pathlib import Path

from scenenav.errors import UserError
from worlds.generator import GENERATOR_VERSION, CityConfig, generate_world
from worlds.world import MANIFEST_FILE, World

log = logging.getLogger(__name__)

CACHE_ENV = "SCENENAV_CACHE_DIR"
DEFAULT_WORLD_NAME = "default"


def cache_root() -> Path:
    """``$SCENENAV_CACHE_DIR`` or ``~/.cache/scenenav``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "scenenav"


def _generator_fingerprint() -> str:
    """Short hash of the generator's own source: any change to how worlds are drawn gives the
    default world a new cache folder, so no machine keeps flying a stale one."""
    import hashlib
    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in ("generator.py", "reference.py", "landcover.py"):
        try:
            h.update((here / name).read_bytes())
        except OSError:
            pass
    return h.hexdigest()[:10]


def default_world_dir() -> Path:
    """Folder of the cached default world (may not exist yet)."""
    return cache_root() / "worlds" / f"default-v{GENERATOR_VERSION}-{_generator_fingerprint()}"


def load_default_world() -> World:
    """Load the default world, generating and caching it on first use."""
    final = default_world_dir()
    if (final / MANIFEST_FILE).is_file():
        try:
            return World.load(final)
        except UserError as exc:
            log.warning("cached default world is damaged (%s); regenerating", exc)
            _move_aside(final)
    parent = final.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{parent}: cannot create the world cache ({exc.strerror}); "
                        f"set {CACHE_ENV} to a writable folder") from None
    log.info("generating the default world into %s (first use)", final)
    world = generate_world(CityConfig(), name=DEFAULT_WORLD_NAME)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=parent))
    try:
        world.save(tmp)
        try:
            os.rename(tmp, final)
        except OSError as exc:
            # Another process finished first (the target exists and is not empty): use its copy.
            if not (final / MANIFEST_FILE).is_file():
                raise UserError(f"{final}: cannot install the default world ({exc.strerror}); "
                                f"remove that folder or set {CACHE_ENV}") from None
            log.info("default world was cached concurrently by another process")
            return World.load(final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return world


def _move_aside(path: Path) -> None:
    """Rename a damaged cache folder out of the way (then delete it)."""
    trash = Path(tempfile.mkdtemp(prefix=f".{path.name}-broken-", dir=path.parent))
    try:
        os.rename(path, trash / path.name)
    except OSError as exc:
        log.warning("could not move %s aside: %s", path, exc)
    shutil.rmtree(trash, ignore_errors=True)
