"""ArduPilot-named, typed parameters with range checks, JSON persistence and observers.

Pure module (no pymavlink). The MAVLink server serves these over the parameter protocol
(PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET -> PARAM_VALUE); the flight core reads
them (``store.get("WPNAV_SPEED")``) and subscribes to changes (``store.add_observer``).

Names, types, units, defaults and ranges follow ArduCopter 4.5 (``@Param`` documentation in
ArduPilot ``ArduCopter/Parameters.cpp``, ``libraries/AC_WPNav/AC_WPNav.cpp``,
``libraries/AP_NavEKF3/AP_NavEKF3.cpp``, ``libraries/GCS_MAVLink/GCS.cpp``).

What a set accepts, as ArduPilot: any value within the parameter's type (an integer that fits
INT8/16/32, a finite float32); the documented range (``min_value`` .. ``max_value``) is
ground-station metadata, as ArduPilot's ``@Range`` is. Two exceptions, each said in the reply:

* a value beyond a parameter's **safe limit** (``safe_min`` / ``safe_max``) is clamped to it,
  where the flight core would otherwise be unsafe (no descent in LAND, a zero mass in the mixer)
  or where ArduPilot's own code clamps (``AC_WPNav``: WPNAV_SPEED >= 20 cm/s, WPNAV_RADIUS >= 5 cm,
  WPNAV_ACCEL >= 50 cm/s/s; ``ArduCopter/config.h``: RTL_ALT >= 30 cm); the reason goes back with
  the stored value;
* an enumerated value this stack does not implement (``ParamSpec.values``) is refused: the old
  value stays and the server answers with it plus a STATUSTEXT, the way ArduPilot answers a write
  to a read-only parameter (ArduPilot stores it and runs that feature, which does not exist here).

Integer parameters are converted from the float on the wire as ArduPilot's
``AP_Param::set_float`` does (truncation after adding 0.01 towards the sign).
"""

from __future__ import annotations

import json
import logging
import math
import os
import struct
import tempfile
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Callable, Iterable, Mapping, NamedTuple

from scenenav.core.errors import UserError

logger = logging.getLogger(__name__)

PARAM_NAME_MAX_LEN = 16  # PARAM_VALUE.param_id is char[16]


class ParamType(IntEnum):
    """MAV_PARAM_TYPE values ArduPilot uses (AP_Int8/16/32, AP_Float)."""

    INT8 = 2
    INT16 = 4
    INT32 = 6
    REAL32 = 9


_INT_LIMITS: dict[ParamType, tuple[int, int]] = {
    ParamType.INT8: (-(2 ** 7), 2 ** 7 - 1),
    ParamType.INT16: (-(2 ** 15), 2 ** 15 - 1),
    ParamType.INT32: (-(2 ** 31), 2 ** 31 - 1),
}


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, MAVLink type, default, inclusive range, unit and meaning."""

    name: str
    ptype: ParamType
    default: float
    min_value: float
    max_value: float
    units: str = ""
    description: str = ""
    # allowed enumerated values as (value, label); empty = any value of the type
    values: tuple[tuple[int, str], ...] = ()
    # safe limits: a value beyond them is clamped (None = no limit); see the module docstring
    safe_min: float | None = None
    safe_max: float | None = None

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > PARAM_NAME_MAX_LEN or not self.name.isascii():
            raise ValueError(f"parameter name {self.name!r}: expected 1..16 ASCII characters")
        if not self.min_value <= self.default <= self.max_value:
            raise ValueError(f"{self.name}: default {self.default} outside "
                             f"[{self.min_value}, {self.max_value}]")
        if self.values and int(self.default) not in {v for v, _ in self.values}:
            raise ValueError(f"{self.name}: default {self.default} not among the allowed values")
        if not ((self.safe_min is None or self.safe_min <= self.default)
                and (self.safe_max is None or self.default <= self.safe_max)):
            raise ValueError(f"{self.name}: default {self.default} beyond its safe limits")

    @property
    def is_integer(self) -> bool:
        return self.ptype != ParamType.REAL32

    def coerce(self, value: float) -> tuple[float | None, str]:
        """The stored value for a requested ``value`` and a note when it was clamped, or
        ``(None, reason)`` when refused."""
        try:
            v = float(value)
        except (TypeError, ValueError):
            return None, f"{self.name}: not a number"
        if not math.isfinite(v):
            return None, f"{self.name}: {v} is not finite"
        if self.is_integer:
            lo, hi = _INT_LIMITS[self.ptype]
            if not lo - 1 < v < hi + 1:
                return None, f"{self.name}: {v:g} does not fit {self.ptype.name}"
            v = float(int(v + math.copysign(0.01, v)))
        else:
            # what goes over the wire is a float32
            v = _to_float32(v)
            if not math.isfinite(v):
                return None, f"{self.name}: {value:g} does not fit REAL32"
        if self.values and int(v) not in {val for val, _ in self.values}:
            allowed = ", ".join(f"{val}:{label}" for val, label in self.values)
            return None, f"{self.name}={v:g} not supported ({allowed})"
        if self.safe_min is not None and v < self.safe_min:
            return self._clamped(v, self.safe_min, "minimum")
        if self.safe_max is not None and v > self.safe_max:
            return self._clamped(v, self.safe_max, "maximum")
        return v, ""

    def _clamped(self, requested: float, limit: float, which: str) -> tuple[float, str]:
        v = float(limit) if self.is_integer else _to_float32(limit)
        return v, f"{self.name} {requested:g} clamped to {v:g} (safe {which})"


def _to_float32(v: float) -> float:
    try:
        return struct.unpack("<f", struct.pack("<f", v))[0]
    except OverflowError:
        return math.copysign(math.inf, v)


class SetResult(NamedTuple):
    """Outcome of :meth:`ParameterStore.set`: the value now stored and why a set was refused
    (``ok`` False) or clamped (``ok`` True with a reason)."""

    ok: bool
    value: float
    reason: str = ""


def _spec(name: str, ptype: ParamType, default: float, lo: float, hi: float, units: str,
          description: str, values: tuple[tuple[int, str], ...] = (), *,
          safe: tuple[float | None, float | None] = (None, None)) -> ParamSpec:
    return ParamSpec(name, ptype, default, lo, hi, units, description, values, safe[0], safe[1])


_I8, _I16, _I32, _F = ParamType.INT8, ParamType.INT16, ParamType.INT32, ParamType.REAL32

# ArduCopter 4.5 names, units, defaults and ranges (see the module docstring for sources).
DEFAULT_PARAM_SPECS: tuple[ParamSpec, ...] = (
    _spec("ANGLE_MAX", _I16, 3000, 1000, 8000, "cdeg", "Maximum lean angle in all flight modes", safe=(1000, 8000)),
    _spec("ARMING_CHECK", _I32, 1, 0, 2 ** 31 - 1, "",
          "Pre-arm checks bitmask: 0 skips all checks, 1 runs all"),
    _spec("BATT_CAPACITY", _I32, 3300, 0, 1_000_000, "mAh", "Battery capacity", safe=(0, None)),
    _spec("BATT_MONITOR", _I8, 4, 0, 4, "", "Battery monitoring reported to the GCS",
          ((0, "Disabled"), (3, "Analog Voltage Only"), (4, "Analog Voltage and Current"))),
    _spec("DISARM_DELAY", _I8, 10, 0, 127, "s",
          "Delay before automatic disarm after landing; 0 disables auto disarm", safe=(0, None)),
    _spec("EK3_DRAG_BCOEF_X", _F, 0.0, 0.0, 1000.0, "kg/m/m",
          "Ballistic coefficient (mass / (Cd A)) for drag along body X; drag fusion (wind estimation "
          "and bounded dead reckoning) is on while it, EK3_DRAG_BCOEF_Y or EK3_DRAG_MCOEF is > 0",
          safe=(0.0, None)),
    _spec("EK3_DRAG_BCOEF_Y", _F, 0.0, 0.0, 1000.0, "kg/m/m",
          "Ballistic coefficient (mass / (Cd A)) for drag along body Y", safe=(0.0, None)),
    _spec("EK3_DRAG_MCOEF", _F, 0.0, 0.0, 1.0, "1/s",
          "Momentum coefficient for propeller drag: rotor drag acceleration per m/s of air velocity",
          safe=(0.0, None)),
    _spec("EK3_DRAG_M_NSE", _F, 0.5, 0.1, 2.0, "m/s/s",
          "Observation noise of the drag acceleration", safe=(0.1, None)),
    _spec("EK3_FLOW_I_GATE", _I16, 300, 100, 1000, "",
          "Optical flow innovation gate: a flow measurement more than EK3_FLOW_I_GATE / 100 standard "
          "deviations off the prediction is rejected", safe=(100, None)),
    _spec("EK3_POS_I_GATE", _I16, 500, 100, 1000, "",
          "Horizontal position innovation gate (GPS and external navigation, vision fixes): a fix "
          "more than EK3_POS_I_GATE / 100 standard deviations off the prediction is rejected",
          safe=(100, None)),
    _spec("EK3_FLOW_M_NSE", _F, 0.25, 0.05, 1.0, "rad/s",
          "Optical flow measurement noise the EKF assumes (sensor noise, timing and scale errors)",
          safe=(0.05, None)),
    _spec("EK3_MAX_FLOW", _F, 2.5, 1.0, 4.0, "rad/s",
          "Maximum optical flow rate the EKF uses; faster flow (low over the ground) is ignored"),
    _spec("EK3_ACC_P_NSE", _F, 0.2, 0.01, 1.0, "m/s/s",
          "Accelerometer noise the EKF assumes on each 10 ms sample: the velocity's process noise; "
          "raise it for a vibrating airframe (ArduPilot's default is 0.35; scenenav's 0.2 is what "
          "this filter used before the parameter, kept so that published flights reproduce)",
          safe=(0.01, None)),
    _spec("EK3_GBIAS_P_NSE", _F, 1.0e-3, 1.0e-5, 1.0e-3, "rad/s/s",
          "Rate gyro bias stability: the EKF's gyro-bias process noise (lower: the bias learnt at "
          "rest is kept longer, e.g. for dead-reckoned climbs and landings)"),
    _spec("EK3_YAW_M_NSE", _F, 0.03, 0.01, 1.0, "rad",
          "Yaw measurement noise of the compass heading the EKF fuses (ArduPilot's default 0.5 rad "
          "is for its yaw-only fusion; this EKF fuses the compass as a heading, default 0.03)",
          safe=(0.01, None)),
    _spec("EK3_WIND_P_NSE", _F, 0.2, 0.01, 2.0, "m/s/s",
          "Wind velocity process noise: how fast the wind estimate of drag fusion may change",
          safe=(0.01, None)),
    _spec("EK3_SRC1_POSXY", _I8, 3, 0, 6, "", "EKF horizontal position source",
          ((0, "None"), (3, "GPS"), (6, "ExternalNav"))),
    _spec("EK3_SRC1_POSZ", _I8, 1, 0, 6, "", "EKF vertical position source",
          ((0, "None"), (1, "Baro"), (3, "GPS"), (6, "ExternalNav"))),
    _spec("EK3_SRC1_VELXY", _I8, 3, 0, 6, "", "EKF horizontal velocity source (5: the optical flow "
          "sensor's velocity is fused, FLOW_TYPE > 0)",
          ((0, "None"), (3, "GPS"), (5, "OpticalFlow"), (6, "ExternalNav"))),
    _spec("EK3_SRC1_VELZ", _I8, 3, 0, 6, "", "EKF vertical velocity source",
          ((0, "None"), (3, "GPS"), (6, "ExternalNav"))),
    _spec("EK3_SRC1_YAW", _I8, 1, 0, 6, "", "EKF yaw source",
          ((0, "None"), (1, "Compass"), (6, "ExternalNav"))),
    _spec("FLOW_TYPE", _I8, 0, 0, 10, "", "Optical flow sensor type (the simulator's flow module, "
          "sensors/flow, is type 10)", ((0, "None"), (10, "SITL"))),
    _spec("FRAME_CLASS", _I8, 1, 1, 1, "", "Frame class (only Quad is implemented)",
          ((1, "Quad"),)),
    _spec("FRAME_TYPE", _I8, 1, 1, 1, "", "Frame type (only X is implemented)", ((1, "X"),)),
    _spec("FS_EKF_ACTION", _I8, 1, 0, 3, "", "EKF failsafe action",
          ((0, "Report only"), (1, "Land if the mode needs position"),
           (2, "AltHold if the mode needs position"), (3, "Land from all modes"))),
    _spec("FS_EKF_THRESH", _F, 0.8, 0.0, 1.0, "",
          "EKF failsafe variance threshold (0 disables the EKF failsafe)"),
    _spec("FS_GCS_ENABLE", _I8, 0, 0, 5, "",
          "GCS failsafe action after FS_GCS_TIMEOUT without a SYSID_MYGCS heartbeat",
          ((0, "Disabled"), (1, "RTL"), (3, "SmartRTL or RTL"), (4, "SmartRTL or Land"),
           (5, "Land"))),
    _spec("FS_GCS_TIMEOUT", _F, 5.0, 2.0, 120.0, "s", "GCS failsafe timeout", safe=(0.1, None)),
    _spec("GUID_TIMEOUT", _F, 3.0, 0.1, 5.0, "s",
          "Guided mode: stop if no velocity/acceleration setpoint arrives for this long", safe=(0.1, None)),
    _spec("LAND_SPEED", _I16, 50, 30, 200, "cm/s", "Descent speed for the final stage of landing", safe=(30, None)),
    _spec("LAND_SPEED_HIGH", _I16, 0, 0, 500, "cm/s",
          "Descent speed for the first stage of landing; 0 = WPNAV_SPEED_DN", safe=(0, None)),
    _spec("PILOT_SPEED_DN", _I16, 0, 0, 500, "cm/s",
          "Maximum pilot descent speed; 0 = PILOT_SPEED_UP", safe=(0, None)),
    _spec("PILOT_SPEED_UP", _I16, 250, 50, 500, "cm/s", "Maximum pilot climb speed", safe=(50, None)),
    # The range finder's limits. ArduPilot's defaults (20 / 700 cm) suit an unknown sensor; these suit
    # the simulator's default flow module's (Broadcom AFBR-S50LV85D, 0.1-30 m: sitl.config.FlowConfig).
    # A reading outside them is out of range: not fused, and DISTANCE_SENSOR reports them as limits.
    _spec("RNGFND1_MAX_CM", _I16, 3000, 0, 32767, "cm",
          "Range finder 1 maximum distance: farther readings are out of range (not fused)", safe=(0, None)),
    _spec("RNGFND1_MIN_CM", _I16, 10, 0, 32767, "cm",
          "Range finder 1 minimum distance: nearer readings are out of range (not fused)", safe=(0, None)),
    _spec("RTL_ALT", _I32, 1500, 30, 300000, "cm",
          "Minimum altitude above home for the return leg of RTL", safe=(30, 300000)),
    _spec("RTL_ALT_FINAL", _I16, 0, 0, 1000, "cm",
          "Final RTL altitude above home; 0 = land", safe=(0, None)),
    _spec("RTL_LOIT_TIME", _I32, 5000, 0, 60000, "ms", "Loiter time above home before descending", safe=(0, None)),
    _spec("RTL_SPEED", _I16, 0, 0, 2000, "cm/s", "Horizontal RTL speed; 0 = WPNAV_SPEED", safe=(0, None)),
    _spec("SYSID_MYGCS", _I16, 255, 1, 255, "",
          "System id of the GCS whose heartbeats keep the GCS failsafe quiet", safe=(1, 255)),
    _spec("SYSID_THISMAV", _I16, 1, 1, 255, "", "MAVLink system id of this vehicle (at start-up)", safe=(1, 255)),
    _spec("VISO_TYPE", _I8, 0, 0, 1, "",
          "Visual odometry: 1 accepts VISION_POSITION_ESTIMATE / ODOMETRY over MAVLink",
          ((0, "None"), (1, "MAVLink"))),
    _spec("WP_YAW_BEHAVIOR", _I8, 2, 0, 3, "", "Yaw during missions and RTL",
          ((0, "Never change yaw"), (1, "Face next waypoint"),
           (2, "Face next waypoint except RTL"), (3, "Face along GPS course"))),
    _spec("WPNAV_ACCEL", _F, 250.0, 50.0, 500.0, "cm/s/s", "Horizontal waypoint acceleration", safe=(50.0, None)),
    _spec("WPNAV_RADIUS", _F, 200.0, 5.0, 1000.0, "cm", "Waypoint acceptance radius", safe=(5.0, None)),
    _spec("WPNAV_SPEED", _F, 1000.0, 10.0, 2000.0, "cm/s", "Horizontal waypoint speed", safe=(20.0, None)),
    _spec("WPNAV_SPEED_DN", _F, 150.0, 10.0, 500.0, "cm/s", "Waypoint descent speed", safe=(10.0, None)),
    _spec("WPNAV_SPEED_UP", _F, 250.0, 10.0, 1000.0, "cm/s", "Waypoint climb speed", safe=(10.0, None)),
)

ParamObserver = Callable[[str, float], None]


def load_param_file(path: Path) -> dict[str, object]:
    """A JSON parameter file ``{"NAME": value, ...}`` (values checked when applied)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read parameter file: {exc}") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: line {exc.lineno}: not valid JSON "
                        f"(expected {{\"NAME\": value, ...}})") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object {{\"NAME\": value, ...}}")
    return data


class ParameterStore:
    """Typed parameters in a fixed order (``param_index`` = position in ``specs``).

    ``path`` (optional) is a JSON file ``{"NAME": value, ...}`` of every value, read at
    construction and rewritten atomically after every change. ``defaults`` overrides spec defaults
    (e.g. from a scenario) before the files are applied.

    ``persist_path`` (optional) is the parameter file kept from one start to the next, as
    ArduPilot SITL keeps ``eeprom.bin``: it holds only the parameters set through :meth:`set`
    (ArduPilot saves a parameter when it is set, not its defaults), is read at construction over
    the defaults (so a later start with other defaults, e.g. without GPS, keeps them unless they
    were set) and rewritten atomically after every set.
    """

    def __init__(self, specs: Iterable[ParamSpec] = DEFAULT_PARAM_SPECS,
                 path: str | Path | None = None,
                 defaults: Mapping[str, float] | None = None,
                 persist_path: str | Path | None = None) -> None:
        self._specs: tuple[ParamSpec, ...] = tuple(specs)
        self._index: dict[str, int] = {}
        for i, spec in enumerate(self._specs):
            if spec.name in self._index:
                raise ValueError(f"duplicate parameter {spec.name}")
            self._index[spec.name] = i
        self._values: list[float] = [float(s.default) for s in self._specs]
        self._observers: list[ParamObserver] = []
        self._generation = 0
        self._path = Path(path) if path is not None else None
        for name, value in (defaults or {}).items():
            self._apply_initial(name, value, "defaults")
        self._defaults: tuple[float, ...] = tuple(self._values)
        if self._path is not None and self._path.exists():
            self._load(self._path)
        self._persist_path = Path(persist_path) if persist_path is not None else None
        self._persisted: set[str] = set()
        if self._persist_path is not None and self._persist_path.exists():
            for name in self._load(self._persist_path):
                self._persisted.add(name)

    # ----------------------------------------------------------------- queries
    @property
    def count(self) -> int:
        return len(self._specs)

    def names(self) -> list[str]:
        return [s.name for s in self._specs]

    def specs(self) -> tuple[ParamSpec, ...]:
        return self._specs

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def index_of(self, name: str) -> int | None:
        return self._index.get(name)

    def spec(self, name: str) -> ParamSpec:
        return self._specs[self._index[name]]

    @property
    def generation(self) -> int:
        """Counts the changes made through :meth:`set`: a cache of values derived from parameters
        is valid while this is unchanged."""
        return self._generation

    def get(self, name: str) -> float:
        """The value (an integral float for integer types). KeyError for unknown names."""
        return self._values[self._index[name]]

    def get_int(self, name: str) -> int:
        return int(self.get(name))

    def by_index(self, index: int) -> tuple[ParamSpec, float]:
        return self._specs[index], self._values[index]

    def default_at(self, index: int) -> float:
        """The start-up default of a parameter: the spec's, or the ``defaults`` given."""
        return self._defaults[index]

    def as_dict(self) -> dict[str, float]:
        return {s.name: v for s, v in zip(self._specs, self._values, strict=False)}

    # ----------------------------------------------------------------- changes
    def add_observer(self, observer: ParamObserver) -> None:
        """Call ``observer(name, value)`` after every change (not for refused or no-op sets)."""
        self._observers.append(observer)

    def remove_observer(self, observer: ParamObserver) -> None:
        if observer in self._observers:
            self._observers.remove(observer)

    def set(self, name: str, value: float) -> SetResult:
        """Validate and store; on refusal the old value is kept and returned with a reason."""
        i = self._index.get(name)
        if i is None:
            return SetResult(False, math.nan, f"{name}: no such parameter")
        new, reason = self._specs[i].coerce(value)
        if new is None:
            logger.info("parameter set refused: %s", reason)
            return SetResult(False, self._values[i], reason)
        if reason:
            logger.info("parameter set clamped: %s", reason)
        if new == self._values[i]:
            if name not in self._persisted and self._persist_path is not None:
                self._persisted.add(name)
                self._save_persisted()
            return SetResult(True, new, reason)
        self._values[i] = new
        self._generation += 1
        logger.info("parameter %s = %g", name, new)
        self._persisted.add(name)
        self._save()
        self._save_persisted()
        for observer in list(self._observers):
            observer(name, new)
        return SetResult(True, new, reason)

    # ----------------------------------------------------------------- persistence
    def _apply_initial(self, name: str, value: object, source: str) -> bool:
        i = self._index.get(name)
        if i is None:
            logger.warning("%s: unknown parameter %s ignored", source, name)
            return False
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UserError(f"{source}: {name} = {value!r}: expected a number")
        new, reason = self._specs[i].coerce(value)
        if new is None:
            raise UserError(f"{source}: {reason}")
        if reason:
            logger.warning("%s: %s", source, reason)
        self._values[i] = new
        return True

    def _load(self, path: Path) -> list[str]:
        """Apply a parameter file; the names it set (unknown ones are logged and skipped)."""
        applied = []
        for name, value in load_param_file(path).items():
            if self._apply_initial(str(name), value, str(path)):
                applied.append(str(name))
        return applied

    def save(self) -> None:
        """Write the files now (``path`` with every value, ``persist_path`` with the set ones)."""
        self._save()
        self._save_persisted()

    def erase_persisted(self) -> None:
        """PREFLIGHT_STORAGE erase (ArduPilot ``AP_Param::erase_all``): the kept values are dropped
        from the ``persist_path`` file, so the next start uses the defaults; the running values stay
        until then, as on ArduPilot before its reboot."""
        self._persisted.clear()
        self._save_persisted()

    @property
    def persisted_names(self) -> frozenset[str]:
        """The parameters that are in (or go to) the ``persist_path`` file."""
        return frozenset(self._persisted)

    def _save(self) -> None:
        if self._path is None:
            return
        _write_json(self._path, {s.name: (int(v) if s.is_integer else v)
                                 for s, v in zip(self._specs, self._values, strict=True)})

    def _save_persisted(self) -> None:
        if self._persist_path is None:
            return
        _write_json(self._persist_path, {
            s.name: (int(v) if s.is_integer else v)
            for s, v in zip(self._specs, self._values, strict=True) if s.name in self._persisted})


def _write_json(path: Path, data: dict[str, float]) -> None:
    """Atomically replace ``path`` (a crash leaves the old file or the new one, never half)."""
    tmp = ""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.name, dir=path.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1, sort_keys=True)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError:
        logger.exception("could not save parameters to %s", path)
        if tmp:
            try:
                os.unlink(tmp)
            except OSError:
                pass
