"""Checks the launcher runs before any node starts: every file the run will read, and the disk.

Each check uses the reader the node itself uses (``scenenav.core.formats.assistant_map_file`` for
assistant maps, ``perception.cnn.load_weights`` for CNN weights, ``CombinedDecisionModel.load`` for
decision models, ``autopilot_bridge.params`` for parameter files), so a file that passes here is a
file the node accepts, and a bad one is one ``error: ...`` line (exit 2) instead of a node that dies
in flight. The world itself is loaded by the launcher before these checks.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from scenenav.app.scenario import FlightMode, ScenarioConfig, route_for
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

#: Perception methods whose node loads the CNN weights and the assistant map (perception/node.py).
_CNN_METHODS = ("cnn", "assistant-map")


def validate_inputs(cfg: ScenarioConfig, world) -> None:
    """Raise a one-line UserError naming the key and the file when an input of the run is bad."""
    _check_perception(cfg, world)
    _check_guidance(cfg, world)
    _check_route(cfg, world)
    _check_params_file(cfg)
    check_listen_hosts(cfg)
    _warn_rangefinder_limits(cfg)


def _check_perception(cfg: ScenarioConfig, world) -> None:
    p = cfg.perception
    if not p.enabled:
        return
    try:
        world.reference_map(None if p.reference == "default" else p.reference)
    except UserError as exc:
        raise UserError(f"perception.reference = {p.reference!r}: {exc}") from None
    from scenenav.app.nodes import _perception_weights
    weights = _perception_weights(p)
    methods = {p.method} | ({p.swap_method} if p.swap_at_s > 0 else set())
    if weights and weights.endswith(".json"):
        from perception.decision import CombinedDecisionModel
        key = "perception.decision_model"
        _exists(key, weights, "a combined decision model .json (scenenav perception fit-decision)")
        try:
            model = CombinedDecisionModel.load(weights)
        except UserError as exc:
            raise UserError(f"{key}: {exc}") from None
        cnn = model.cnn_weights_path()
        weights = str(cnn) if cnn is not None else None
    if methods & set(_CNN_METHODS):
        from perception.shipped import DEFAULT_WEIGHTS_PATH
        path = weights or str(DEFAULT_WEIGHTS_PATH)
        try:
            checked_once("perception.cnn", path, _load_cnn_weights)
        except UserError as exc:
            raise UserError(f"perception.weights: {exc}") from None
        if p.assistant_map:
            from scenenav.core.formats.assistant_map_file import read_assistant_map_file
            key = "perception.assistant_map"
            _exists(key, p.assistant_map, "an assistant map .npz (scenenav assistant-map build)")
            try:
                read_assistant_map_file(p.assistant_map, world.width_px, world.height_px,
                                        world.m_per_px)
            except UserError as exc:
                raise UserError(f"{key}: {exc}") from None


def _load_cnn_weights(path: str) -> None:
    from perception.cnn import load_weights  # torch: imported only when a file must be read
    load_weights(path)


def checked_once(reader_module: str, path: str, check: Callable[[str], None]) -> None:
    """``check(path)``, unless this very file (its sha256) passed the same reader (the sha256 of
    ``reader_module``'s source) before: a marker in ``$SCENENAV_CACHE_DIR/checked`` remembers a
    pass. Reading the CNN weights costs ~1.5 s of CPU (torch's import); a run folder's launcher
    checks the same shipped file every time. A file that fails is checked again every time."""
    from worlds.default import cache_root
    try:
        digest = hashlib.sha256(Path(path).read_bytes())
        spec = importlib.util.find_spec(reader_module)
        if spec is None or spec.origin is None:
            raise OSError(reader_module)
        digest.update(Path(spec.origin).read_bytes())
    except (OSError, ImportError):
        check(path)      # unreadable: the reader says why, in its own words
        return
    marker = cache_root() / "checked" / f"{reader_module}-{digest.hexdigest()[:32]}"
    if marker.is_file():
        return
    check(path)
    try:
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text(f"{path}\n")
    except OSError:
        pass     # a read-only cache only costs the check next time


def _check_guidance(cfg: ScenarioConfig, world) -> None:
    g = cfg.guidance
    if not g.enabled or not g.assistant_map:
        return
    from scenenav.core.formats.assistant_map_file import check_map_matches_world, read_probability_map
    key = "guidance.assistant_map"
    _exists(key, g.assistant_map, "an assistant map .npz (scenenav assistant-map build), or empty "
                                  "to build one")
    try:
        check_map_matches_world(read_probability_map(g.assistant_map), world.manifest, g.assistant_map)
    except UserError as exc:
        raise UserError(f"{key}: {exc}") from None
    for i, (x, y) in enumerate(g.goals_enu_m):
        _inside_world(f"guidance.goals_enu_m[{i}]", x, y, world)


def _check_route(cfg: ScenarioConfig, world) -> None:
    """The flown route (scripted flights, autopilot flights without guidance) lies on the world."""
    if cfg.flight.mode == FlightMode.AUTOPILOT and cfg.guidance.enabled:
        return
    route = route_for(cfg, world)      # the bowtie for an empty route (UserError if it cannot fit)
    for i, (x, y) in enumerate(route):
        _inside_world(f"flight.route_enu_m[{i}]", x, y, world)
    _inside_world("flight.start_enu_m", *cfg.flight.start_enu_m, world)


def _inside_world(key: str, x: float, y: float, world) -> None:
    half_w = world.width_px * world.m_per_px / 2.0
    half_h = world.height_px * world.m_per_px / 2.0
    if not (abs(x) <= half_w and abs(y) <= half_h):
        raise UserError(f"{key} = [{x:g}, {y:g}]: outside world '{world.manifest.name}'; expected "
                        f"|x| <= {half_w:g} m and |y| <= {half_h:g} m (ENU, origin at the map centre)")


def _check_params_file(cfg: ScenarioConfig) -> None:
    a = cfg.autopilot
    if cfg.flight.mode != FlightMode.AUTOPILOT or not a.params_file:
        return
    from autopilot_bridge.param_specs import PARAM_SPECS
    from autopilot_bridge.params import ParameterStore, load_param_file
    key = "autopilot.params_file"
    _exists(key, a.params_file, 'a JSON file {"NAME": value, ...} of ArduPilot parameters')
    try:
        ParameterStore(PARAM_SPECS, defaults=load_param_file(Path(a.params_file)))
    except UserError as exc:
        detail = str(exc).removeprefix("defaults: ").removeprefix(f"{a.params_file}: ")
        raise UserError(f"{key} = {a.params_file!r}: {detail}") from None


def check_listen_hosts(cfg: ScenarioConfig) -> None:
    """The addresses the run listens on (``external.listen_host``, ``autopilot.mavlink_tcp_host``)
    must be ones this machine can listen on."""
    _check_bindable("external.listen_host", cfg.external.listen_host)
    if cfg.autopilot.mavlink_tcp_port != 0:
        _check_bindable("autopilot.mavlink_tcp_host", cfg.autopilot.mavlink_tcp_host)


def _check_bindable(key: str, host: str) -> None:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, 0))
        except OSError as exc:
            raise UserError(f"{key}: cannot listen on {host} ({exc.strerror}); expected 127.0.0.1, "
                            f"0.0.0.0 or the address of one of this machine's interfaces "
                            f"(`ip -4 addr`)") from None


def _warn_rangefinder_limits(cfg: ScenarioConfig) -> None:
    """A warning (not an error: a user may limit the sensor on purpose) when the simulated flow
    module reaches beyond the autopilot's RNGFND1_MAX_CM, whose readings beyond it it does not fuse."""
    a = cfg.autopilot
    if cfg.flight.mode != FlightMode.AUTOPILOT or not cfg.sim.flow.enabled:
        return
    from autopilot_bridge.param_specs import PARAM_SPECS
    from autopilot_bridge.params import load_param_file
    values = {s.name: s.default for s in PARAM_SPECS if s.name in ("FLOW_TYPE", "RNGFND1_MAX_CM")}
    if a.params_file and Path(a.params_file).is_file():
        values.update(load_param_file(Path(a.params_file)))
    values.update(a.params)
    max_cm = float(values["RNGFND1_MAX_CM"])
    if int(values["FLOW_TYPE"]) == 0 or cfg.sim.flow.range_max_m * 100.0 <= max_cm:
        return
    log.warning("sim.flow.range_max_m is %g m but the autopilot's RNGFND1_MAX_CM is %g cm: it will not "
                "fuse readings beyond %g m; set autopilot.params.RNGFND1_MAX_CM to %d to use them",
                cfg.sim.flow.range_max_m, max_cm, max_cm / 100.0, round(cfg.sim.flow.range_max_m * 100.0))


def _exists(key: str, path: str, expected: str) -> None:
    if not Path(path).is_file():
        raise UserError(f"{key} = {path!r}: no such file; expected {expected}")


# ------------------------------------------------------------------------------------- disk
def free_bytes(path: Path) -> tuple[Path, int]:
    """(the nearest existing folder of ``path``, free bytes on its file system for this user)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p, shutil.disk_usage(p).free


def mount_point(path: Path) -> Path:
    p = Path(path).absolute()
    while not os.path.ismount(p) and p != p.parent:
        p = p.parent
    return p


def check_free_space(out_dir: Path, min_free_mb: float) -> None:
    """Refuse to start a run whose folder's disk has less than ``min_free_mb`` MB free."""
    if min_free_mb <= 0:
        return
    where, free = free_bytes(out_dir)
    if free < min_free_mb * 1e6:
        raise UserError(f"{out_dir}: only {free / 1e6:.1f} MB free on {mount_point(where)}; a run "
                        f"needs at least {min_free_mb:g} MB (recorder.min_free_disk_mb)")
