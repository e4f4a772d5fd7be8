"""Navigation filter: an 18-state error-state extended Kalman filter (ESKF) for the autopilot.

Nominal state (kept outside the covariance): position p (ENU m), velocity v (ENU m/s), attitude q_wxyz
(body FLU -> world ENU), gyro bias b_g (rad/s, FLU), accelerometer bias b_a (m/s^2, FLU), horizontal
wind w (ENU m/s), compass heading bias b_c (rad).

Error state (18, the covariance ``P``; order used by ``covariance()``):

    0:3   dp      position error, ENU m
    3:6   dv      velocity error, ENU m/s
    6:9   dtheta  attitude error as a small rotation vector in the *world* frame: q_true = Exp(dtheta) * q
    9:12  db_g    gyro bias error, rad/s
    12:15 db_a    accel bias error, m/s^2
    15:17 dw      horizontal wind error (east, north), m/s; a random walk, observed only by drag fusion
    17    db_c    compass heading bias error, rad (measured heading = true heading + b_c + noise)

Prediction (every IMU tick, tick-averaged specific force f and rate w):
    q <- q * Exp((w - b_g) dt)
    v <- v + (R_mid (f - b_a) + g) dt,   p <- p + v dt + 1/2 a dt^2   (R_mid: attitude at mid-tick)
    P <- F P F^T + Q with the continuous-time noise densities of ``EkfConfig`` (Q = density^2 * dt).
Error dynamics:  d(dp) = dv;  d(dv) = -[R f]x dtheta - R db_a;  d(dtheta) = -R db_g;  biases random walks.

Fusion (all sequential, standard EKF update, P symmetrised): barometer -> p_z (the barometer's offset to
ENU z is fixed at ``initialise``); compass heading -> yaw; GPS position -> p_xy (height comes from the
barometer, ArduPilot's EK3_SRC1_POSZ = baro); GPS velocity -> v (3-D); vision fix -> p_xy. After each
update the error is injected into the nominal state and reset to zero; the covariance reset Jacobian
(I - [dtheta/2]x) is taken as identity, which is accurate for the small corrections of a healthy filter.
The covariance prediction and updates are compiled kernels (``autopilot_bridge.ekf_kernels``, numba): one
call each instead of a dozen small numpy calls.

Compass bias (``set_compass_bias_model``, SN_MAG_BIAS_SD / SN_MAG_BIAS_TURN): a compass whose
magnetometer has residual hard- and soft-iron errors and a motor-current term is off by a bias that
depends on the heading (a ship's compass deviation), not by white noise; fused as white noise at
the compass rate, that bias becomes the heading, and at cruise speed every degree of it is 0.17 m/s
of velocity error wherever a body-frame velocity (drag, flow) holds the estimate. With a prior
1-sigma > 0 the bias is a state: the compass measures heading + b_c, and the body-frame velocity
measurements together with position fixes observe the heading itself, so that the bias is learnt
on a straight leg. It is a random walk in the angle turned (variance ``turn_std^2`` per radian,
because the deviation changes with the heading) plus a slow one in time, capped at its prior. With
a prior of 0 (the default) the state is never corrected and the filter is the 17-state one.

Drag fusion (``fuse_drag``, ArduPilot EKF3's FuseDragForces with EK3_DRAG_BCOEF_X/Y, EK3_DRAG_MCOEF,
EK3_DRAG_M_NSE): thrust acts along body z, so the body x, y specific force of a multicopter is the air's
drag alone, a = -(mcoef v_a + 0.5 rho |v_a| v_a / bcoef) per axis with the air-relative velocity
v_a = R^T (v - w). Fused (averaged over a window by the caller) while flying, it ties the velocity to
the wind: between position fixes the dead-reckoned velocity cannot run away by more than the wind's
uncertainty, and the fixes teach the filter the wind. With both coefficients 0 the wind states are
never observed (zero rows in every measurement): the other 15 states behave as without them.

Gating: with innovation nu and innovation covariance S, the normalised innovation squared NIS = nu' S^-1 nu
is compared with gate^2 (gate in standard deviations, like ArduPilot's *_I_GATE / 100); the reported
``test_ratio`` = NIS / gate^2 and a measurement is fused only when test_ratio <= 1.

Position source (ArduPilot EK3_SRC1_POSXY): only the selected source's horizontal position is fused; the
other source's fixes are evaluated (innovation and test ratio are returned, for monitoring) but not used.
GPS velocity is fused only while GPS is the position source. Switching source does not reset anything:
the new source's fixes enter through the same gated update, so the estimate moves towards them at the
rate the covariances allow (continuous, no step). Only if every fix of the selected source is rejected
for ``position_reject_timeout_s`` is the horizontal position reset onto the source (a step); each such
reset increments ``position_reset_count`` and records ``last_position_reset_m`` (the xy jump) so that the
node can shift its position targets, like ArduPilot's EKF xy-reset handling. The barometer height and the
compass heading have the same rejection-timeout reset (``height_reset_count``, ``heading_reset_count``).
GPS velocity too (``velocity_reset_count``, GPS source only): the velocity is set to GPS and the tilt
uncertainty is re-opened, because persistently rejected velocities usually mean a wrong tilt.

Optical flow (``fuse_optical_flow``, ArduPilot EKF3's FuseOptFlow with EK3_FLOW_M_NSE, EK3_FLOW_I_GATE):
a downward flow sensor's rate with the body rotation removed, over the range finder's range, measures
the body-frame horizontal velocity over the ground; it bounds the dead-reckoned velocity, and together
with drag fusion it makes the wind observable, while the range finder reaches the surface.

Zero rate at rest (``fuse_zero_rate``): on the ground and disarmed the averaged body x, y rates are
the gyro biases of those axes; the longer the vehicle rests, the better the bias a dead-reckoned climb
starts with (see the method).

Dead reckoning: with no position fixes the position covariance grows through the velocity and attitude
uncertainty (and is clamped at ``max_position_std_m``); ``position_ok()`` turns false when the horizontal
standard deviation exceeds ``position_ok_max_std_m``.

Delayed fixes: ``fuse_gps_position`` and ``fuse_vision_position`` take the fix's age; the fix is moved
forward by the estimated velocity times the age and its covariance grows by the velocity covariance times
age^2 (no state buffer / delayed-horizon fusion).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field

import numpy as np

from autopilot_bridge.config import EkfConfig, PositionSource
from autopilot_bridge.ekf_kernels import (
    VARIANCE_FLOOR,
    predict_covariance,
    update_direct,
    update_scalar,
    warm_up,
)
from scenenav.core.frames import wrap_pi
from scenenav.core.rotations import (
    heading_from_quat,
    quat_from_euler_zyx,
    quat_from_rotation_vector,
    quat_multiply,
    quat_normalise,
    quat_rotate,
    quat_to_rotation_matrix,
)

logger = logging.getLogger(__name__)

__all__ = ["NavFilter", "NavState", "FusionResult", "PositionSource", "NUM_ERROR_STATES"]

NUM_ERROR_STATES = 18
_POS = slice(0, 3)
_VEL = slice(3, 6)
_ATT = slice(6, 9)
_BG = slice(9, 12)
_BA = slice(12, 15)
_WIND = slice(15, 17)
_MAG_BIAS = 17
_TWO_PI = 2.0 * math.pi
# States the barometer and the compass correct (see fuse_baro / fuse_compass): height, vertical velocity
# and vertical accelerometer bias; heading, vertical gyro bias and the compass's own bias.
_BARO_STATES = np.array([2, 5, 14])
_COMPASS_STATES = np.array([8, 11, _MAG_BIAS])
_EXT_HEIGHT_STATES = np.array([2, 5])     # external-navigation height: height, vertical velocity


def _skew(a: np.ndarray) -> np.ndarray:
    """[a]x: the matrix of the cross product a x (.)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _mask(states: np.ndarray) -> np.ndarray:
    m = np.zeros(NUM_ERROR_STATES)
    m[states] = 1.0
    return m


_BARO_MASK = _mask(_BARO_STATES)
_COMPASS_MASK = _mask(_COMPASS_STATES)
_EXT_HEIGHT_MASK = _mask(_EXT_HEIGHT_STATES)
_ALL_MASK = np.ones(NUM_ERROR_STATES)
_XY_STATES = np.array([0, 1], dtype=np.int64)        # horizontal position fixes
_VEL_STATES = np.array([3, 4, 5], dtype=np.int64)    # GPS velocity
_GYRO_XY_BIAS_STATES = np.array([9, 10], dtype=np.int64)   # zero-rate fusion at rest: body x, y
_H_HEIGHT = np.zeros(NUM_ERROR_STATES)     # height measurements: z
_H_HEIGHT[2] = 1.0
#: tilt_rows: a camera ray closer to the horizon than this (its down component, ~78 deg off nadir)
#: gives no tilt rows (the ground offset's derivative grows without bound there)
_MIN_DOWN_COMPONENT = 0.2




# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FusionResult:
    """Outcome of one measurement fusion.

    ``innovation`` = measurement - prediction (before the update); ``test_ratio`` = NIS / gate^2 (<= 1
    passes the gate). ``accepted`` is true when the measurement changed the state (fused, or a reset);
    ``reset`` marks a rejection-timeout reset onto the measurement.
    """

    accepted: bool
    innovation: np.ndarray
    test_ratio: float
    reset: bool = False


@dataclass(frozen=True)
class NavState:
    """Navigation solution handed to the controllers (arrays are copies)."""

    position_enu_m: np.ndarray      # (3,)
    velocity_enu_m_s: np.ndarray    # (3,)
    q_wxyz: np.ndarray              # (4,) body FLU -> world ENU
    gyro_bias: np.ndarray           # (3,) rad/s, body FLU
    accel_bias: np.ndarray          # (3,) m/s^2, body FLU
    position_std_m: np.ndarray      # (3,) 1-sigma
    velocity_std_m_s: np.ndarray    # (3,) 1-sigma
    heading_rad: float              # compass, clockwise from north, [0, 2 pi)
    # (2,) horizontal wind east, north (zero unless drag fusion is on)
    wind_enu_m_s: np.ndarray = field(default_factory=lambda: np.zeros(2))
    # the compass heading's estimated bias (measured minus true heading), rad; 0 without the bias state
    compass_bias_rad: float = 0.0


class NavFilter:
    """18-state error-state EKF; see the module docstring for the model and the conventions."""

    def __init__(self, cfg: EkfConfig | None = None) -> None:
        self._cfg = cfg if cfg is not None else EkfConfig()
        self._vision_floor_m = 0.0      # VISO_POS_M_NSE (set_vision_noise_floor); the config's floor rules below it
        c = self._cfg
        self._g = c.gravity_m_s2
        self._source = c.position_source
        self._p = [0.0, 0.0, 0.0]
        self._v = [0.0, 0.0, 0.0]
        self._q = (1.0, 0.0, 0.0, 0.0)
        self._bg = [0.0, 0.0, 0.0]
        self._w_flu = (0.0, 0.0, 0.0)   # the last body rate, bias removed (rad/s, FLU)
        self._ba = [0.0, 0.0, 0.0]
        self._wind = [0.0, 0.0]
        self._mag_bias = 0.0            # compass heading bias, rad (measured minus true)
        # the states the kernels work on: 17, or 18 with the compass-bias state (ekf_kernels)
        self._n = NUM_ERROR_STATES if c.compass_bias_std_rad > 0.0 else _MAG_BIAS
        self._P = np.zeros((NUM_ERROR_STATES, NUM_ERROR_STATES))
        warm_up()           # the compiled kernels load now, not in the first control tick
        # work arrays of the compiled kernels (ekf_kernels)
        self._tmp = np.zeros((NUM_ERROR_STATES, NUM_ERROR_STATES))
        self._qd = np.zeros(NUM_ERROR_STATES)
        self._qd_dt = math.nan
        self._h = np.zeros(NUM_ERROR_STATES)
        self._h_drag = np.zeros(NUM_ERROR_STATES)    # fuse_drag and fuse_optical_flow rows (self._h keeps zeros off 6:9)
        self._u = np.zeros(NUM_ERROR_STATES)
        self._dx = np.zeros(NUM_ERROR_STATES)
        self._work: dict[int, tuple[np.ndarray, ...]] = {}
        self._q_density = np.zeros(NUM_ERROR_STATES)
        self._set_q_density()
        self._max_pos_var = c.max_position_std_m ** 2
        self._max_vel_var = c.max_velocity_std_m_s ** 2
        self._baro_offset_m = 0.0
        self._time_s = 0.0
        self._pos_last_ok_s = 0.0
        self._hgt_last_ok_s = 0.0
        self._hdg_last_ok_s = 0.0
        self._vel_last_ok_s = 0.0
        self._heading_reset_count = 0
        self._velocity_reset_count = 0
        self._position_reset_count = 0
        self._last_position_reset_m = np.zeros(2)
        self._refused_reset_count = 0
        self._last_refused_reset_m = np.zeros(2)
        self._height_reset_count = 0
        self.aligned = False
        # is_healthy() is kept until the state changes: _rev counts the changes (predict, updates,
        # resets, initialise)
        self._rev = 0
        self._healthy_rev = -1
        self._healthy = False

    # ------------------------------------------------------------------ setup
    @property
    def config(self) -> EkfConfig:
        return self._cfg

    def _set_q_density(self) -> None:
        """Process noise densities^2 of every error state from the config (the wind's only while drag
        fusion is on: unobserved, its variance would otherwise grow without end; the compass bias's
        only while it is a state)."""
        c = self._cfg
        wind = c.wind_noise_m_s2_per_rt_hz ** 2 if c.drag_fusion else 0.0
        mag = c.compass_bias_noise_rad_per_rt_s ** 2 if c.compass_bias_std_rad > 0.0 else 0.0
        self._q_density[:] = ([0.0] * 3 + [c.accel_noise_m_s2_per_rt_hz ** 2] * 3
                              + [c.gyro_noise_rad_s_per_rt_hz ** 2] * 3
                              + [c.gyro_bias_noise_rad_s2_per_rt_hz ** 2] * 3
                              + [c.accel_bias_noise_m_s3_per_rt_hz ** 2] * 3 + [wind] * 2 + [mag])
        self._qd_dt = math.nan

    def initialise(self, accel_flu_m_s2, heading_rad: float, baro_alt_m: float, *,
                   gyro_flu_rad_s=None, position_enu_m=None, gps_position_enu_m=None,
                   at_rest: bool = True) -> None:
        """Align at rest: roll/pitch from the specific force, heading from the compass, height reference
        from the barometer, horizontal position from ``position_enu_m`` (a known home), else GPS, else the
        origin with ``unknown_position_std_m``. Pass averages of about a second of samples at rest;
        ``gyro_flu_rad_s`` (the average rate at rest) seeds the gyro bias. ``at_rest=False`` (a start in
        the air, from samples taken while flying) keeps the wide, independent priors of an unknown tilt
        (``initial_tilt_moving_std_rad``) and gyro bias: the specific force of a hovering vehicle in
        wind does not level it.

        Height: the barometer altitude is taken as ENU z (offset 0) unless ``position_enu_m`` is given, in
        which case the offset is set so that the filter's z equals ``position_enu_m[2]``. GPS height is
        never used (height source = barometer).
        """
        c = self._cfg
        fx, fy, fz = (float(a) for a in accel_flu_m_s2)
        if not all(math.isfinite(a) for a in (fx, fy, fz, heading_rad, baro_alt_m)):
            raise ValueError("NavFilter.initialise: non-finite accel, heading or baro sample")
        if math.sqrt(fx * fx + fy * fy + fz * fz) < 0.5 * self._g:
            raise ValueError("NavFilter.initialise: specific force far below gravity; is the vehicle at rest?")
        roll = math.atan2(fy, fz)
        pitch = math.atan2(-fx, math.sqrt(fy * fy + fz * fz))   # FLU pitch (positive = nose down)
        yaw = 0.5 * math.pi - float(heading_rad)
        self._q = quat_normalise(quat_from_euler_zyx(yaw, pitch, roll))

        pos_std = c.initial_position_std_m
        pz = float(baro_alt_m)
        if position_enu_m is not None:
            px, py, pz = (float(a) for a in position_enu_m)
        elif gps_position_enu_m is not None:
            px, py = (float(a) for a in list(gps_position_enu_m)[:2])
        else:
            px, py = 0.0, 0.0
            pos_std = c.unknown_position_std_m
        self._p = [px, py, pz]
        self._v = [0.0, 0.0, 0.0]
        self._baro_offset_m = float(baro_alt_m) - pz
        self._bg = [float(a) for a in gyro_flu_rad_s] if gyro_flu_rad_s is not None else [0.0, 0.0, 0.0]
        self._clamp_biases()
        self._ba = [0.0, 0.0, 0.0]
        self._wind = [0.0, 0.0]
        self._mag_bias = 0.0

        # The gyro bias seeded from the average rate at rest is known far better than an unknown one;
        # treating it as unknown makes the tilt (and, without position aiding, the position) uncertainty
        # grow by ~0.6 deg/s from the take-off.
        # The body z (yaw) bias keeps the wide prior: the compass observes it quickly, and a slow turn
        # during the alignment (a moving platform) shows up there.
        seeded = gyro_flu_rad_s is not None and at_rest
        bg_std = c.aligned_gyro_bias_std_rad_s if seeded else c.initial_gyro_bias_std_rad_s
        sa = c.initial_accel_bias_std_m_s2
        tilt_std = c.initial_tilt_std_rad if at_rest else c.initial_tilt_moving_std_rad
        variances = ([pos_std ** 2] * 2 + [c.baro_noise_m ** 2]
                     + [c.initial_velocity_std_m_s ** 2] * 3
                     + [tilt_std ** 2] * 2 + [c.initial_heading_std_rad ** 2]
                     + [bg_std ** 2] * 2 + [c.initial_gyro_bias_std_rad_s ** 2]
                     + [sa ** 2] * 3)
        variances += [c.initial_wind_std_m_s ** 2 if c.drag_fusion else 0.0] * 2
        variances += [c.compass_bias_std_rad ** 2]
        P = np.diag(np.array(variances, dtype=float))
        # Levelling on the measured specific force absorbs the horizontal accelerometer bias into the
        # tilt: with w = R b_a (world), the levelled tilt error is dtheta_x = -w_y / g, dtheta_y = w_x / g
        # (plus the independent levelling error initial_tilt_std_rad), so that the horizontal specific
        # force g dtheta + R b_a, which is what drives the velocity, starts known to the levelling error
        # only. (Independent tilt and bias priors would add ~0.28 m/s^2 of phantom acceleration
        # uncertainty: ~14 m of position 1-sigma 10 s after the take-off without aiding.)
        if at_rest:
            g = self._g
            M = np.array([[0.0, -1.0 / g, 0.0], [1.0 / g, 0.0, 0.0], [0.0, 0.0, 0.0]])
            cross = (sa * sa) * (M @ quat_to_rotation_matrix(self._q))
            P[_ATT, _ATT] += (sa * sa) * (M @ M.T)
            P[_ATT, _BA] = cross
            P[_BA, _ATT] = cross.T
        self._P = P
        self._time_s = 0.0
        self._pos_last_ok_s = 0.0
        self._hgt_last_ok_s = 0.0
        self._hdg_last_ok_s = 0.0
        self._vel_last_ok_s = 0.0
        self.aligned = True
        self._rev += 1
        logger.info("NavFilter aligned: roll %.2f deg, pitch %.2f deg, heading %.1f deg, position (%.1f, %.1f, %.1f) m"
                    " +- %.1f m, source %s", math.degrees(roll), math.degrees(-pitch),
                    math.degrees(heading_rad % _TWO_PI), px, py, pz, pos_std, self._source.name)

    # ------------------------------------------------------------------ source selection
    @property
    def position_source(self) -> PositionSource:
        return self._source

    def set_gyro_bias_noise(self, density_rad_s2_per_rt_hz: float) -> None:
        """Change the gyro-bias random walk the filter assumes (``EK3_GBIAS_P_NSE``); from the next
        prediction on. It also sets how well the bias must be known before a dead-reckoned climb
        (``gyro_bias_learned``)."""
        self._cfg = dataclasses.replace(self._cfg, gyro_bias_noise_rad_s2_per_rt_hz=float(density_rad_s2_per_rt_hz))
        self._set_q_density()

    def set_accel_noise(self, density_m_s2_per_rt_hz: float) -> None:
        """Change the accelerometer white-noise density the filter assumes (``EK3_ACC_P_NSE``), the
        velocity's process noise; from the next prediction on."""
        self._cfg = dataclasses.replace(self._cfg, accel_noise_m_s2_per_rt_hz=float(density_m_s2_per_rt_hz))
        self._set_q_density()

    def set_vision_reset_max(self, max_m: float) -> None:
        """Largest jump of a position reset onto vision fixes (``SN_VIS_RST_MAX``; 0 = no limit)."""
        self._cfg = dataclasses.replace(self._cfg, vision_reset_max_m=float(max_m))

    def set_position_gate(self, gate_sd: float) -> None:
        """Change the horizontal position innovation gate, in standard deviations (``EK3_POS_I_GATE``
        / 100); from the next position fusion on."""
        self._cfg = dataclasses.replace(self._cfg, position_gate_sd=float(gate_sd))

    def set_vision_noise_floor(self, floor_m: float) -> None:
        """Raise the floor on each vision fix's 1-sigma per axis (``VISO_POS_M_NSE``, ArduPilot's
        minimum visual-odometry position noise) above ``vision_position_noise_min_m``; from the next
        fusion on. A floor below the configured one changes nothing."""
        self._vision_floor_m = float(floor_m)

    def set_compass_noise(self, std_rad: float) -> None:
        """Change the compass heading's measurement noise (``EK3_YAW_M_NSE``); from the next fusion on.
        A larger value lets position fixes and drag correct a biased compass heading."""
        self._cfg = dataclasses.replace(self._cfg, compass_noise_rad=float(std_rad))

    def set_compass_bias_model(self, std_rad: float, turn_std_rad: float) -> None:
        """The compass heading's bias state (module docstring; SN_MAG_BIAS_SD, SN_MAG_BIAS_TURN):
        prior 1-sigma and cap ``std_rad`` (0 = no bias state: the estimate is kept at zero and
        uncorrelated) and the 1-sigma change per radian turned. Switching it on opens the bias at
        zero with its prior; from the next step on. Raises ValueError for values the config refuses."""
        was = self._cfg.compass_bias_std_rad
        self._cfg = dataclasses.replace(self._cfg, compass_bias_std_rad=float(std_rad),
                                        compass_bias_turn_std_rad=float(turn_std_rad))
        self._set_q_density()
        now = self._cfg.compass_bias_std_rad
        self._n = NUM_ERROR_STATES if now > 0.0 else _MAG_BIAS
        if now == was:
            return
        self._rev += 1
        P = self._P
        P[_MAG_BIAS, :] = 0.0
        P[:, _MAG_BIAS] = 0.0
        if now > 0.0 and was == 0.0:
            self._mag_bias = 0.0
            P[_MAG_BIAS, _MAG_BIAS] = now * now if self.aligned else 0.0
        elif now == 0.0:
            self._mag_bias = 0.0
        else:
            P[_MAG_BIAS, _MAG_BIAS] = now * now

    def set_drag_model(self, *, ballistic_x_kg_m2: float, ballistic_y_kg_m2: float, momentum_per_s: float,
                       noise_m_s2: float, wind_noise_m_s2_per_rt_hz: float) -> None:
        """Change the drag model of ``fuse_drag`` (EK3_DRAG_BCOEF_X/Y, EK3_DRAG_MCOEF, EK3_DRAG_M_NSE,
        EK3_WIND_P_NSE); from the next step on. Switching drag fusion on opens the wind's uncertainty
        (``initial_wind_std_m_s``, the wind estimate restarting at zero), switching it off freezes it.
        Raises ValueError for values the config refuses."""
        was_on = self._cfg.drag_fusion
        self._cfg = dataclasses.replace(
            self._cfg, drag_ballistic_coef_x_kg_m2=float(ballistic_x_kg_m2),
            drag_ballistic_coef_y_kg_m2=float(ballistic_y_kg_m2), drag_momentum_coef_per_s=float(momentum_per_s),
            drag_noise_m_s2=float(noise_m_s2), wind_noise_m_s2_per_rt_hz=float(wind_noise_m_s2_per_rt_hz))
        self._set_q_density()
        if self._cfg.drag_fusion and not was_on and self.aligned:
            self._open_wind()

    def _open_wind(self) -> None:
        """Wind unknown: estimate zero, uncorrelated, ``initial_wind_std_m_s``."""
        self._rev += 1
        self._wind = [0.0, 0.0]
        P = self._P
        P[_WIND, :] = 0.0
        P[:, _WIND] = 0.0
        P[15, 15] = P[16, 16] = self._cfg.initial_wind_std_m_s ** 2

    def set_position_source(self, source: PositionSource) -> None:
        """Select the horizontal position source (EK3_SRC1_POSXY); takes effect on the next fix, no reset."""
        source = PositionSource(source)
        if source == self._source:
            return
        logger.info("NavFilter position source %s -> %s", self._source.name, source.name)
        self._source = source
        # The new source gets the full rejection timeout before any reset onto it.
        self._pos_last_ok_s = self._time_s
        self._vel_last_ok_s = self._time_s

    # ------------------------------------------------------------------ prediction
    def predict(self, accel_flu_m_s2, gyro_flu_rad_s, dt_s: float) -> None:
        """Propagate with one IMU tick: tick-averaged specific force (m/s^2) and body rate (rad/s), FLU."""
        if not self.aligned:
            raise RuntimeError("NavFilter.predict called before initialise")
        dt = float(dt_s)
        if not (0.0 < dt < 1.0):
            logger.warning("NavFilter.predict: ignoring dt_s = %r", dt_s)
            return
        bg, ba = self._bg, self._ba
        wx = float(gyro_flu_rad_s[0]) - bg[0]
        wy = float(gyro_flu_rad_s[1]) - bg[1]
        wz = float(gyro_flu_rad_s[2]) - bg[2]
        self._w_flu = (wx, wy, wz)
        ax = float(accel_flu_m_s2[0]) - ba[0]
        ay = float(accel_flu_m_s2[1]) - ba[1]
        az = float(accel_flu_m_s2[2]) - ba[2]
        if not math.isfinite(wx + wy + wz + ax + ay + az):
            logger.warning("NavFilter.predict: ignoring a non-finite IMU sample")
            return
        half = quat_from_rotation_vector(0.5 * dt * wx, 0.5 * dt * wy, 0.5 * dt * wz)
        q_mid = quat_multiply(self._q, half)
        self._q = quat_normalise(quat_multiply(q_mid, half))
        rot = quat_to_rotation_matrix(q_mid)
        r = rot.tolist()
        fx = r[0][0] * ax + r[0][1] * ay + r[0][2] * az
        fy = r[1][0] * ax + r[1][1] * ay + r[1][2] * az
        fz = r[2][0] * ax + r[2][1] * ay + r[2][2] * az
        acc = (fx, fy, fz - self._g)
        p, v = self._p, self._v
        half_dt2 = 0.5 * dt * dt
        for i in range(3):
            p[i] += v[i] * dt + acc[i] * half_dt2
            v[i] += acc[i] * dt

        if dt != self._qd_dt:
            self._qd_dt = dt
            self._qd = self._q_density * dt
        # P <- F P F' + Q: F = I + dt blocks, d(dv)/d(dtheta) = -[f_world]x dt, -R dt on the biases
        P = self._P
        predict_covariance(P, self._tmp, dt, fx, fy, fz, rot, self._qd, self._n)
        if self._n == NUM_ERROR_STATES:
            # the deviation changes with the heading: a random walk in the angle turned (world z rate)
            bias_std = self._cfg.compass_bias_std_rad
            turned = abs(r[2][0] * wx + r[2][1] * wy + r[2][2] * wz) * dt
            P[_MAG_BIAS, _MAG_BIAS] += self._cfg.compass_bias_turn_std_rad ** 2 * turned
            if P[_MAG_BIAS, _MAG_BIAS] > bias_std * bias_std:
                self._clamp_variance((_MAG_BIAS,), bias_std * bias_std)
        if P[0, 0] > self._max_pos_var or P[1, 1] > self._max_pos_var or P[2, 2] > self._max_pos_var:
            self._clamp_variance(range(0, 3), self._max_pos_var)
        if P[3, 3] > self._max_vel_var or P[4, 4] > self._max_vel_var or P[5, 5] > self._max_vel_var:
            self._clamp_variance(range(3, 6), self._max_vel_var)
        self._time_s += dt
        self._rev += 1

    def _clamp_variance(self, indices, max_var: float) -> None:
        """Scale row/column i so that P[i, i] <= max_var (D P D keeps P positive semi-definite)."""
        P = self._P
        for i in indices:
            if P[i, i] > max_var:
                s = math.sqrt(max_var / P[i, i])
                P[i, :] *= s
                P[:, i] *= s

    # ------------------------------------------------------------------ fusion core
    def _update_scalar(self, innovation: float, h: np.ndarray, r: float, gate_sd: float,
                       mask: np.ndarray | None) -> FusionResult:
        """``_update`` for one measurement row ``h`` (15) with variance ``r``, compiled
        (``ekf_kernels.update_scalar``); ``mask``: the corrected states (1.0) of a Schmidt update,
        None = every state."""
        innov = np.array([innovation])
        if not math.isfinite(innovation):
            return FusionResult(False, innov, float("nan"))
        ratio = update_scalar(self._P, h, float(r), float(innovation), float(gate_sd),
                              _ALL_MASK if mask is None else mask, mask is not None, True,
                              self._u, self._dx, self._n)
        if ratio == math.inf:
            logger.warning("NavFilter: singular innovation covariance; measurement skipped")
            return FusionResult(False, innov, ratio)
        if not ratio <= 1.0:
            return FusionResult(False, innov, ratio)
        self._inject(self._dx)
        return FusionResult(True, innov, ratio)

    def _update_direct(self, innovation: np.ndarray, states: np.ndarray, R: np.ndarray, gate_sd: float,
                       apply: bool) -> FusionResult:
        """``_update`` for a direct measurement of ``states`` (H = rows of the identity), every
        state corrected, compiled (``ekf_kernels.update_direct``)."""
        m = len(states)
        work = self._work.get(m)
        if work is None:
            work = self._work[m] = (np.zeros((m, m)), np.zeros((m, m)), np.zeros((NUM_ERROR_STATES, m)),
                                    np.zeros((NUM_ERROR_STATES, m)))
        nu = np.ascontiguousarray(innovation, dtype=float)
        ratio = update_direct(self._P, states, np.ascontiguousarray(R, dtype=float), nu, float(gate_sd),
                              bool(apply), *work, self._dx, self._n)
        if ratio == math.inf:
            logger.warning("NavFilter: singular innovation covariance; measurement skipped")
            return FusionResult(False, innovation, ratio)
        if apply and ratio <= 1.0:
            self._inject(self._dx)
            return FusionResult(True, innovation, ratio)
        return FusionResult(False, innovation, ratio)

    def _update_rows(self, innovation: np.ndarray, H: np.ndarray, R: np.ndarray, gate_sd: float,
                     apply: bool) -> FusionResult:
        """A gated update with measurement rows ``H`` (m x N) and noise covariance ``R``, every state
        corrected (``P <- P - K H P``), in numpy (a vision fix with its tilt rows: a few a second).
        On the first ``self._n`` states (a contiguous copy: the 17-state filter's arithmetic while
        the compass-bias state is off)."""
        n = self._n
        P = np.ascontiguousarray(self._P[:n, :n])
        H = np.ascontiguousarray(H[:, :n])
        pht = P @ H.T
        S = H @ pht + R
        try:
            s_inv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            s_inv = None
        ratio = float(innovation @ s_inv @ innovation) / (gate_sd * gate_sd) if s_inv is not None else math.inf
        if not math.isfinite(ratio):
            logger.warning("NavFilter: singular innovation covariance; measurement skipped")
            return FusionResult(False, innovation, math.inf)
        if not (apply and ratio <= 1.0):
            return FusionResult(False, innovation, ratio)
        K = pht @ s_inv
        self._dx[:n] = K @ innovation
        P -= K @ pht.T
        P[:] = 0.5 * (P + P.T)
        idx = np.arange(n)
        P[idx, idx] = np.maximum(P[idx, idx], VARIANCE_FLOOR)
        self._P[:n, :n] = P
        self._inject(self._dx)
        return FusionResult(True, innovation, ratio)

    def _inject(self, dx: np.ndarray) -> None:
        self._rev += 1
        d = dx.tolist()
        for i in range(3):
            self._p[i] += d[i]
            self._v[i] += d[3 + i]
            self._bg[i] += d[9 + i]
            self._ba[i] += d[12 + i]
        self._wind[0] += d[15]
        self._wind[1] += d[16]
        if self._n == NUM_ERROR_STATES:
            self._mag_bias += d[_MAG_BIAS]
        self._q = quat_normalise(quat_multiply(quat_from_rotation_vector(d[6], d[7], d[8]), self._q))
        self._clamp_biases()

    def _clamp_biases(self) -> None:
        mg, ma = self._cfg.max_gyro_bias_rad_s, self._cfg.max_accel_bias_m_s2
        self._bg = [min(max(b, -mg), mg) for b in self._bg]
        self._ba = [min(max(b, -ma), ma) for b in self._ba]

    def _require_aligned(self, what: str) -> None:
        if not self.aligned:
            raise RuntimeError(f"NavFilter.{what} called before initialise")

    # ------------------------------------------------------------------ measurements
    def fuse_baro(self, alt_m: float) -> FusionResult:
        """Barometric altitude (m, same reference as at initialise) -> z."""
        self._require_aligned("fuse_baro")
        c = self._cfg
        r = c.baro_noise_m ** 2
        result = self._update_scalar(float(alt_m) - self._baro_offset_m - self._p[2], _H_HEIGHT, r,
                                     c.height_gate_sd, _BARO_MASK)
        innov = result.innovation
        R = np.array([[r]])
        if result.accepted:
            self._hgt_last_ok_s = self._time_s
        elif self._time_s - self._hgt_last_ok_s > c.height_reject_timeout_s and math.isfinite(float(innov[0])):
            self._reset_axes([2], np.array([self._p[2] + float(innov[0])]), R)
            self._height_reset_count += 1
            self._hgt_last_ok_s = self._time_s
            logger.warning("NavFilter: height reset to the barometer (jump %.2f m)", float(innov[0]))
            return FusionResult(True, innov, result.test_ratio, reset=True)
        return result

    def fuse_compass(self, heading_rad: float) -> FusionResult:
        """Compass heading (clockwise from north, rad) -> yaw."""
        self._require_aligned("fuse_compass")
        return self._fuse_heading(heading_rad, self._cfg.compass_noise_rad, "the compass", compass=True)

    def fuse_ext_nav_yaw(self, heading_rad: float, std_rad: float, age_s: float = 0.0) -> FusionResult:
        """External-navigation heading (EK3_SRCn_YAW = 6: ArduPilot fuses the ExtNav yaw instead of
        the compass; ``std_rad`` from VISO_YAW_M_NSE and the message) -> yaw. A heading measured
        ``age_s`` ago is moved forward with the current turn rate, as positions are with the velocity."""
        self._require_aligned("fuse_ext_nav_yaw")
        heading = float(heading_rad)
        if age_s > 0.0:
            heading += self._heading_rate_rad_s() * float(age_s)
        return self._fuse_heading(heading, max(float(std_rad), 1e-3), "external navigation")

    def _heading_rate_rad_s(self) -> float:
        """Clockwise heading rate (heading = pi/2 - yaw) from the last body rate, bias removed."""
        return -float(quat_rotate(self._q, self._w_flu)[2])

    def fuse_ext_nav_height(self, z_enu_m: float, std_m: float, age_s: float = 0.0) -> FusionResult:
        """External-navigation height (EK3_SRCn_POSZ = 6, ENU z in this filter's frame) -> z and the
        vertical velocity (not the barometer's bias states); reset after the height timeout as a
        rejected barometer would be. A height measured ``age_s`` ago is moved forward with the
        vertical velocity (its uncertainty added), as positions are."""
        self._require_aligned("fuse_ext_nav_height")
        c = self._cfg
        z = float(z_enu_m)
        var = max(float(std_m), 0.01) ** 2
        if age_s > 0.0:
            z += self._v[2] * float(age_s)
            var += float(self._P[5, 5]) * float(age_s) ** 2
        result = self._update_scalar(z - self._p[2], _H_HEIGHT, var, c.height_gate_sd,
                                     _EXT_HEIGHT_MASK)
        innov = result.innovation
        R = np.array([[var]])
        if result.accepted:
            self._hgt_last_ok_s = self._time_s
        elif self._time_s - self._hgt_last_ok_s > c.height_reject_timeout_s and math.isfinite(float(innov[0])):
            self._reset_axes([2], np.array([z]), R)
            self._height_reset_count += 1
            self._hgt_last_ok_s = self._time_s
            logger.warning("NavFilter: height reset to external navigation (jump %.2f m)", float(innov[0]))
            return FusionResult(True, innov, result.test_ratio, reset=True)
        return result

    def _fuse_heading(self, heading_rad: float, std_rad: float, what: str, compass: bool = False) -> FusionResult:
        """A heading (clockwise from north, rad) -> yaw; a ``compass`` heading measures the heading
        plus the compass bias state."""
        c = self._cfg
        # Body x axis in the world (a, b, c); d(yaw) = dtheta_z - (a c dtheta_x + b c dtheta_y)/(a^2+b^2);
        # heading = pi/2 - yaw.
        a, b, cz = quat_rotate(self._q, (1.0, 0.0, 0.0))
        h2 = max(a * a + b * b, 1e-6)
        h = self._h
        h[6] = a * cz / h2
        h[7] = b * cz / h2
        h[8] = -1.0
        bias = self._mag_bias if compass else 0.0
        h[_MAG_BIAS] = 1.0 if compass else 0.0
        result = self._update_scalar(wrap_pi(float(heading_rad) - bias - heading_from_quat(self._q)), h,
                                     std_rad ** 2, c.heading_gate_sd, _COMPASS_MASK)
        innov = result.innovation
        if result.accepted:
            self._hdg_last_ok_s = self._time_s
        elif self._time_s - self._hdg_last_ok_s > c.heading_reject_timeout_s and math.isfinite(float(innov[0])):
            self._reset_heading(float(innov[0]), std_rad, what)
            return FusionResult(True, innov, result.test_ratio, reset=True)
        return result

    def reset_heading_to_compass(self, heading_rad: float) -> float:
        """Set the heading to a compass reading (ArduPilot EKF3's in-flight yaw alignment,
        ``controlMagYawReset``); returns the jump, rad."""
        self._require_aligned("reset_heading_to_compass")
        jump = wrap_pi(float(heading_rad) - self._mag_bias - heading_from_quat(self._q))
        if math.isfinite(jump):
            self._reset_heading(jump, self._cfg.compass_noise_rad, "the compass (in-flight alignment)")
        return jump

    def _reset_heading(self, innovation_rad: float, std_rad: float, what: str) -> None:
        """Rotate the attitude about world z onto the measurement (heading = pi/2 - yaw, so
        yaw -= innovation) and restart the heading uncertainty from its noise."""
        c = self._cfg
        self._q = quat_normalise(quat_multiply(quat_from_rotation_vector(0.0, 0.0, -innovation_rad), self._q))
        P = self._P
        P[8, :] = 0.0
        P[:, 8] = 0.0
        P[8, 8] = std_rad ** 2 + c.initial_heading_std_rad ** 2
        self._rev += 1
        self._heading_reset_count += 1
        self._hdg_last_ok_s = self._time_s
        logger.warning("NavFilter: heading reset to %s (jump %.1f deg)", what, math.degrees(innovation_rad))

    def fuse_drag(self, mean_accel_flu_m_s2) -> tuple[FusionResult, FusionResult]:
        """Drag fusion (module docstring): the body x and y specific force averaged over a window of
        flight (m/s^2, FLU, as the accelerometer reads it) as two sequential scalar measurements of
        the air-relative velocity, each gated like a velocity; every state is corrected. Returns the
        (x, y) results; a not-accepted pair when drag fusion is off (both coefficients 0).

        Model per body axis j: f_j = b_a,j - (mcoef + 0.5 rho |v_a| / bcoef_j) v_a,j, with
        v_a = R^T (v - w) (3-D, w horizontal). Its Jacobian: d v_a / d dv = R^T, d v_a / d dw = -R^T
        (x, y columns), d v_a / d dtheta = R^T [v - w]x (the attitude error is a world rotation).
        """
        self._require_aligned("fuse_drag")
        c = self._cfg
        f = np.asarray(mean_accel_flu_m_s2, dtype=float).reshape(3)
        off = FusionResult(False, np.array([math.nan]), math.nan)
        if not c.drag_fusion or not np.all(np.isfinite(f)):
            return off, off
        results = []
        for axis, bcoef in ((0, c.drag_ballistic_coef_x_kg_m2), (1, c.drag_ballistic_coef_y_kg_m2)):
            rot = quat_to_rotation_matrix(self._q)
            u = np.array([self._v[0] - self._wind[0], self._v[1] - self._wind[1], self._v[2]])
            va = rot.T @ u
            speed = float(np.linalg.norm(va))
            kb = 0.5 * c.air_density_kg_m3 / bcoef if bcoef > 0.0 else 0.0
            predicted = -(c.drag_momentum_coef_per_s + kb * speed) * float(va[axis]) + self._ba[axis]
            # d predicted / d v_a (row): -(mcoef + kb |v_a|) e_j - kb v_a,j v_a / |v_a|
            j_row = np.zeros(3)
            j_row[axis] = -(c.drag_momentum_coef_per_s + kb * speed)
            if speed > 1e-6:
                j_row -= kb * float(va[axis]) * va / speed
            jr = j_row @ rot.T                                      # d / d v (world)
            ux = _skew(u)
            h = self._h_drag
            h[:] = 0.0
            h[3:6] = jr
            h[6:9] = jr @ ux
            h[12 + axis] = 1.0
            h[15] = -jr[0]
            h[16] = -jr[1]
            results.append(self._update_scalar(float(f[axis]) - predicted, h, c.drag_noise_m_s2 ** 2,
                                               c.velocity_gate_sd, None))
        return results[0], results[1]

    def fuse_optical_flow(self, los_rate_flu_rad_s, range_m: float, noise_rad_s: float,
                          gate_sd: float, range_std_m: float = 0.0) -> tuple[FusionResult, FusionResult]:
        """Optical-flow fusion (ArduPilot EKF3's FuseOptFlow, with the range finder's range in place
        of EKF3's terrain state): the flow of a downward sensor with the body rotation removed,
        (x, y) rad/s about body x and y, as two sequential scalar measurements of the body velocity
        over the range ``range_m`` along body -z: x = -v_b,y / r, y = v_b,x / r with v_b = R^T v.
        Every state is corrected. Variance per axis: ``noise_rad_s^2`` plus the range's share,
        (predicted rate * range_std_m / r)^2; gated at ``gate_sd`` (EK3_FLOW_I_GATE / 100). Returns
        the (x, y) results; a not-accepted pair for a non-finite rate or a range that is not > 0.

        Jacobian (the attitude error is a world rotation): d v_b / d dv = R^T,
        d v_b / d dtheta = R^T [v]x.
        """
        self._require_aligned("fuse_optical_flow")
        rate = np.asarray(los_rate_flu_rad_s, dtype=float).reshape(2)
        r = float(range_m)
        off = FusionResult(False, np.array([math.nan]), math.nan)
        if not (np.all(np.isfinite(rate)) and math.isfinite(r) and r > 0.0):
            return off, off
        results = []
        for axis in (0, 1):
            rot = quat_to_rotation_matrix(self._q)
            v = np.array(self._v)
            vb = rot.T @ v
            # measurement x: -v_b[1] / r; y: +v_b[0] / r
            sign, comp = (-1.0, 1) if axis == 0 else (1.0, 0)
            predicted = sign * float(vb[comp]) / r
            row = sign * rot.T[comp] / r                              # d / d v (world)
            vx = _skew(v)
            h = self._h_drag
            h[:] = 0.0
            h[3:6] = row
            h[6:9] = row @ vx
            var = noise_rad_s ** 2 + (predicted * range_std_m / r) ** 2
            results.append(self._update_scalar(float(rate[axis]) - predicted, h, var, gate_sd, None))
        return results[0], results[1]

    def fuse_zero_rate(self, mean_gyro_flu_rad_s, window_s: float) -> FusionResult:
        """The vehicle is at rest (on the ground, disarmed): the body x and y rates averaged over
        ``window_s`` are the gyro biases of those axes (zero-angular-rate update), noise
        ``gyro_noise_rad_s_per_rt_hz^2 / window_s``, gated like a velocity. Every state is corrected
        (the tilt too, through its correlation with the bias). The body z bias is left to the compass:
        a vehicle turned slowly on the ground (by hand, on a platform) really rotates about z, while
        on its landing gear it cannot keep rotating in roll or pitch.

        Why (issue 12): without horizontal aiding the climb dead-reckons, and a residual gyro bias eps
        tilts the estimate by eps t, which the controller flies as a real tilt: a drift of g eps t^3 / 6
        (38 m after a 30 s climb for the 0.85 mrad/s left by a 1 s average of a 0.5 mrad/s/rt-Hz
        gyro). Averaging at rest is the only way to learn eps before such a climb.
        """
        self._require_aligned("fuse_zero_rate")
        c = self._cfg
        w = float(window_s)
        rate = np.asarray(mean_gyro_flu_rad_s, dtype=float)[:2]
        innov = rate - np.array(self._bg[:2])
        if not (w > 0.0 and np.all(np.isfinite(innov))):
            return FusionResult(False, innov, float("inf"))
        var = c.gyro_noise_rad_s_per_rt_hz ** 2 / w
        return self._update_direct(innov, _GYRO_XY_BIAS_STATES, np.eye(2) * var, c.velocity_gate_sd, True)

    def gyro_bias_std_rad_s(self) -> np.ndarray:
        """1-sigma gyro bias uncertainty (body x, y, z), rad/s."""
        return np.sqrt(np.maximum(self._P[[9, 10, 11], [9, 10, 11]], 0.0))

    def gyro_bias_learned(self) -> bool:
        """The body x, y gyro biases are known to within ``learned_gyro_bias_ratio`` of the steady
        state of the zero-rate update at rest: a random walk of density q observed through white noise
        of density r settles at a 1-sigma of sqrt(q r)."""
        c = self._cfg
        limit = c.learned_gyro_bias_ratio * math.sqrt(c.gyro_noise_rad_s_per_rt_hz
                                                      * c.gyro_bias_noise_rad_s2_per_rt_hz)
        return bool(self.aligned and max(self._P[9, 9], self._P[10, 10]) <= limit * limit)

    def fuse_gps_position(self, pos_enu_m, std_m, age_s: float = 0.0) -> FusionResult:
        """GPS position (ENU m, the node converts lat/lon); only x, y are fused (height from the baro).

        ``std_m``: horizontal 1-sigma (scalar, or per-axis; the first two entries are used).
        Fused only when GPS is the position source; otherwise the result reports the innovation only.
        """
        self._require_aligned("fuse_gps_position")
        std = np.atleast_1d(np.asarray(std_m, dtype=float))
        sx = float(std[0])
        sy = float(std[1]) if std.size > 1 else sx
        floor = self._cfg.gps_position_noise_min_m
        R = np.diag([max(sx, floor) ** 2, max(sy, floor) ** 2])
        return self._fuse_horizontal_position(np.asarray(pos_enu_m, dtype=float)[:2], R, float(age_s),
                                              PositionSource.GPS)

    def fuse_gps_velocity(self, vel_enu_m_s, std_m_s) -> FusionResult:
        """GPS velocity (ENU m/s, 3-D); fused only while GPS is the position source."""
        self._require_aligned("fuse_gps_velocity")
        c = self._cfg
        std = np.broadcast_to(np.atleast_1d(np.asarray(std_m_s, dtype=float)), (3,))
        R = np.diag(np.maximum(std, c.gps_velocity_noise_min_m_s) ** 2)
        vel = np.asarray(vel_enu_m_s, dtype=float)[:3]
        innov = vel - np.array(self._v)
        selected = self._source == PositionSource.GPS
        result = self._update_direct(innov, _VEL_STATES, R, c.velocity_gate_sd, selected)
        if not selected:
            return result
        if result.accepted:
            self._vel_last_ok_s = self._time_s
        elif self._time_s - self._vel_last_ok_s > c.velocity_reject_timeout_s and np.all(np.isfinite(innov)):
            # A velocity the filter keeps rejecting usually means a wrong tilt (biases drift slowly): reset
            # the velocity onto GPS and re-open the tilt uncertainty so that the tilt is re-learnt (the
            # accel-bias uncertainty is left alone, else at rest the error splits between the two).
            P = self._P
            for i in range(3):
                self._v[i] = float(vel[i])
            for i in (3, 4, 5, 6, 7):
                P[i, :] = 0.0
                P[:, i] = 0.0
            for k, i in enumerate((3, 4, 5)):
                P[i, i] = R[k, k]
            P[6, 6] = P[7, 7] = 16.0 * (c.initial_tilt_std_rad ** 2
                                        + (c.initial_accel_bias_std_m_s2 / self._g) ** 2)
            self._velocity_reset_count += 1
            self._rev += 1
            self._vel_last_ok_s = self._time_s
            logger.warning("NavFilter: velocity reset to GPS (jump %.2f, %.2f, %.2f m/s)", *innov.tolist())
            return FusionResult(True, innov, result.test_ratio, reset=True)
        return result

    def fuse_vision_position(self, xy_enu_m, cov_2x2_m2, age_s: float = 0.0,
                             camera_height_m: float = 0.0) -> FusionResult:
        """Vision (scene-matching) fix: x, y (ENU m) with its 2x2 covariance (m^2).

        ``camera_height_m`` > 0: the fix came from a camera fixed to the body (looking along body
        down) whose image was aligned with this filter's roll and pitch from that height above the
        ground; its error then holds the filter's tilt error projected to the ground
        (``tilt_rows``), and the update corrects the tilt along with the position.
        Fused only when EXTNAV is the position source; otherwise the result reports the innovation only.
        """
        self._require_aligned("fuse_vision_position")
        h = float(camera_height_m)
        tilt = self.tilt_rows(h) if math.isfinite(h) and h > 0.0 else None
        return self._fuse_horizontal_position(np.asarray(xy_enu_m, dtype=float)[:2],
                                              self._vision_noise(cov_2x2_m2), float(age_s),
                                              PositionSource.EXTNAV, tilt)

    def _vision_noise(self, cov_2x2_m2) -> np.ndarray:
        """A vision fix's noise covariance: symmetrised, each variance at least
        ``vision_position_noise_min_m`` (or the ``set_vision_noise_floor``, the larger) squared."""
        cov = np.asarray(cov_2x2_m2, dtype=float).reshape(2, 2)
        R = 0.5 * (cov + cov.T)
        floor2 = max(self._cfg.vision_position_noise_min_m, self._vision_floor_m) ** 2
        R[0, 0] = max(R[0, 0], floor2)
        R[1, 1] = max(R[1, 1], floor2)
        return R

    def _moved_forward(self, xy: np.ndarray, R: np.ndarray, age_s: float) -> tuple[np.ndarray, np.ndarray]:
        """A horizontal fix measured ``age_s`` ago, moved forward to now with the estimated velocity;
        its covariance gains the velocity's uncertainty over that time."""
        if age_s > 0.0:
            xy = xy + np.array(self._v[:2]) * age_s
            R = R + self._P[3:5, 3:5] * (age_s * age_s)
        return xy, R

    def vision_test_ratio(self, xy_enu_m, cov_2x2_m2, gate_sd: float, age_s: float = 0.0) -> float:
        """The innovation test ratio (squared Mahalanobis distance over ``gate_sd`` squared) a vision
        fix with this covariance would have now; nothing changes."""
        self._require_aligned("vision_test_ratio")
        xy, R = self._moved_forward(np.asarray(xy_enu_m, dtype=float)[:2], self._vision_noise(cov_2x2_m2),
                                    float(age_s))
        innov = xy - np.array(self._p[:2])
        if not np.all(np.isfinite(innov)):
            return math.inf
        return self._update_direct(innov, _XY_STATES, R, float(gate_sd), False).test_ratio

    def tilt_rows(self, height_m: float) -> np.ndarray:
        """2 x 3: how a fix from a body-fixed downward camera, aligned with this filter's roll and
        pitch ``height_m`` above flat ground, moves with the attitude error (world frame, the error
        state: truth = exp(dtheta) * estimate). The image's centre ray d (body down) meets the ground
        at p + h f(d), f(d) = d_xy / -d_z; the node puts it at p + h f(d_est), so the fix is
        p + h J (d - d_est) = p - h J [d_est]x dtheta. The yaw column is zero: the node takes the
        heading from the compass and its own alignment (docs/perception.md), not from this filter."""
        d = -quat_to_rotation_matrix(self._q)[:, 2]
        if d[2] > -_MIN_DOWN_COMPONENT:
            return np.zeros((2, 3))
        inv = -1.0 / d[2]
        jac = np.array([[inv, 0.0, d[0] * inv * inv], [0.0, inv, d[1] * inv * inv]])
        rows = -float(height_m) * (jac @ _skew(d))
        rows[:, 2] = 0.0
        return rows

    def _fuse_horizontal_position(self, xy: np.ndarray, R: np.ndarray, age_s: float,
                                  source: PositionSource, tilt: np.ndarray | None = None) -> FusionResult:
        c = self._cfg
        xy, R = self._moved_forward(xy, R, age_s)
        innov = xy - np.array(self._p[:2])
        if not np.all(np.isfinite(innov)):
            return FusionResult(False, innov, float("inf"))
        selected = self._source == source
        if tilt is None:
            result = self._update_direct(innov, _XY_STATES, R, c.position_gate_sd, selected)
        else:
            H = np.zeros((2, NUM_ERROR_STATES))
            H[0, 0] = H[1, 1] = 1.0
            H[:, _ATT] = tilt
            result = self._update_rows(innov, H, R, c.position_gate_sd, selected)
        if not selected:
            return result
        if result.accepted:
            self._pos_last_ok_s = self._time_s
            return result
        if self._time_s - self._pos_last_ok_s > c.position_reject_timeout_s:
            elapsed = self._time_s - self._pos_last_ok_s
            limit = c.vision_reset_max_m
            if source == PositionSource.EXTNAV and limit > 0.0 and float(np.hypot(*innov)) > limit:
                # a jump no drift since the last accepted fix explains: a consistent false lock far
                # off is the likelier cause; keep rejecting, restart the timeout
                self._refused_reset_count += 1
                self._last_refused_reset_m = innov.copy()
                self._pos_last_ok_s = self._time_s
                return result
            self._reset_axes([0, 1], xy, R)
            self._reopen_horizontal_velocity(float(np.hypot(*innov)) / elapsed)
            self._position_reset_count += 1
            self._last_position_reset_m = innov.copy()
            self._pos_last_ok_s = self._time_s
            logger.warning("NavFilter: horizontal position reset to %s (jump %.1f m, %.1f m)", source.name,
                           float(innov[0]), float(innov[1]))
            return FusionResult(True, innov, result.test_ratio, reset=True)
        return result

    def _reopen_horizontal_velocity(self, speed_error_m_s: float) -> None:
        """After a position reset onto a source whose every fix was rejected: the position ran away
        from the fixes, so the horizontal velocity is suspect too. Decorrelate it and give it at least
        the variance of the run-away rate (jump / time since the last accepted fix), so that the next
        fixes correct the velocity instead of being gated out one reset after another."""
        P = self._P
        var = max(float(P[3, 3]), float(P[4, 4]), speed_error_m_s ** 2)
        for i in (3, 4):
            P[i, :] = 0.0
            P[:, i] = 0.0
            P[i, i] = var
        self._rev += 1

    def reset_horizontal_position(self, xy_enu_m, variance_m2: float) -> None:
        """Set x, y to a measurement (external nav reset_counter change), counted as a reset."""
        self._require_aligned("reset_horizontal_position")
        xy = np.asarray(xy_enu_m, dtype=float)[:2]
        jump = xy - np.array(self._p[:2])
        self._reset_axes([0, 1], xy, np.eye(2) * float(variance_m2))
        self._position_reset_count += 1
        self._last_position_reset_m = jump.copy()
        self._pos_last_ok_s = self._time_s

    def _reset_axes(self, axes: list[int], values: np.ndarray, R: np.ndarray) -> None:
        """Set position axes to a measurement: decorrelate them and give them the measurement variance."""
        self._rev += 1
        P = self._P
        for k, i in enumerate(axes):
            self._p[i] = float(values[k])
            P[i, :] = 0.0
            P[:, i] = 0.0
        for k, i in enumerate(axes):
            for m, j in enumerate(axes):
                P[i, j] = R[k, m]

    # ------------------------------------------------------------------ outputs
    def state(self) -> NavState:
        sqrt = math.sqrt
        d = [sqrt(x) if x > 0.0 else (x if x != x else 0.0) for x in self._P.diagonal()[:6].tolist()]
        return NavState(position_enu_m=np.array(self._p), velocity_enu_m_s=np.array(self._v),
                        q_wxyz=np.array(self._q), gyro_bias=np.array(self._bg), accel_bias=np.array(self._ba),
                        position_std_m=np.array(d[0:3]), velocity_std_m_s=np.array(d[3:6]),
                        heading_rad=heading_from_quat(self._q), wind_enu_m_s=np.array(self._wind),
                        compass_bias_rad=self._mag_bias)

    def position_std_m(self) -> np.ndarray:
        """1-sigma position uncertainty (x, y, z), m."""
        return np.sqrt(np.maximum(self._P[[0, 1, 2], [0, 1, 2]], 0.0))

    def covariance(self) -> np.ndarray:
        """Copy of the 18x18 error-state covariance (order: dp, dv, dtheta_world, db_g, db_a, dw, db_c)."""
        return self._P.copy()

    def attitude_std_rad(self) -> np.ndarray:
        """1-sigma attitude error about the world x, y, z axes (z is the heading uncertainty), rad."""
        return np.sqrt(np.maximum(self._P[[6, 7, 8], [6, 7, 8]], 0.0))

    def is_healthy(self) -> bool:
        """Aligned, finite, and the tilt uncertainty within ``healthy_max_tilt_std_rad``: the attitude is
        usable (STABILIZE / ALT_HOLD). Position and velocity quality: ``position_ok()``, ``velocity_ok()``."""
        if not self.aligned:
            return False
        if self._healthy_rev == self._rev:
            return self._healthy
        self._healthy_rev = self._rev
        self._healthy = self._compute_healthy()
        return self._healthy

    def _compute_healthy(self) -> bool:
        isfinite = math.isfinite
        if not (all(map(isfinite, self._p)) and all(map(isfinite, self._v)) and all(map(isfinite, self._q))
                and np.isfinite(self._P).all()):
            return False
        tilt_std = math.sqrt(max(self._P[6, 6] + self._P[7, 7], 0.0))
        return tilt_std <= self._cfg.healthy_max_tilt_std_rad

    def velocity_ok(self) -> bool:
        """Horizontal velocity good enough for velocity control (1-sigma <= velocity_ok_max_std_m_s)."""
        if not self.is_healthy():
            return False
        P = self._P
        return math.sqrt(max(P[3, 3], P[4, 4])) <= self._cfg.velocity_ok_max_std_m_s

    def position_ok(self) -> bool:
        """Horizontal position good enough for position control (1-sigma <= position_ok_max_std_m)."""
        if not self.is_healthy():
            return False
        P = self._P
        return math.sqrt(max(P[0, 0], P[1, 1])) <= self._cfg.position_ok_max_std_m

    @property
    def time_s(self) -> float:
        """Filter time: the sum of the predict steps since initialise."""
        return self._time_s

    @property
    def baro_offset_m(self) -> float:
        return self._baro_offset_m

    @property
    def position_reset_count(self) -> int:
        return self._position_reset_count

    @property
    def last_position_reset_m(self) -> np.ndarray:
        """xy jump (m) of the latest horizontal position reset (zero if none)."""
        return self._last_position_reset_m.copy()

    @property
    def refused_reset_count(self) -> int:
        """Vision position resets refused for a jump over ``vision_reset_max_m``."""
        return self._refused_reset_count

    @property
    def last_refused_reset_m(self) -> np.ndarray:
        """xy jump (m) of the latest refused reset (zero if none)."""
        return self._last_refused_reset_m.copy()

    @property
    def height_reset_count(self) -> int:
        return self._height_reset_count

    @property
    def heading_reset_count(self) -> int:
        return self._heading_reset_count

    @property
    def velocity_reset_count(self) -> int:
        return self._velocity_reset_count
