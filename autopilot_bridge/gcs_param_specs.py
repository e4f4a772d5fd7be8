"""The parameters QGroundControl's APM setup pages read (Radio, Flight Modes, Sensors, Power,
Safety, Airframe), so that QGC finds none missing and shows the setup complete. None of them
changes what this autopilot does (docs/mavlink.md, "changes nothing"): there is no compass or
accelerometer calibration, no analog battery monitor and no fence here; except the RC channel
mapping and calibration and FS_THR_ENABLE, which the pilot's RC overrides use
(``PILOT_INPUT_PARAM_NAMES``, ``autopilot_bridge.pilot``). They are stored, served and persisted like every other parameter.

Pure module. Names, types and defaults are ArduCopter 4.5's (``RC_Channel.cpp``,
``RC_Channels``/``RCMapper``, ``ArduCopter/Parameters.cpp``, ``AP_Compass.cpp``,
``AP_InertialSensor.cpp``, ``AP_BattMonitor_Params.cpp``, ``AC_Fence.cpp``), with the values
ArduPilot's own SITL loads for the same reason (``Tools/autotest/default_params/copter.parm``):
RC1..8 calibrated to 1000..2000, INS_ACCOFFS 0.001 / INS_ACCSCAL 1.001 ("we need small INS_ACC
offsets so INS is recognised as being calibrated"), compass offsets 5, 13, -18, the SITL flight
modes (CIRCLE, LAND, RTL, AUTO, LOITER, STABILIZE), RC7_OPTION 7, FENCE_RADIUS 150. The compass
device ids are those of ArduPilot SITL's simulated compasses. The checks QGC makes on them
(``APMRadioComponent::setupComplete``: the RCMAP channels' MIN/MAX/TRIM not all at 1100/1900/1500;
``APMSensorsComponent``: offsets non-zero for every used compass, INS_ACCOFFS not all zero;
``APMAirframeComponent``: FRAME_CLASS > 0) are in tests/mavlink/test_mavlink_gcs.py.

Enabling what does not exist is refused rather than stored (battery failsafe action 5 =
terminate): a ground station must not show a protection the vehicle does not have.
BATT_FS_LOW_ACT / BATT_FS_CRT_ACT with the BATT_LOW_* / BATT_CRT_* thresholds drive the battery
failsafe (``failsafe_checks``); FENCE_ENABLE, FENCE_TYPE, FENCE_ACTION, FENCE_ALT_MAX/MIN,
FENCE_RADIUS, FENCE_MARGIN, RALLY_LIMIT_KM and RALLY_INCL_HOME the geofence and rally points
(``geofence``).
"""

from __future__ import annotations

from autopilot_bridge.params import ParamSpec, ParamType

_I8, _I16, _I32, _F = ParamType.INT8, ParamType.INT16, ParamType.INT32, ParamType.REAL32
_NOTHING = " (changes nothing here)"
RC_CHANNELS = 16
SITL_CALIBRATED_RC = 8                 # copter.parm calibrates RC1..RC8 to 1000..2000
RC_DEAD_ZONES = {1: 20, 2: 20, 3: 30, 4: 20}   # Copter: roll/pitch/yaw 20, throttle 30 (us)
SITL_FLIGHT_MODES = (7, 9, 6, 3, 5, 0)  # copter.parm FLTMODE1..6: CIRCLE LAND RTL AUTO LOITER STAB
SITL_COMPASS_OFFSETS = (5.0, 13.0, -18.0)  # copter.parm COMPASS_OFS*_X/Y/Z (mGauss)
SITL_COMPASS_DEV_IDS = (97539, 131874, 263178)  # ArduPilot SITL's three simulated compasses
FENCE_ACTIONS = ((0, "Report only"), (1, "RTL or Land"), (2, "Always Land"),
                 (3, "SmartRTL or RTL or Land"), (4, "Brake or Land"), (5, "SmartRTL or Land"))
# BATT_FS_LOW_ACT / BATT_FS_CRT_ACT values the battery failsafe implements (5, terminate, is not)
BATT_FS_ACTIONS = ((0, "None"), (1, "Land"), (2, "RTL"), (3, "SmartRTL or RTL"),
                   (4, "SmartRTL or Land"), (6, "Auto DO_LAND_START or RTL"), (7, "Brake or Land"))


def _p(name: str, ptype: ParamType, default: float, lo: float, hi: float, units: str,
       description: str, values: tuple[tuple[int, str], ...] = ()) -> ParamSpec:
    return ParamSpec(name, ptype, default, lo, hi, units, description + _NOTHING, values)


def _rc_specs() -> list[ParamSpec]:
    # RCMAP_* and RCn_MIN/TRIM/MAX/REVERSED/DZ scale the pilot's RC overrides (autopilot_bridge.pilot)
    out = [ParamSpec(f"RCMAP_{axis}", _I8, ch, 1, RC_CHANNELS, "",
                     f"RC input channel for {axis.lower()}")
           for axis, ch in (("ROLL", 1), ("PITCH", 2), ("THROTTLE", 3), ("YAW", 4))]
    for n in range(1, RC_CHANNELS + 1):
        calibrated = n <= SITL_CALIBRATED_RC
        out += [
            ParamSpec(f"RC{n}_MIN", _I16, 1000 if calibrated else 1100, 800, 2200, "PWM",
                      f"RC channel {n} minimum"),
            ParamSpec(f"RC{n}_TRIM", _I16, 1500, 800, 2200, "PWM", f"RC channel {n} trim"),
            ParamSpec(f"RC{n}_MAX", _I16, 2000 if calibrated else 1900, 800, 2200, "PWM",
                      f"RC channel {n} maximum"),
            ParamSpec(f"RC{n}_REVERSED", _I8, 0, 0, 1, "", f"RC channel {n} reversed"),
            ParamSpec(f"RC{n}_DZ", _I16, RC_DEAD_ZONES.get(n, 0), 0, 200, "PWM",
                      f"RC channel {n} dead zone"),
            _p(f"RC{n}_OPTION", _I16, 7 if n == 7 else 0, 0, 2 ** 15 - 1, "",
               f"RC channel {n} auxiliary function"),
        ]
    return out


def _flight_mode_specs() -> list[ParamSpec]:
    out = [_p(f"FLTMODE{i}", _I8, mode, 0, 127, "", f"Flight mode for switch position {i}")
           for i, mode in enumerate(SITL_FLIGHT_MODES, start=1)]
    out += [_p("FLTMODE_CH", _I8, 5, 0, 16, "", "RC channel of the flight mode switch"),
            _p("SIMPLE", _I8, 0, 0, 63, "", "Simple mode bitmask of the switch positions"),
            _p("SUPER_SIMPLE", _I8, 0, 0, 63, "", "Super simple mode bitmask")]
    return out


def _sensor_specs() -> list[ParamSpec]:
    out = [_p("COMPASS_ENABLE", _I8, 1, 0, 1, "", "Compass enabled"),
           _p("COMPASS_AUTODEC", _I8, 1, 0, 1, "", "Declination from the GPS position"),
           _p("COMPASS_DEC", _F, 0.0, -3.142, 3.142, "rad", "Magnetic declination"),
           _p("COMPASS_ORIENT", _I8, 0, 0, 127, "", "Compass orientation"),
           _p("COMPASS_LEARN", _I8, 0, 0, 3, "", "Learn compass offsets in flight")]
    for i, dev_id in enumerate(SITL_COMPASS_DEV_IDS):
        suffix = "" if i == 0 else str(i + 1)
        out += [_p(f"COMPASS_USE{suffix}", _I8, 1, 0, 1, "", f"Use compass {i + 1}"),
                _p(f"COMPASS_DEV_ID{suffix}", _I32, dev_id, 0, 2 ** 31 - 1, "",
                   f"Compass {i + 1} device id")]
        out += [_p(f"COMPASS_OFS{suffix}_{axis}", _F, ofs, -400.0, 400.0, "mGauss",
                   f"Compass {i + 1} offset {axis}")
                for axis, ofs in zip("XYZ", SITL_COMPASS_OFFSETS, strict=True)]
    for i, (offs, scal) in enumerate(((0.001, 1.001), (0.001, 1.001), (0.0, 1.0))):
        tag = "ACC" if i == 0 else f"ACC{i + 1}"
        out += [_p(f"INS_{tag}OFFS_{axis}", _F, offs, -3.5, 3.5, "m/s/s",
                   f"Accelerometer {i + 1} offset {axis}") for axis in "XYZ"]
        out += [_p(f"INS_{tag}SCAL_{axis}", _F, scal, 0.8, 1.2, "",
                   f"Accelerometer {i + 1} scaling {axis}") for axis in "XYZ"]
    out += [_p("INS_GYRO_FILTER", _I16, 20, 0, 256, "Hz", "Gyro filter cutoff"),
            _p("INS_ACCEL_FILTER", _I16, 20, 0, 256, "Hz", "Accelerometer filter cutoff")]
    return out


def _power_specs() -> list[ParamSpec]:
    return [
        _p("BATT_VOLT_PIN", _I8, 13, -1, 127, "", "Battery voltage sensing pin (SITL board)"),
        _p("BATT_CURR_PIN", _I8, 12, -1, 127, "", "Battery current sensing pin (SITL board)"),
        _p("BATT_VOLT_MULT", _F, 10.1, 0.0, 100.0, "", "Voltage divider multiplier"),
        _p("BATT_AMP_PERVLT", _F, 17.0, 0.0, 1000.0, "A/V", "Amps per volt of the current sensor"),
        _p("BATT_AMP_OFFSET", _F, 0.0, -10.0, 10.0, "V", "Current sensor offset"),
        _p("BATT_ARM_VOLT", _F, 0.0, 0.0, 100.0, "V", "Minimum voltage to arm"),
        _p("BATT_ARM_MAH", _I32, 0, 0, 2 ** 31 - 1, "mAh", "Minimum capacity left to arm"),
        ParamSpec("BATT_LOW_VOLT", _F, 10.5, 0.0, 100.0, "V", "Low battery voltage"),
        ParamSpec("BATT_CRT_VOLT", _F, 0.0, 0.0, 100.0, "V", "Critical battery voltage"),
        ParamSpec("BATT_LOW_MAH", _F, 0.0, 0.0, 1e6, "mAh", "Low battery capacity left"),
        ParamSpec("BATT_CRT_MAH", _F, 0.0, 0.0, 1e6, "mAh", "Critical battery capacity left"),
        ParamSpec("BATT_LOW_TIMER", _I32, 10, 0, 120, "s", "Low battery for this long triggers"),
        _p("BATT_FS_VOLTSRC", _I8, 0, 0, 1, "", "Failsafe voltage source (0 raw, 1 sag compensated)"),
        # these two do change something: the battery failsafe (failsafe_checks.BatteryFailsafe)
        ParamSpec("BATT_FS_LOW_ACT", _I8, 0, 0, 7, "", "Low battery failsafe action",
                  BATT_FS_ACTIONS),
        ParamSpec("BATT_FS_CRT_ACT", _I8, 0, 0, 7, "", "Critical battery failsafe action",
                  BATT_FS_ACTIONS),
    ]


def _safety_specs() -> list[ParamSpec]:
    return [
        # the fence and rally parameters change something: geofence.py
        ParamSpec("FENCE_ENABLE", _I8, 0, 0, 1, "", "Geofence enable", ((0, "Disabled"), (1, "Enabled"))),
        ParamSpec("FENCE_TYPE", _I8, 7, 0, 15, "", "Fence types bitmask: 1 max altitude, 2 circle, "
                  "4 polygon, 8 min altitude"),
        ParamSpec("FENCE_ACTION", _I8, 1, 0, 5, "", "Action on a fence breach", FENCE_ACTIONS),
        ParamSpec("FENCE_ALT_MAX", _F, 100.0, 10.0, 1000.0, "m", "Fence maximum altitude"),
        ParamSpec("FENCE_ALT_MIN", _F, -10.0, -100.0, 100.0, "m", "Fence minimum altitude"),
        ParamSpec("FENCE_RADIUS", _F, 150.0, 30.0, 10000.0, "m", "Circular fence radius"),
        ParamSpec("FENCE_MARGIN", _F, 2.0, 1.0, 10.0, "m",
                  "Fence margin: guidance plans this far inside the fence"),
        _p("FENCE_TOTAL", _I8, 0, 0, 127, "", "Number of polygon fence points"),
        _p("FENCE_AUTOENABLE", _I8, 0, 0, 3, "", "Fence auto-enable"),
        ParamSpec("FS_THR_ENABLE", _I8, 1, 0, 7, "",
                  "Radio failsafe action when RC overrides stop: 0 off, 1 RTL, 2 continue AUTO, "
                  "3 Land, 4 SmartRTL or RTL, 5 SmartRTL or Land, 6 RTL, 7 Brake or Land"),
        _p("FS_THR_VALUE", _I16, 975, 910, 1100, "PWM", "Throttle failsafe PWM"),
        _p("FS_OPTIONS", _I32, 0, 0, 2 ** 31 - 1, "", "Failsafe options bitmask"),
        _p("FS_CRASH_CHECK", _I8, 1, 0, 1, "", "Crash check"),
        ParamSpec("RALLY_LIMIT_KM", _F, 0.3, 0.0, 10.0, "km",
                  "Rally points further than this are not used when home is closer (0 = no limit)"),
        ParamSpec("RALLY_INCL_HOME", _I8, 1, 0, 1, "", "RTL to home when it is nearer than the "
                  "nearest rally point", ((0, "Disabled"), (1, "Enabled"))),
        _p("RALLY_TOTAL", _I8, 0, 0, 127, "", "Rally point count (the RALLY upload sets the points)"),
    ]


GCS_PARAM_SPECS: tuple[ParamSpec, ...] = tuple(
    _rc_specs() + _flight_mode_specs() + _sensor_specs() + _power_specs() + _safety_specs())
GCS_PARAM_NAMES = frozenset(spec.name for spec in GCS_PARAM_SPECS)
# The exceptions to "changes nothing": they scale the pilot's RC overrides (autopilot_bridge.pilot).
PILOT_INPUT_PARAM_NAMES = frozenset(
    [f"RCMAP_{axis}" for axis in ("ROLL", "PITCH", "THROTTLE", "YAW")]
    + [f"RC{n}_{field}" for n in range(1, RC_CHANNELS + 1)
       for field in ("MIN", "TRIM", "MAX", "REVERSED", "DZ")]
    + ["FS_THR_ENABLE"])

# The ones among them that do change something (the battery failsafe, the geofence, rally points).
ACTIVE_GCS_PARAM_NAMES = frozenset({
    "BATT_FS_LOW_ACT", "BATT_FS_CRT_ACT", "BATT_LOW_VOLT", "BATT_CRT_VOLT", "BATT_LOW_MAH",
    "BATT_CRT_MAH", "BATT_LOW_TIMER", "FENCE_ENABLE", "FENCE_TYPE", "FENCE_ACTION",
    "FENCE_ALT_MAX", "FENCE_ALT_MIN", "FENCE_RADIUS", "FENCE_MARGIN", "RALLY_LIMIT_KM",
    "RALLY_INCL_HOME",
})
