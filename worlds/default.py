"""The default world and other generated worlds named in a scenario, generated once and cached.

``world: default`` is ``CityConfig()`` (seed 0, 900x1000 px). ``world: generated:seed=3,width_px=1500``
is any ``CityConfig`` given as comma-separated ``key=value`` pairs (unnamed keys keep their defaults),
so a scenario can name a reproducible world without shipping its images.

Location: ``$SCENENAV_CACHE_DIR/worlds/<name>-v<N>-<hash>`` (``~/.cache/scenenav`` when the variable is
unset), where N is the generator version and the hash covers the generator's source (and, for
``generated:`` worlds, the configuration), so a changed generator never serves a stale world.
Generation writes into a temporary sibling folder that is renamed into place, and holds a build lock
(``scenenav.core.build_lock``): several processes asking at once get one generation, the others
wait for it and load its folder.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from pathlib import Path

from scenenav.core.build_lock import exclusive_build
from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import MANIFEST_FILE
from worlds.city_config import GENERATOR_SOURCES, GENERATOR_VERSION, CityConfig
from worlds.world import World

log = logging.getLogger(__name__)

CACHE_ENV = "SCENENAV_CACHE_DIR"
DEFAULT_WORLD_NAME = "default"
GENERATED_PREFIX = "generated:"


def cache_root() -> Path:
    """``$SCENENAV_CACHE_DIR`` or ``~/.cache/scenenav``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "scenenav"


def _generator_fingerprint(folder: Path | None = None) -> str:
    """Short hash of the generator's own source (every file of ``GENERATOR_SOURCES``, sorted, read
    from ``folder``, default this package): any change to how worlds are drawn gives the default
    world a new cache folder, so no machine keeps flying a stale one."""
    import hashlib
    here = folder if folder is not None else Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in sorted(GENERATOR_SOURCES):
        try:
            h.update((here / name).read_bytes())
        except OSError:
            pass
    return h.hexdigest()[:10]


def default_world_dir() -> Path:
    """Folder of the cached default world (may not exist yet)."""
    return cache_root() / "worlds" / f"default-v{GENERATOR_VERSION}-{_generator_fingerprint()}"


def is_generated_spec(spec: str) -> bool:
    """``default`` or ``generated:...``: a world the generator makes on first use."""
    return spec == DEFAULT_WORLD_NAME or spec.startswith(GENERATED_PREFIX)


def parse_generated_spec(spec: str) -> CityConfig:
    """``generated:seed=3,width_px=1500,height_px=900`` -> CityConfig (one-line UserError if bad)."""
    import dataclasses
    body = spec[len(GENERATED_PREFIX):].strip()
    fields = {f.name: f for f in dataclasses.fields(CityConfig)}
    kwargs: dict = {}
    for item in filter(None, (part.strip() for part in body.split(","))):
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or key not in fields:
            known = "seed, width_px, height_px, m_per_px, water_share, lake_diameter_m, ..."
            raise UserError(f"world {spec!r}: {item!r} is not KEY=VALUE with a CityConfig key "
                            f"(e.g. {known}; see worlds/city_config.py)")
        default = getattr(CityConfig(), key)
        try:
            kwargs[key] = type(default)(text.strip()) if not isinstance(default, bool) else \
                text.strip().lower() in ("1", "true", "yes")
        except ValueError:
            raise UserError(f"world {spec!r}: {key} = {text!r}: expected "
                            f"{type(default).__name__}") from None
    try:
        return CityConfig(**kwargs)
    except (ValueError, TypeError) as exc:
        raise UserError(f"world {spec!r}: {exc}") from None


def generated_world_dir(cfg: CityConfig) -> Path:
    """Cache folder of a generated (non-default) world."""
    import dataclasses
    import hashlib
    import json
    digest = hashlib.sha256(json.dumps(dataclasses.asdict(cfg), sort_keys=True).encode()).hexdigest()
    return (cache_root() / "worlds" /
            f"generated-s{cfg.seed}-{cfg.width_px}x{cfg.height_px}-v{GENERATOR_VERSION}-"
            f"{_generator_fingerprint()}-{digest[:8]}")


def load_world_spec(spec: str) -> World:
    """A world named by ``default`` or ``generated:KEY=VALUE,...`` (generated and cached on first use)."""
    if spec == DEFAULT_WORLD_NAME:
        return load_default_world()
    cfg = parse_generated_spec(spec)
    return _load_or_generate(generated_world_dir(cfg), cfg, f"generated-s{cfg.seed}")


def world_folder(spec: str) -> Path:
    """Folder of the world named by a scenario's ``world`` value (generated ones: made if missing)."""
    if not is_generated_spec(spec):
        return Path(spec)
    folder = default_world_dir() if spec == DEFAULT_WORLD_NAME else \
        generated_world_dir(parse_generated_spec(spec))
    if not (folder / MANIFEST_FILE).is_file():
        load_world_spec(spec)
    return folder


def load_default_world() -> World:
    """Load the default world, generating and caching it on first use."""
    return _load_or_generate(default_world_dir(), CityConfig(), DEFAULT_WORLD_NAME)


def _load_or_generate(final: Path, cfg: CityConfig, name: str) -> World:
    if (final / MANIFEST_FILE).is_file():
        try:
            return World.load(final)
        except UserError as exc:
            log.warning("cached world %s is damaged (%s); regenerating", final.name, exc)
            _move_aside(final)
    # one process generates, the others asking at once wait for it and load its copy
    with exclusive_build(cache_root(), final.name,
                         lambda: log.info("world %s is being generated by another process: waiting", name)):
        if (final / MANIFEST_FILE).is_file():
            return World.load(final)
        return _generate(final, cfg, name)


def _generate(final: Path, cfg: CityConfig, name: str) -> World:
    parent = final.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{parent}: cannot create the world cache ({exc.strerror}); "
                        f"set {CACHE_ENV} to a writable folder") from None
    log.info("generating world %s into %s (first use)", name, final)
    # imported here: a process that loads a cached world never pays for the generator (numba)
    from worlds.generator import generate_world
    world = generate_world(cfg, name=name)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=parent))
    try:
        world.save(tmp)
        try:
            os.rename(tmp, final)
        except OSError as exc:
            # Another process finished first (the target exists and is not empty): use its copy.
            if not (final / MANIFEST_FILE).is_file():
                raise UserError(f"{final}: cannot install world {name} ({exc.strerror}); "
                                f"remove that folder or set {CACHE_ENV}") from None
            log.info("world %s was cached concurrently by another process", name)
            return World.load(final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    # What the cache holds, not the generator's in-memory copy: the two differ slightly (the saved
    # files round some arrays), and the first run after generating must see the same world as
    # every later run (determinism; found when a renderer check differed on that first run only).
    del world
    return World.load(final)


def _move_aside(path: Path) -> None:
    """Rename a damaged cache folder out of the way (then delete it)."""
    trash = Path(tempfile.mkdtemp(prefix=f".{path.name}-broken-", dir=path.parent))
    try:
        os.rename(path, trash / path.name)
    except OSError as exc:
        log.warning("could not move %s aside: %s", path, exc)
    shutil.rmtree(trash, ignore_errors=True)
