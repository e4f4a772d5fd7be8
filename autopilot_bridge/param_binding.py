"""Parameter binding (part of ``FlightCore``): the ArduCopter parameters mapped onto the algorithms'
configs (ANGLE_MAX, WPNAV_*, PILOT_*, LAND_*, RTL_*, WP_YAW_BEHAVIOR, EK3_SRC1_POSXY, EK3_GBIAS_P_NSE,
EK3_YAW_M_NSE, EK3_POS_I_GATE, EK3_DRAG_* and EK3_WIND_P_NSE, the airframe
model), applied again whenever the parameter store reports a change.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import dataclasses
import logging

from autopilot_bridge.airframe import AIRFRAME_PARAM_NAMES, Airframe
from autopilot_bridge.config import ControlConfig, GuidanceConfig, PositionSource, YawBehaviour
from autopilot_bridge.control import FlightController
from autopilot_bridge.flight_laws import Tracker
from autopilot_bridge.mixer import QuadXMixer
from autopilot_bridge.vehicle_interface import (
    MavSeverity,
    Outcome,
    SpeedType,
)
from scenenav.core.errors import UserError

logger = logging.getLogger(__name__)


#: ArduPilot adds (dt * EK3_GBIAS_P_NSE)^2 of delta-angle bias variance per EKF step of dt, a gyro-bias
#: random walk of density EK3_GBIAS_P_NSE * sqrt(dt); our filter steps at the 100 Hz control tick.
EKF_STEP_S = 0.01


def gyro_bias_noise_density(p_nse_rad_s2: float) -> float:
    """``EK3_GBIAS_P_NSE`` (rad/s/s) -> the filter's gyro-bias random walk (rad/s^2/sqrt(Hz)); the
    default 1e-3 gives ``EkfConfig``'s 1e-4."""
    return process_noise_density(p_nse_rad_s2)


def process_noise_density(p_nse: float) -> float:
    """An ArduPilot EKF3 ``*_P_NSE`` (per-step standard deviation dt * P_NSE of a random walk state's
    change) -> the continuous random-walk density P_NSE * sqrt(dt) at our 100 Hz filter step."""
    return float(p_nse) * EKF_STEP_S ** 0.5


def accel_noise_density(p_nse_m_s2: float) -> float:
    """``EK3_ACC_P_NSE`` (m/s/s) -> the filter's accelerometer white-noise density (m/s^2/sqrt(Hz)).
    ArduPilot EKF3 adds (dt * EK3_ACC_P_NSE)^2 of delta-velocity variance per step of dt: white noise
    of density P_NSE * sqrt(dt), as ``process_noise_density``; written as a division by 1 / sqrt(dt)
    (exactly 10) so that the default 0.2 gives ``EkfConfig``'s 0.02 to the last bit."""
    return float(p_nse_m_s2) / (1.0 / EKF_STEP_S) ** 0.5


def drag_model(params) -> dict[str, float]:
    """``NavFilter.set_drag_model`` arguments from EK3_DRAG_BCOEF_X/Y, EK3_DRAG_MCOEF, EK3_DRAG_M_NSE
    and EK3_WIND_P_NSE (ArduPilot ``AP_NavEKF3.cpp``)."""
    return {"ballistic_x_kg_m2": params.get("EK3_DRAG_BCOEF_X"),
            "ballistic_y_kg_m2": params.get("EK3_DRAG_BCOEF_Y"),
            "momentum_per_s": params.get("EK3_DRAG_MCOEF"),
            "noise_m_s2": params.get("EK3_DRAG_M_NSE"),
            "wind_noise_m_s2_per_rt_hz": process_noise_density(params.get("EK3_WIND_P_NSE"))}


def compass_bias_model(params) -> dict[str, float]:
    """``NavFilter.set_compass_bias_model`` arguments from SN_MAG_BIAS_SD and SN_MAG_BIAS_TURN."""
    return {"std_rad": params.get("SN_MAG_BIAS_SD"), "turn_std_rad": params.get("SN_MAG_BIAS_TURN")}


class ParamBindingMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def param_changed(self, name: str, value: float) -> None:
        # The store's observer (_on_param) has already applied it; nothing more to do here.
        logger.debug("param_changed %s = %g", name, value)

    def _on_param(self, name: str, value: float) -> None:
        """Parameter observer (the store calls it after every change, from any caller)."""
        try:
            self._apply_param(name, value)
        except (ValueError, ArithmeticError, UserError) as exc:
            logger.warning("parameter %s = %g not applied: %s", name, value, exc)

    def _apply_param(self, name: str, value: float) -> None:
        self._tel = None
        if name == "EK3_GBIAS_P_NSE":
            self.nav.set_gyro_bias_noise(gyro_bias_noise_density(value))
        if name == "SN_VIS_RST_MAX":
            self.nav.set_vision_reset_max(value)
        if name == "EK3_ACC_P_NSE":
            self.nav.set_accel_noise(accel_noise_density(value))
        if name == "EK3_YAW_M_NSE":
            self.nav.set_compass_noise(value)
        if name in ("SN_MAG_BIAS_SD", "SN_MAG_BIAS_TURN"):
            self.nav.set_compass_bias_model(**compass_bias_model(self.params))
        if name == "EK3_POS_I_GATE":
            self.nav.set_position_gate(value / 100.0)
        if name == "VISO_POS_M_NSE":
            self.nav.set_vision_noise_floor(value)
        if name.startswith("EK3_DRAG_") or name == "EK3_WIND_P_NSE":
            self.nav.set_drag_model(**drag_model(self.params))
        if name == f"EK3_SRC{self._source_set}_POSXY":
            self.nav.set_position_source(self._source_param())
            self._announce(MavSeverity.INFO, f"EKF3 IMU0 is using {self._source_name()}")
        if name in ("ANGLE_MAX", "PILOT_SPEED_UP", "PILOT_SPEED_DN", "WPNAV_SPEED_UP",
                    "WPNAV_SPEED_DN", "LAND_SPEED", "LAND_SPEED_HIGH"):
            self._rebuild_controller()
        if name in AIRFRAME_PARAM_NAMES:
            self.airframe = Airframe.from_params(self.params)
            self.mixer = QuadXMixer(self.airframe)
            self._rebuild_controller()
        if name.startswith(("WPNAV_", "RTL_", "LAND_", "WP_YAW", "PILOT_")):
            self._gcfg = self._guidance_config()
            if isinstance(self._law, Tracker):
                self._law.retune(self._gcfg)

    def _rebuild_controller(self) -> None:
        """A new controller for changed limits or a changed airframe model (integrators restart)."""
        landed = self.fc.landed
        self.fc = FlightController(self._control_config(), self.airframe)
        if self.nav.aligned:
            self.fc.reset(self.nav.state(), landed=landed)
        else:
            self.fc.set_landed(landed)

    def _source_param(self) -> PositionSource:
        try:
            return PositionSource(self.params.get_int(f"EK3_SRC{self._source_set}_POSXY"))
        except ValueError:
            return PositionSource.NONE

    def set_ekf_source_set(self, number: int) -> Outcome:
        """SET_EKF_SOURCE_SET: use EK3_SRC<number>_* (1..3) from now on (ArduPilot
        ``AP_NavEKF_Source::setPosVelYawSourceSet``)."""
        name = f"EK3_SRC{number}_POSXY"
        if name not in self.params:
            return self._refuse(f"EKF source set {number}: no {name}")
        self._source_set = number
        self._tel = None
        self.nav.set_position_source(self._source_param())
        self._announce(MavSeverity.INFO, f"EKF3 IMU0 is using {self._source_name()}")
        return Outcome(True)

    def _source_name(self) -> str:
        return {PositionSource.GPS: "GPS", PositionSource.EXTNAV: "external nav data"}.get(
            self.nav.position_source, "no position source")

    def _control_config(self) -> ControlConfig:
        p = self.params
        up = max(p.get("WPNAV_SPEED_UP"), p.get("PILOT_SPEED_UP")) / 100.0
        dn_pilot = p.get("PILOT_SPEED_DN") or p.get("PILOT_SPEED_UP")
        dn = max(p.get("WPNAV_SPEED_DN"), dn_pilot, p.get("LAND_SPEED"),
                 p.get("LAND_SPEED_HIGH")) / 100.0
        return dataclasses.replace(self._algo.control, max_lean_angle_deg=p.get("ANGLE_MAX") / 100.0,
                                   max_climb_m_s=up, max_descent_m_s=dn)

    def _guidance_config(self) -> GuidanceConfig:
        p = self.params
        yaw = YawBehaviour.NEVER_CHANGE if p.get_int("WP_YAW_BEHAVIOR") == 0 \
            else YawBehaviour.FACE_NEXT_WAYPOINT
        up = self._speed_up if self._speed_up is not None else p.get("WPNAV_SPEED_UP") / 100.0
        dn = self._speed_dn if self._speed_dn is not None else p.get("WPNAV_SPEED_DN") / 100.0
        return dataclasses.replace(
            self._algo.guidance,
            wp_speed_m_s=p.get("WPNAV_SPEED") / 100.0, wp_speed_up_m_s=up, wp_speed_down_m_s=dn,
            wp_accel_m_s2=p.get("WPNAV_ACCEL") / 100.0, wp_radius_m=p.get("WPNAV_RADIUS") / 100.0,
            yaw_behaviour=yaw, takeoff_speed_m_s=up, rtl_alt_m=p.get("RTL_ALT") / 100.0,
            rtl_loiter_s=p.get("RTL_LOIT_TIME") / 1000.0, land_speed_m_s=p.get("LAND_SPEED") / 100.0,
            rtl_climb_min_m=p.get("RTL_CLIMB_MIN") / 100.0, rtl_cone_slope=p.get("RTL_CONE_SLOPE"),
            land_speed_high_m_s=p.get("LAND_SPEED_HIGH") / 100.0)

    def _apply_speed(self, kind: SpeedType, speed_m_s: float) -> None:
        if kind in (SpeedType.AIRSPEED, SpeedType.GROUNDSPEED):
            self._speed_xy = speed_m_s
            if isinstance(self._law, Tracker):
                self._law.set_speed(speed_m_s)
        elif kind == SpeedType.CLIMB_SPEED:
            self._speed_up = speed_m_s
        else:
            self._speed_dn = speed_m_s
        self._gcfg = self._guidance_config()
        if isinstance(self._law, Tracker):
            self._law.retune(self._gcfg)
        self._bus_text(MavSeverity.INFO, f"speed {kind.name.lower()} {speed_m_s:.1f} m/s")

    def _speed_limit(self, kind: SpeedType, speed_m_s: float) -> float:
        """A DO_CHANGE_SPEED speed capped at the range of the parameter it overrides (a mission item
        may carry any finite value)."""
        name = {SpeedType.CLIMB_SPEED: "WPNAV_SPEED_UP",
                SpeedType.DESCENT_SPEED: "WPNAV_SPEED_DN"}.get(kind, "WPNAV_SPEED")
        return min(speed_m_s, self.params.spec(name).max_value / 100.0)
