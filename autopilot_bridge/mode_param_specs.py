"""Parameters of the modes this package adds beyond the first seven: CIRCLE (``AC_Circle``),
SMART_RTL (``AP_SmartRTL``), RTL's climb (``ArduCopter/mode_rtl.cpp``) and pilot input
(``ArduCopter/Parameters.cpp``, ``RC_Channels``). Names, units, defaults and ranges are
ArduCopter 4.5's.

Pure module.
"""

from __future__ import annotations

from autopilot_bridge.params import ParamSpec, ParamType

_I8, _I16, _F = ParamType.INT8, ParamType.INT16, ParamType.REAL32

MODE_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("CIRCLE_RADIUS", _F, 1000.0, 0.0, 200000.0, "cm",
              "CIRCLE mode radius; 0 turns on the spot (panorama)", safe_min=0.0),
    ParamSpec("CIRCLE_RATE", _F, 20.0, -90.0, 90.0, "deg/s",
              "CIRCLE mode turn rate, positive clockwise"),
    ParamSpec("SRTL_ACCURACY", _F, 2.0, 0.0, 10.0, "m",
              "SmartRTL: the path is recorded and simplified to this accuracy", safe_min=0.0),
    ParamSpec("SRTL_POINTS", ParamType.INT16, 300, 0, 500, "",
              "SmartRTL: the most path points kept; 0 disables SmartRTL", safe_min=0.0),
    ParamSpec("RTL_CLIMB_MIN", _I16, 0, 0, 3000, "cm",
              "RTL climbs at least this much before returning", safe_min=0.0),
    ParamSpec("RTL_CONE_SLOPE", _F, 3.0, 0.0, 10.0, "",
              "RTL cone above home limiting the climb near home; below 0.5 disables it",
              safe_min=0.0),
    ParamSpec("RC_OVERRIDE_TIME", _F, 3.0, -1.0, 120.0, "s",
              "RC overrides (RC_CHANNELS_OVERRIDE, MANUAL_CONTROL) last this long; -1 for ever, "
              "0 ignores them"),
    ParamSpec("PILOT_Y_RATE", _F, 202.5, 1.0, 500.0, "deg/s", "Pilot yaw rate at full stick",
              safe_min=1.0),
    ParamSpec("THR_DZ", _I16, 100, 0, 300, "", "Throttle dead zone around mid stick (of 1000) "
              "in ALT_HOLD, LOITER and POSHOLD", safe_min=0.0),
    ParamSpec("LOIT_SPEED", _F, 1250.0, 20.0, 3500.0, "cm/s",
              "LOITER / POSHOLD horizontal speed at full stick", safe_min=20.0),
)
