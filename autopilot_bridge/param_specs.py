"""Every parameter the autopilot serves: ArduCopter's (``params.DEFAULT_PARAM_SPECS``), the scenenav
vision-failsafe parameters, the airframe model (``airframe.AIRFRAME_PARAM_SPECS``) and the ones QGC's
setup pages read that change nothing here (``gcs_param_specs.GCS_PARAM_SPECS``), in the order of
their MAVLink ``param_index``."""

from __future__ import annotations

from autopilot_bridge.airframe import AIRFRAME_PARAM_SPECS
from autopilot_bridge.gcs_param_specs import GCS_PARAM_SPECS
from autopilot_bridge.mode_param_specs import MODE_PARAM_SPECS
from autopilot_bridge.params import DEFAULT_PARAM_SPECS, ParamSpec, ParamType

# scenenav parameters of the vision failsafe and of vision fusion.
SN_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("SN_VIS_TIMEOUT", ParamType.REAL32, 5.0, 0.0, 120.0, "s",
              "Vision failsafe: hold position after this long without a usable fix in "
              "GPS-denied flight (EK3_SRC1_POSXY 6); 0 disables", safe_min=0.0),
    ParamSpec("SN_VIS_FS_LAND", ParamType.REAL32, 10.0, 0.0, 600.0, "s",
              "Vision failsafe: land after holding this long without a fix", safe_min=0.0),
    ParamSpec("SN_VIS_MIN_ALT", ParamType.REAL32, 50.0, 0.0, 1000.0, "m",
              "Vision fixes are used (and expected) only this high above home", safe_min=0.0),
    ParamSpec("SN_VIS_RST_MAX", ParamType.REAL32, 0.0, 0.0, 10000.0, "m",
              "Largest jump of an EKF position reset onto vision fixes that were rejected for the "
              "reset timeout; a larger one is refused (a consistent false lock far off) and the "
              "vision failsafe decides; 0 = no limit (ArduPilot's behaviour)", safe_min=0.0),
    ParamSpec("SN_VIS_DR_MAX", ParamType.REAL32, 0.0, 0.0, 1000.0, "m",
              "Vision failsafe: after SN_VIS_TIMEOUT without a fix, fly on dead reckoning while "
              "the EKF's horizontal 1-sigma position uncertainty stays below this, then hold; "
              "0 = hold at SN_VIS_TIMEOUT", safe_min=0.0),
    ParamSpec("SN_VIS_MAX_SD", ParamType.REAL32, 0.0, 0.0, 10000.0, "m",
              "Vision fixes whose published 1-sigma (the larger axis of their covariance) exceeds "
              "this are fused at most once every 5 s (the others still count as fixes for the "
              "vision failsafe): an ambiguous match is published as wide as its search area, and "
              "fused at the frame rate its repeated error walks the estimate away; 0 = fuse every "
              "fix", safe_min=0.0),
    ParamSpec("SN_VIS_YAW_HOLD", ParamType.REAL32, 1.0, 0.0, 600.0, "s",
              "With EK3_SRCn_YAW 6 (ExternalNav): after a vision fix's heading was fused the "
              "compass stays unfused this long, so that the gyro carries the heading between the "
              "fixes' headings and the compass's bias does not pull it back in the gaps", safe_min=0.0),
    ParamSpec("SN_VIS_TILT", ParamType.INT8, 0, 0, 1, "",
              "1: the vision fixes come from a camera fixed to the body whose images the perception "
              "node aligned with this EKF's roll and pitch, so a fix's error holds the EKF's tilt "
              "error times the height; the EKF fuses the fix with that dependence and corrects its "
              "tilt with it. 0: a fix is of the position alone"),
    ParamSpec("SN_VIS_WIDE_SD", ParamType.REAL32, 0.0, 0.0, 1000.0, "m",
              "A vision fix wider than SN_VIS_MAX_SD that lies where the estimate is (within 3 "
              "combined sigmas of the EKF's uncertainty and this) is fused with this 1-sigma at "
              "every frame: an ambiguous match that agrees with the estimate is taken as the true "
              "peak, whose error is that of a tracked one; 0 = off", safe_min=0.0),
    ParamSpec("SN_CAM_FLOW", ParamType.INT8, 0, 0, 1, "",
              "1: fuse the followed perception node's camera flow (VisionFix flow_flu_rad_s, "
              "perception.camera_flow) as optical flow: its body rotation removed with this "
              "autopilot's gyro over the frame interval, over the range finder's recent mean range "
              "(FLOW_TYPE > 0) or else height above home / cos(tilt); in the air above SN_VIS_MIN_ALT, "
              "gated at EK3_FLOW_I_GATE. 0: ignored"),
    ParamSpec("SN_MAG_BIAS_SD", ParamType.REAL32, 0.0, 0.0, 0.5, "rad",
              "Prior 1-sigma (and cap) of the compass heading's bias, a state of the EKF: a compass "
              "whose residual hard- and soft-iron errors make it a few degrees off at each heading is "
              "then corrected by the position fixes and the body-frame velocity (drag, flow) instead "
              "of being taken for the heading; 0 = no bias state (the heading fused as white noise)",
              safe_min=0.0),
    ParamSpec("SN_MAG_BIAS_TURN", ParamType.REAL32, 0.07, 0.0, 0.5, "rad",
              "How much the compass heading's bias may change per radian the vehicle turns (1-sigma "
              "over one radian; the variance grows with the angle turned): the deviation depends on "
              "the heading (SN_MAG_BIAS_SD > 0)", safe_min=0.0),
    ParamSpec("SN_CAM_FLOW_NSE", ParamType.REAL32, 0.01, 0.001, 1.0, "rad/s",
              "Camera-flow measurement noise the EKF assumes (SN_CAM_FLOW 1) for a flow of quality 1, "
              "per axis and frame; a flow of quality q is fused with this / q^2"),
    ParamSpec("SN_CAM_FLOW_QMIN", ParamType.REAL32, 0.5, 0.0, 1.0, "",
              "Camera flows with a lower quality (the correlation peak's height against that of identical images) are not fused"),
)
# EKF source sets 2 and 3 (SET_EKF_SOURCE_SET, system_commands.py): ArduPilot's defaults are 0 (None).
_SRC_VALUES = {
    "POSXY": ((0, "None"), (3, "GPS"), (6, "ExternalNav")),
    "POSZ": ((0, "None"), (1, "Baro"), (3, "GPS"), (6, "ExternalNav")),
    "VELXY": ((0, "None"), (3, "GPS"), (5, "OpticalFlow"), (6, "ExternalNav")),
    "VELZ": ((0, "None"), (3, "GPS"), (6, "ExternalNav")),
    "YAW": ((0, "None"), (1, "Compass"), (6, "ExternalNav")),
}
EKF_SOURCE_SET_SPECS: tuple[ParamSpec, ...] = tuple(
    ParamSpec(f"EK3_SRC{n}_{kind}", ParamType.INT8, 0, 0, 6, "",
              f"EKF source set {n}: {kind} source (used after SET_EKF_SOURCE_SET {n}; as set 1, "
              "POSXY, POSZ and YAW change what this EKF fuses)", values)
    for n in (2, 3) for kind, values in _SRC_VALUES.items())
# External vision over MAVLink (external_vision.py); names, units and defaults ArduPilot 4.5's.
VISO_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("VISO_DELAY_MS", ParamType.INT16, 10, 0, 250, "ms",
              "Visual odometry sensor delay: fixes are fused this much before their arrival", safe_min=0),
    ParamSpec("VISO_POS_X", ParamType.REAL32, 0.0, -5.0, 5.0, "m", "Visual odometry sensor position, forward"),
    ParamSpec("VISO_POS_Y", ParamType.REAL32, 0.0, -5.0, 5.0, "m", "Visual odometry sensor position, right"),
    ParamSpec("VISO_POS_Z", ParamType.REAL32, 0.0, -5.0, 5.0, "m", "Visual odometry sensor position, down"),
    ParamSpec("VISO_POS_M_NSE", ParamType.REAL32, 0.2, 0.0, 5.0, "m",
              "Visual odometry position noise: floor of the covariance-derived error (MAVLink vision "
              "messages; bus fixes too, above the EKF's own 0.3 m)", safe_min=0.0),
    ParamSpec("VISO_QUAL_MIN", ParamType.INT8, 0, -1, 100, "%",
              "Visual odometry minimum quality: ODOMETRY below it is ignored"),
    ParamSpec("VISO_YAW_M_NSE", ParamType.REAL32, 0.2, 0.05, 1.0, "rad",
              "Visual odometry yaw noise: floor of the covariance-derived yaw error (EK3_SRCn_YAW 6)",
              safe_min=0.0),
)
PARAM_SPECS: tuple[ParamSpec, ...] = (DEFAULT_PARAM_SPECS + SN_PARAM_SPECS + AIRFRAME_PARAM_SPECS
                                      + GCS_PARAM_SPECS + MODE_PARAM_SPECS + EKF_SOURCE_SET_SPECS
                                      + VISO_PARAM_SPECS)
PARAM_NAMES = frozenset(spec.name for spec in PARAM_SPECS)
