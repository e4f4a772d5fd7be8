"""The telemetry model (part of ``FlightCore``): ``VehicleTelemetry`` (what the MAVLink server
encodes) from the EKF estimate, the last GPS fix, the battery monitor, home, the mission and the
health of the sensors; EKF_STATUS_REPORT flags and SYS_STATUS sensor bits.

Frames: NED metres from the EKF origin, body FRD, latitude/longitude through ``scenenav.core.frames``
around the world's geodetic origin, altitudes AMSL = ``origin_alt_amsl_m`` + ENU z.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import math
from enum import IntFlag

import numpy as np

from autopilot_bridge.config import PositionSource
from autopilot_bridge.failsafe_checks import BatteryLevel
from autopilot_bridge.flight_laws import LawKind
from autopilot_bridge.geo_frame import enu_to_ned
from autopilot_bridge.vehicle_interface import (
    DEFAULT_SENSORS,
    LandedState,
    SensorFlag,
    SystemStatus,
    VehicleTelemetry,
)
from scenenav.core.contracts import GpsFixType
from scenenav.core.frames import wrap_pi
from scenenav.core.rotations import aviation_euler_from_quat

# Motor outputs as PWM: ArduCopter's MOT_PWM_MIN / MOT_PWM_MAX defaults (1000 / 2000 us); disarmed
# motors get MOT_PWM_MIN, as ArduPilot SITL shows them.
MOT_PWM_MIN_US = 1000
MOT_PWM_MAX_US = 2000


def motor_pwm(commands, armed: bool) -> tuple[int, ...]:
    """SERVO_OUTPUT_RAW servo1..4 from the four motor commands (0..1)."""
    span = MOT_PWM_MAX_US - MOT_PWM_MIN_US
    return tuple(MOT_PWM_MIN_US + (int(round(span * min(max(float(c), 0.0), 1.0))) if armed else 0)
                 for c in commands)


class EkfStatusFlag(IntFlag):
    """MAVLink EKF_STATUS_FLAGS (EKF_STATUS_REPORT.flags)."""

    ATTITUDE = 1
    VELOCITY_HORIZ = 2
    VELOCITY_VERT = 4
    POS_HORIZ_REL = 8
    POS_HORIZ_ABS = 16
    POS_VERT_ABS = 32
    POS_VERT_AGL = 64
    CONST_POS_MODE = 128
    PRED_POS_HORIZ_REL = 256
    PRED_POS_HORIZ_ABS = 512
    UNINITIALIZED = 1024
    GPS_GLITCH = 32768


class TelemetryMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def telemetry(self) -> VehicleTelemetry:
        if self._tel is None:
            self._tel = self._build_telemetry()
        return self._tel

    def _ekf_variances(self) -> tuple[float, float, float]:
        """EKF_STATUS_REPORT's velocity, horizontal position and compass variances, as
        ``_build_telemetry`` computes them (the EKF failsafe checks them at 10 Hz: without
        building the whole telemetry)."""
        if not self.nav.aligned:
            vstd = std = np.full(3, math.inf)
        else:
            est = self.nav.state()
            std = np.asarray(est.position_std_m, dtype=float)
            vstd = np.asarray(est.velocity_std_m_s, dtype=float)
        cfg = self.nav.config
        return (float(max(vstd[0], vstd[1]) / cfg.velocity_ok_max_std_m_s),
                float(max(std[0], std[1]) / cfg.position_ok_max_std_m),
                float(self.nav.attitude_std_rad()[2] / 0.2) if self.nav.aligned else 1.0)

    def _build_telemetry(self) -> VehicleTelemetry:
        aligned = self.nav.aligned
        if aligned:
            est = self.nav.state()
            pos = np.asarray(est.position_enu_m, dtype=float)
            vel = np.asarray(est.velocity_enu_m_s, dtype=float)
            roll, pitch, heading = aviation_euler_from_quat(tuple(float(a) for a in est.q_wxyz))
            w = self._gyro - np.asarray(est.gyro_bias, dtype=float)
            std = np.asarray(est.position_std_m, dtype=float)
            vstd = np.asarray(est.velocity_std_m_s, dtype=float)
            wind = np.array([*est.wind_enu_m_s, 0.0], dtype=float)
        else:
            pos = np.array([*self.cfg.start_enu_m, self.cfg.ground_z_m], dtype=float)
            vel = np.zeros(3)
            roll = pitch = heading = 0.0
            w = np.zeros(3)
            wind = np.zeros(3)
            std = np.full(3, math.inf)
            vstd = np.full(3, math.inf)
        lat, lon = self.geo.to_geodetic(float(pos[0]), float(pos[1]))
        home = self._home if self._home is not None else pos
        home_lat, home_lon = self.geo.to_geodetic(float(home[0]), float(home[1]))
        origin = self._origin_enu() if self._origin is not None else pos
        origin_lat, origin_lon = self.geo.to_geodetic(float(origin[0]), float(origin[1]))
        thrust = self._last_out.thrust_n if (self._last_out is not None and self._armed) else 0.0
        g = self._last_gps
        gps_fix = GpsFixType(min(max(g.fix_type, 0), GpsFixType.FIX_3D)) if g is not None \
            else GpsFixType.NO_GPS
        sensors = self._sensor_flags(aligned)
        battery = self.battery.state(self.params.get("BATT_CAPACITY"))
        ok = self.nav.config.position_ok_max_std_m
        return VehicleTelemetry(
            time_boot_ms=int(self._now_s * 1000.0), armed=self._armed, mode=self._reported_mode(),
            landed_state=self._landed_state(), system_status=self._system_status(),
            lat_deg=lat, lon_deg=lon, alt_amsl_m=self.geo.origin_alt_amsl_m + float(pos[2]),
            relative_alt_m=float(pos[2] - home[2]),
            position_ned_m=enu_to_ned(pos - origin), velocity_ned_m_s=enu_to_ned(vel),
            attitude_rpy_rad=(roll, pitch, wrap_pi(heading)),
            body_rates_rad_s=(float(w[0]), -float(w[1]), -float(w[2])),
            heading_deg=math.degrees(heading) % 360.0,
            groundspeed_m_s=float(math.hypot(vel[0], vel[1])),
            airspeed_m_s=float(math.hypot(vel[0] - wind[0], vel[1] - wind[1])), climb_m_s=float(vel[2]),
            wind_ned_m_s=enu_to_ned(wind),
            throttle_pct=100.0 * thrust / self.airframe.max_thrust_n,
            rc_channels_pwm=self.rc_channels(), servo_pwm=motor_pwm(self._motors, self._armed or self.motor_test_state.running),
            gps_fix_type=gps_fix, gps_satellites=g.satellites if g is not None else 0,
            gps_hdop=g.eph_m if g is not None else math.nan,
            gps_vdop=g.epv_m if g is not None else math.nan,
            gps_lat_deg=g.lat_deg if g is not None else 0.0,
            gps_lon_deg=g.lon_deg if g is not None else 0.0,
            gps_alt_amsl_m=(self.geo.origin_alt_amsl_m + g.alt_m) if g is not None else 0.0,
            gps_ground_speed_m_s=float(math.hypot(*g.velocity_enu_m_s[:2])) if g is not None else math.nan,
            gps_course_deg=(math.degrees(math.atan2(g.velocity_enu_m_s[0], g.velocity_enu_m_s[1])) % 360.0)
            if g is not None else math.nan,
            battery_voltage_v=battery.voltage_v, battery_current_a=battery.current_a,
            battery_remaining_pct=battery.remaining_pct,
            home_set=self._home is not None, home_lat_deg=home_lat, home_lon_deg=home_lon,
            home_alt_amsl_m=self.geo.origin_alt_amsl_m + float(home[2]),
            home_position_ned_m=enu_to_ned(np.asarray(home) - origin),
            origin_set=self._origin is not None, origin_lat_deg=origin_lat, origin_lon_deg=origin_lon,
            origin_alt_amsl_m=self.geo.origin_alt_amsl_m + float(origin[2]),
            mission_current_seq=self._mission_index + 1 if self._mission else 0,
            mission_state=self._mission_state,
            ekf_flags=int(self._ekf_flags(aligned)),
            ekf_velocity_variance=float(max(vstd[0], vstd[1]) / self.nav.config.velocity_ok_max_std_m_s),
            ekf_pos_horiz_variance=float(max(std[0], std[1]) / ok),
            ekf_pos_vert_variance=float(std[2] / ok),
            ekf_compass_variance=float(self.nav.attitude_std_rad()[2] / 0.2) if aligned else 1.0,
            sensors_present=int(sensors[0]), sensors_enabled=int(sensors[1]),
            sensors_health=int(sensors[2]),
            **self._flow_telemetry(),
            **self._nav_controller_output(pos, (roll, pitch, heading)),
            **self._imu_and_target(origin))

    def _flow_telemetry(self) -> dict:
        """The flow module's last sample for OPTICAL_FLOW / DISTANCE_SENSOR / RANGEFINDER, in body
        FRD (the bus's FLU with y negated); empty (not fitted) without FLOW_TYPE or a sample."""
        f = self._last_flow
        if f is None or not self._flow_fitted():
            return {}
        r = f.distance_m
        tx, ty = f.translation_rate_flu_rad_s
        cx, cy = tx * r, ty * r
        r_min, r_max = self._rangefinder_limits_m()
        return {"flow_fitted": True, "flow_time_us": int(round(f.t_s * 1e6)),
                "flow_rate_frd_rad_s": (f.flow_flu_rad_s[0], -f.flow_flu_rad_s[1]),
                "flow_comp_frd_m_s": (cx, -cy), "flow_quality": int(f.quality),
                "rangefinder_distance_m": r, "rangefinder_min_m": r_min,
                "rangefinder_max_m": r_max}

    def _nav_controller_output(self, pos: np.ndarray, attitude: tuple[float, float, float]
                               ) -> dict[str, float]:
        """NAV_CONTROLLER_OUTPUT as ArduCopter's ``send_nav_controller_output``: the attitude
        target (degrees), the bearing and horizontal distance to the waypoint of the current
        leg, the vertical position error (target - estimate, m) and the distance from the leg's
        line (0 without a waypoint). Reads state only."""
        out = self._last_out
        if out is not None and self._armed:
            roll, pitch, heading = aviation_euler_from_quat(
                tuple(float(a) for a in out.q_target_wxyz))
        else:
            roll, pitch, heading = attitude
        fields = {"nav_roll_deg": math.degrees(roll), "nav_pitch_deg": math.degrees(pitch),
                  "nav_bearing_deg": math.degrees(heading) % 360.0}
        target = self._last_target
        if target is not None and self._armed and not self.fc.landed:
            fields["alt_error_m"] = float(target.position_enu_m[2] - pos[2])
        leg = getattr(self._law, "leg", None)
        if callable(leg) and self._armed:
            start, wp = leg()
            d = wp[:2] - pos[:2]
            fields["wp_dist_m"] = float(math.hypot(d[0], d[1]))
            fields["target_bearing_deg"] = math.degrees(math.atan2(d[0], d[1])) % 360.0
            track = wp[:2] - start[:2]
            length = float(math.hypot(track[0], track[1]))
            if length > 1e-6:
                rel = pos[:2] - start[:2]
                fields["xtrack_error_m"] = float(abs(track[0] * rel[1] - track[1] * rel[0]) / length)
        return fields

    def _landed_state(self) -> LandedState:
        if not self.nav.aligned:
            return LandedState.UNDEFINED
        if self.fc.landed or not self._armed:
            return LandedState.ON_GROUND
        if self._law_kind() == LawKind.TAKEOFF and not self._law.complete:
            return LandedState.TAKEOFF
        if self._landing():
            return LandedState.LANDING
        return LandedState.IN_AIR

    def _imu_and_target(self, origin: np.ndarray) -> dict:
        """RAW_IMU / SCALED_IMU (FLU -> FRD), VIBRATION, POSITION_TARGET_* fields."""
        a, g = self._accel, self._gyro
        fields: dict = {
            "imu_accel_frd_m_s2": (float(a[0]), -float(a[1]), -float(a[2])),
            "imu_gyro_frd_rad_s": (float(g[0]), -float(g[1]), -float(g[2])),
            "vibration_m_s2": self.vibration.levels,
            "accel_clipping": tuple(self.vibration.clip_counts),
        }
        target = self._last_target
        if target is not None and self._armed and not self.fc.landed:
            fields["target_position_ned_m"] = enu_to_ned(np.asarray(target.position_enu_m) - origin)
            fields["target_velocity_ned_m_s"] = enu_to_ned(target.velocity_enu_m_s)
            fields["target_accel_ned_m_s2"] = enu_to_ned(target.accel_enu_m_s2)
            if target.heading_rad is not None:
                fields["target_yaw_rad"] = float(target.heading_rad)
            lat, lon = self.geo.to_geodetic(float(target.position_enu_m[0]),
                                            float(target.position_enu_m[1]))
            fields.update(target_lat_deg=lat, target_lon_deg=lon,
                          target_alt_amsl_m=self.geo.origin_alt_amsl_m + float(target.position_enu_m[2]))
        return fields

    def _system_status(self) -> SystemStatus:
        if not self.nav.aligned:
            return SystemStatus.BOOT
        if (self.failsafe.any_active or self.ekf_check.active
                or self.battery_failsafe.level != BatteryLevel.OK):
            return SystemStatus.CRITICAL
        return SystemStatus.ACTIVE if self._armed and not self.fc.landed else SystemStatus.STANDBY

    def _ekf_flags(self, aligned: bool) -> EkfStatusFlag:
        if not aligned:
            return EkfStatusFlag.UNINITIALIZED
        flags = EkfStatusFlag(0)
        if self.nav.is_healthy():
            flags |= EkfStatusFlag.ATTITUDE | EkfStatusFlag.POS_VERT_ABS | EkfStatusFlag.POS_VERT_AGL
        if self.nav.velocity_ok():
            flags |= EkfStatusFlag.VELOCITY_HORIZ | EkfStatusFlag.VELOCITY_VERT
        if self._position_ok():
            flags |= (EkfStatusFlag.POS_HORIZ_REL | EkfStatusFlag.POS_HORIZ_ABS
                      | EkfStatusFlag.PRED_POS_HORIZ_REL | EkfStatusFlag.PRED_POS_HORIZ_ABS)
        return flags

    def _sensor_flags(self, aligned: bool) -> tuple[SensorFlag, SensorFlag, SensorFlag]:
        present = SensorFlag(int(DEFAULT_SENSORS)) & ~SensorFlag.VISION_POSITION
        if self._last_gps is not None:
            present |= SensorFlag.GPS
        if self._flow_fitted():
            present |= SensorFlag.OPTICAL_FLOW
        if self.nav.position_source == PositionSource.EXTNAV:
            present |= SensorFlag.VISION_POSITION
        enabled = present
        health = present
        if not (aligned and self.nav.is_healthy()):
            health &= ~SensorFlag.AHRS
        if not self._gps_fix_fresh():
            health &= ~SensorFlag.GPS
        if self.nav.position_source == PositionSource.EXTNAV and not (
                self._ext_nav_available() or (self._last_usable_vision_s is not None
                                              and self._now_s - self._last_usable_vision_s < 2.0)):
            health &= ~SensorFlag.VISION_POSITION
        if not (aligned and not self._prearm_failures()):
            health &= ~SensorFlag.PREARM_CHECK
        # AC_Fence sys_status_present / _enabled / _failed: present with a fence to check, enabled
        # when switched on and not FENCE_ACTION 0 (report only), healthy unless breached (MAVProxy's
        # "fence enabled" / "fence breach" and QGC read these bits)
        health |= SensorFlag.GEOFENCE
        if self._fences_present():
            present |= SensorFlag.GEOFENCE
            if self._fences_on() and self.params.get_int("FENCE_ACTION") != 0:
                enabled |= SensorFlag.GEOFENCE
            if self.fence.breached:
                health &= ~SensorFlag.GEOFENCE
        return present, enabled, health
