"""Navigation filter (autopilot_bridge.ekf) on kinematic trajectories with noisy, biased sensors.

The truth here is kinematic: a prescribed acceleration profile and attitude; the IMU reports the
specific force R^T (a - g) and the body rate plus bias and white noise, at 100 Hz. Baro and compass at
20 Hz, GPS at 5 Hz, vision at 10 Hz.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot_bridge.config import EkfConfig, PositionSource
from autopilot_bridge.ekf import NavFilter
from scenenav.core.rotations import (
    aviation_euler_from_quat,
    heading_from_quat,
    quat_from_aviation_euler,
    quat_from_euler_zyx,
    quat_from_rotation_vector,
    quat_multiply,
    quat_to_rotation_matrix,
)

G = 9.80665
DT = 0.01
ACCEL_NOISE = 0.1
GYRO_NOISE = 0.003
ACCEL_BIAS = np.array([0.03, -0.02, 0.12])
GYRO_BIAS = np.array([0.004, -0.003, 0.002])


class KinematicTruth:
    """Truth integrated from an acceleration profile a(t) (ENU) and a body rate w(t) (FLU)."""

    def __init__(self, accel_fn, rate_fn, q0=(1.0, 0.0, 0.0, 0.0), p0=(0.0, 0.0, 0.0)):
        self.accel_fn = accel_fn
        self.rate_fn = rate_fn
        self.t = 0.0
        self.p = np.array(p0, dtype=float)
        self.v = np.zeros(3)
        self.q = tuple(q0)

    def step(self, rng: np.random.Generator):
        """Advance one IMU tick; return the (noisy, biased) tick-averaged IMU sample."""
        a = np.asarray(self.accel_fn(self.t), dtype=float)
        w = np.asarray(self.rate_fn(self.t), dtype=float)
        q_mid = quat_multiply(self.q, quat_from_rotation_vector(*(0.5 * DT * w)))
        r_mid = quat_to_rotation_matrix(q_mid)
        specific = r_mid.T @ (a + np.array([0.0, 0.0, G]))
        self.p = self.p + self.v * DT + 0.5 * a * DT * DT
        self.v = self.v + a * DT
        self.q = quat_multiply(self.q, quat_from_rotation_vector(*(DT * w)))
        self.t += DT
        accel = specific + ACCEL_BIAS + rng.normal(0.0, ACCEL_NOISE, 3)
        gyro = w + GYRO_BIAS + rng.normal(0.0, GYRO_NOISE, 3)
        return accel, gyro

    @property
    def heading(self) -> float:
        return heading_from_quat(self.q)


def _align(truth: KinematicTruth, rng, cfg=None, gps=True) -> NavFilter:
    """Average 1 s of samples at rest (truth must be at rest) and initialise."""
    samples = [truth.step(rng) for _ in range(100)]
    accel = np.mean([s[0] for s in samples], axis=0)
    gyro = np.mean([s[1] for s in samples], axis=0)
    nav = NavFilter(cfg)
    heading = truth.heading + rng.normal(0.0, 0.01)
    baro = truth.p[2] + float(np.mean(rng.normal(0.0, 0.3, 20)))
    gps_pos = truth.p + rng.normal(0.0, 0.5, 3) if gps else None
    nav.initialise(accel, heading, baro, gyro_flu_rad_s=gyro, gps_position_enu_m=gps_pos,
                   position_enu_m=None if gps else truth.p.copy())
    return nav


def _run(nav: NavFilter, truth: KinematicTruth, rng, seconds: float, *, gps=True, vision=False,
         vision_offset=(0.0, 0.0), vision_std=1.0, on_tick=None):
    """Run the filter for ``seconds``; return per-tick (truth p, est p, P_pos) history."""
    hist = []
    n = int(round(seconds / DT))
    for k in range(n):
        accel, gyro = truth.step(rng)
        nav.predict(accel, gyro, DT)
        tick = int(round(truth.t / DT))
        if tick % 5 == 0:
            nav.fuse_baro(truth.p[2] + rng.normal(0.0, 0.3))
            nav.fuse_compass((truth.heading + rng.normal(0.0, 0.01)) % (2 * math.pi))
        if gps and tick % 20 == 0:
            nav.fuse_gps_position(truth.p + rng.normal(0.0, 0.5, 3), 0.5)
            nav.fuse_gps_velocity(truth.v + rng.normal(0.0, 0.1, 3), 0.1)
        if vision and tick % 10 == 0:
            fix = truth.p[:2] + np.asarray(vision_offset) + rng.normal(0.0, vision_std, 2)
            nav.fuse_vision_position(fix, np.eye(2) * vision_std ** 2)
        if on_tick is not None:
            on_tick(k)
        hist.append((truth.p.copy(), truth.v.copy(), nav.state(), nav.covariance()))
    return hist


def _still(_t):
    return np.zeros(3)


# ----------------------------------------------------------------------------------------------

def test_quaternion_helpers_conventions():
    # Heading 0 = nose north; heading pi/2 = nose east.
    q = quat_from_aviation_euler(0.0, 0.0, 0.0)
    nose = quat_to_rotation_matrix(q) @ np.array([1.0, 0.0, 0.0])
    assert np.allclose(nose, [0.0, 1.0, 0.0], atol=1e-12)
    q = quat_from_aviation_euler(0.0, 0.0, math.pi / 2)
    assert np.allclose(quat_to_rotation_matrix(q) @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], atol=1e-12)
    # Nose up 10 deg: body x gains +z. Right wing down 10 deg: body y (left) gains +z.
    r = quat_to_rotation_matrix(quat_from_aviation_euler(0.0, math.radians(10.0), 0.0))
    assert r[2, 0] == pytest.approx(math.sin(math.radians(10.0)))
    r = quat_to_rotation_matrix(quat_from_aviation_euler(math.radians(10.0), 0.0, 0.0))
    assert r[2, 1] == pytest.approx(math.sin(math.radians(10.0)))
    roll, pitch, heading = aviation_euler_from_quat(quat_from_aviation_euler(0.1, -0.2, 4.0))
    assert (roll, pitch, heading) == pytest.approx((0.1, -0.2, 4.0))
    assert heading_from_quat(quat_from_euler_zyx(0.0, 0.0, 0.0)) == pytest.approx(math.pi / 2)


def test_initialise_levels_from_accel_and_compass():
    rng = np.random.default_rng(1)
    q0 = quat_from_aviation_euler(math.radians(5.0), math.radians(-3.0), math.radians(250.0))
    truth = KinematicTruth(_still, _still, q0=q0, p0=(10.0, -5.0, 0.0))
    nav = _align(truth, rng)
    roll, pitch, heading = aviation_euler_from_quat(nav.state().q_wxyz)
    # Accel bias (0.03, -0.02) m/s^2 appears as ~0.2 deg of tilt: unobservable at rest.
    assert math.degrees(roll) == pytest.approx(5.0, abs=0.4)
    assert math.degrees(pitch) == pytest.approx(-3.0, abs=0.4)
    assert math.degrees(heading) == pytest.approx(250.0, abs=1.5)
    assert nav.aligned and nav.is_healthy()


def test_stationary_with_noise_converges_and_stays_bounded():
    rng = np.random.default_rng(2)
    # Tilted and slowly yawing in place: exercises the attitude Jacobians.
    q0 = quat_from_aviation_euler(math.radians(8.0), math.radians(4.0), 1.0)
    truth = KinematicTruth(_still, lambda t: np.array([0.0, 0.0, 0.1]), q0=q0)
    nav = _align(truth, rng)
    hist = _run(nav, truth, rng, 60.0)
    p_err = np.array([np.linalg.norm(h[2].position_enu_m - h[0]) for h in hist[-1000:]])
    v_err = np.array([np.linalg.norm(h[2].velocity_enu_m_s - h[1]) for h in hist[-1000:]])
    assert p_err.max() < 1.0
    assert v_err.max() < 0.2
    state = hist[-1][2]
    hdg_err = (state.heading_rad - truth.heading + math.pi) % (2 * math.pi) - math.pi
    assert abs(math.degrees(hdg_err)) < 1.0
    # Gyro bias learned (the z bias through the compass, x/y through the tilt).
    assert np.allclose(state.gyro_bias, GYRO_BIAS, atol=1.5e-3)
    assert state.accel_bias[2] == pytest.approx(ACCEL_BIAS[2], abs=0.05)
    # Bounded: the position standard deviation is not growing.
    std_mid = hist[3000][2].position_std_m
    assert np.all(state.position_std_m <= std_mid * 1.05)
    assert np.all(state.position_std_m < 0.6)
    assert nav.is_healthy() and nav.position_ok()


def _accel_then_cruise(t):
    # 2 s at rest, 5 s at 1 m/s^2 north-east, then constant velocity (~7 m/s).
    if 2.0 <= t < 7.0:
        return np.array([1.0, 1.0, 0.1])
    return np.zeros(3)


def test_constant_velocity_with_gps_small_error_and_consistent_covariance():
    rng = np.random.default_rng(3)
    truth = KinematicTruth(_accel_then_cruise, _still, q0=quat_from_aviation_euler(0.0, 0.0, 0.7))
    nav = _align(truth, rng)
    hist = _run(nav, truth, rng, 70.0)
    cruise = hist[2000:]    # after 20 s (plus alignment)
    err = np.array([h[2].position_enu_m - h[0] for h in cruise])
    rms_xy = math.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1)))
    assert rms_xy < 0.5
    assert np.max(np.abs(err[:, 2])) < 1.0
    assert np.linalg.norm(cruise[-1][2].velocity_enu_m_s - cruise[-1][1]) < 0.2
    # NEES of the horizontal position: E[e' P^-1 e] = 2 for a consistent filter. Samples are strongly
    # correlated in time, so the bounds are wide; a badly over- or under-confident filter falls outside.
    nees = [float(e[:2] @ np.linalg.solve(h[3][:2, :2], e[:2])) for e, h in zip(err, cruise, strict=False)]
    mean_nees = float(np.mean(nees))
    assert 0.5 < mean_nees < 5.0, mean_nees


def test_gate_rejects_50m_outlier():
    rng = np.random.default_rng(4)
    truth = KinematicTruth(_still, _still)
    nav = _align(truth, rng)
    _run(nav, truth, rng, 20.0)
    before = nav.state().position_enu_m
    result = nav.fuse_gps_position(truth.p + np.array([50.0, 0.0, 0.0]), 0.5)
    assert not result.accepted
    assert result.test_ratio > 1.0
    assert result.innovation[0] == pytest.approx(50.0, abs=1.0)
    assert np.allclose(nav.state().position_enu_m, before)
    # A good fix passes with a small ratio.
    good = nav.fuse_gps_position(truth.p, 0.5)
    assert good.accepted and good.test_ratio < 1.0
    # Height and heading outliers too.
    assert not nav.fuse_baro(truth.p[2] + 30.0).accepted
    assert not nav.fuse_compass(truth.heading + 1.0).accepted


def test_dead_reckoning_covariance_grows():
    rng = np.random.default_rng(5)
    truth = KinematicTruth(_still, _still)
    nav = _align(truth, rng)
    _run(nav, truth, rng, 20.0)
    std0 = nav.position_std_m()[:2]
    stds = []
    hist = _run(nav, truth, rng, 30.0, gps=False,
                on_tick=lambda k: stds.append(nav.position_std_m()[:2].copy()) if k % 100 == 0 else None)
    stds = np.array(stds)
    assert np.all(np.diff(stds, axis=0) > 0.0)          # grows monotonically
    assert np.all(stds[-1] > 3.0 * std0)
    # The error stays within a few sigma of the (honest) covariance.
    err = hist[-1][2].position_enu_m[:2] - hist[-1][0][:2]
    assert np.all(np.abs(err) < 4.0 * stds[-1])
    assert nav.is_healthy()


def test_position_gate_follows_its_setting():
    """A fix 4 sigma off passes the default 5-sigma gate and not a 3-sigma one (EK3_POS_I_GATE 300)."""
    rng = np.random.default_rng(4)
    truth = KinematicTruth(_still, _still)
    nav = _align(truth, rng)
    _run(nav, truth, rng, 20.0)
    sd = math.sqrt(float(nav.covariance()[0, 0]) + 1.0)   # the innovation's, with R = 1 m^2
    probe = np.asarray(nav.state().position_enu_m[:2]) + np.array([4.0 * sd, 0.0])
    assert nav.vision_test_ratio(probe, np.eye(2), 5.0) == pytest.approx((4.0 / 5.0) ** 2, rel=0.05)
    nav.set_position_source(PositionSource.EXTNAV)
    nav.set_position_gate(3.0)
    tight = nav.fuse_vision_position(probe, np.eye(2))
    assert not tight.accepted and tight.test_ratio == pytest.approx((4.0 / 3.0) ** 2, rel=0.05)
    nav.set_position_gate(5.0)
    assert nav.fuse_vision_position(probe, np.eye(2)).accepted


def test_vision_noise_floor_weighs_a_narrow_fix_less():
    """VISO_POS_M_NSE floors each fix's 1-sigma: a fix stated at 0.5 m pulls the estimate less with
    a 2 m floor; a floor under the configured 0.3 m changes nothing."""
    def pull(floor_m: float) -> float:
        rng = np.random.default_rng(4)
        truth = KinematicTruth(_still, _still)
        nav = _align(truth, rng)
        _run(nav, truth, rng, 20.0)
        nav.set_position_source(PositionSource.EXTNAV)
        nav.set_vision_noise_floor(floor_m)
        before = np.asarray(nav.state().position_enu_m[:2], float)
        r = nav.fuse_vision_position(before + np.array([1.0, 0.0]), np.eye(2) * 0.25)
        assert r.accepted
        return float(nav.state().position_enu_m[0] - before[0])
    narrow, floored, below = pull(0.0), pull(2.0), pull(0.2)
    assert 0.0 < floored < 0.5 * narrow
    assert below == narrow


def test_source_switch_gps_to_extnav_is_continuous():
    rng = np.random.default_rng(6)
    truth = KinematicTruth(_accel_then_cruise, _still)
    nav = _align(truth, rng)
    _run(nav, truth, rng, 20.0, vision=True, vision_offset=(1.5, -1.0))
    # Vision fixes were evaluated but not fused while GPS was the source.
    assert nav.position_source == PositionSource.GPS
    assert not nav.fuse_vision_position(truth.p[:2], np.eye(2)).accepted
    nav.set_position_source(PositionSource.EXTNAV)
    # GPS is now ignored for position and velocity.
    assert not nav.fuse_gps_position(truth.p, 0.5).accepted
    assert not nav.fuse_gps_velocity(truth.v, 0.1).accepted
    prev_err = None
    max_step = 0.0
    hist = _run(nav, truth, rng, 30.0, gps=True, vision=True, vision_offset=(1.5, -1.0))
    for h in hist:
        e = h[2].position_enu_m[:2] - h[0][:2]
        if prev_err is not None:
            max_step = max(max_step, float(np.linalg.norm(e - prev_err)))
        prev_err = e
    # No jump: the estimate error changes by at most a few decimetres per tick...
    assert max_step < 0.3
    # ...and it has moved onto the vision frame (offset 1.5, -1.0).
    final = hist[-1][2].position_enu_m[:2] - hist[-1][0][:2]
    assert np.allclose(final, [1.5, -1.0], atol=0.8)
    assert nav.position_reset_count == 0


def test_extnav_rejected_for_too_long_resets_position():
    rng = np.random.default_rng(7)
    truth = KinematicTruth(_still, _still)
    cfg = EkfConfig(position_source=PositionSource.EXTNAV)
    nav = _align(truth, rng, cfg=cfg, gps=False)
    _run(nav, truth, rng, 10.0, gps=False, vision=True)
    hist = _run(nav, truth, rng, 8.0, gps=False, vision=True, vision_offset=(100.0, 0.0))
    assert nav.position_reset_count == 1
    assert nav.last_position_reset_m[0] == pytest.approx(100.0, abs=5.0)
    assert hist[-1][2].position_enu_m[0] - truth.p[0] == pytest.approx(100.0, abs=3.0)


def test_predict_before_initialise_is_an_error():
    with pytest.raises(RuntimeError):
        NavFilter().predict([0.0, 0.0, G], [0.0, 0.0, 0.0], DT)


def test_unobserved_tilt_step_recovers_through_velocity_reset():
    """The truth tilts 6 deg without the gyro seeing it (e.g. a hard landing model): the GPS velocity
    innovations grow past the gate, the rejection-timeout reset re-opens the tilt uncertainty and the
    filter re-learns the attitude instead of drifting away."""
    rng = np.random.default_rng(8)
    truth = KinematicTruth(_still, _still)
    nav = _align(truth, rng)
    _run(nav, truth, rng, 20.0)
    truth.q = quat_multiply(quat_from_rotation_vector(math.radians(6.0), 0.0, 0.0), truth.q)
    hist = _run(nav, truth, rng, 30.0)
    assert nav.velocity_reset_count >= 1
    est = quat_to_rotation_matrix(hist[-1][2].q_wxyz) @ [0.0, 0.0, 1.0]
    true_z = quat_to_rotation_matrix(truth.q) @ [0.0, 0.0, 1.0]
    assert math.degrees(math.acos(min(1.0, float(est @ true_z)))) < 1.0
    assert np.linalg.norm(hist[-1][2].velocity_enu_m_s - truth.v) < 0.3
    assert np.linalg.norm(hist[-1][2].position_enu_m[:2] - truth.p[:2]) < 2.0


def test_ext_nav_height_and_yaw_measured_earlier_are_moved_forward_to_now():
    """VISO_DELAY_MS for height and yaw: a value measured ``age_s`` ago is moved forward with the
    vertical velocity and the turn rate before it is compared with the state."""
    import copy
    rng = np.random.default_rng(4)
    climb, turn = 2.0, 0.2                                   # m/s up; rad/s counter-clockwise

    def accel(t):
        return np.array([0.0, 0.0, climb]) if 1.0 <= t < 2.0 else np.zeros(3)

    def rate(t):
        return np.array([0.0, 0.0, turn]) if t >= 2.0 else np.zeros(3)
    truth = KinematicTruth(accel, rate)
    nav = _align(truth, rng)
    _run(nav, truth, rng, 3.0)
    age = 0.3
    z_then = float(truth.p[2]) - climb * age
    heading_then = truth.heading + turn * age              # heading = pi/2 - yaw: it decreases
    innov = {}
    for a in (0.0, age):
        innov[a] = (float(copy.deepcopy(nav).fuse_ext_nav_height(z_then, 0.1, age_s=a).innovation[0]),
                    float(copy.deepcopy(nav).fuse_ext_nav_yaw(heading_then, 0.05, age_s=a).innovation[0]))
    assert innov[0.0][0] == pytest.approx(-climb * age, abs=0.25)      # on arrival: 0.6 m behind
    assert abs(innov[age][0]) < 0.25
    assert innov[0.0][1] == pytest.approx(turn * age, abs=0.03)
    assert abs(innov[age][1]) < 0.03


def test_zero_rate_at_rest_learns_the_horizontal_gyro_bias_and_rejects_motion():
    """Issue 12: at rest, the averaged body x, y rates are the gyro biases (``fuse_zero_rate``).
    Aligned with a bias 2 mrad/s off on x and y, 20 s of 0.2 s averages bring it within 0.25 mrad/s
    and ``gyro_bias_learned`` turns true; a vehicle that really turns is gated out."""
    rng = np.random.default_rng(12)
    truth = KinematicTruth(lambda _t: np.zeros(3), _still)
    samples = [truth.step(rng) for _ in range(100)]
    accel = np.mean([s[0] for s in samples], axis=0)
    gyro = np.mean([s[1] for s in samples], axis=0) + np.array([0.002, -0.002, 0.0])
    nav = NavFilter(EkfConfig(position_source=PositionSource.EXTNAV))
    nav.initialise(accel, truth.heading, truth.p[2], gyro_flu_rad_s=gyro, position_enu_m=truth.p.copy())
    assert not nav.gyro_bias_learned()
    fused = 0
    window = []
    for k in range(2000):
        a, w = truth.step(rng)
        nav.predict(a, w, DT)
        window.append(w)
        if len(window) == 20:
            fused += nav.fuse_zero_rate(np.mean(window, axis=0), 20 * DT).accepted
            window.clear()
        if k % 5 == 0:
            nav.fuse_baro(truth.p[2] + rng.normal(0.0, 0.3))
            nav.fuse_compass((truth.heading + rng.normal(0.0, 0.01)) % (2 * math.pi))
    assert fused == 100
    err = nav.state().gyro_bias[:2] - GYRO_BIAS[:2]
    assert np.all(np.abs(err) < 2.5e-4), err
    assert nav.gyro_bias_learned()
    assert np.all(nav.gyro_bias_std_rad_s()[:2] < 4e-4)
    # a real roll of 0.1 rad/s is no bias: rejected, the bias stays
    before = nav.state().gyro_bias.copy()
    r = nav.fuse_zero_rate(GYRO_BIAS + np.array([0.1, 0.0, 0.0]), 0.2)
    assert not r.accepted and r.test_ratio > 1.0
    assert np.array_equal(nav.state().gyro_bias, before)


def test_lower_gyro_bias_process_noise_keeps_the_bias_learnt_at_rest_tighter():
    """``set_gyro_bias_noise`` (EK3_GBIAS_P_NSE): with a 10x lower bias random walk the zero-rate
    update at rest settles to a smaller bias uncertainty (sqrt(q r)), the learnt threshold follows,
    and the uncertainty then grows more slowly in flight without aiding."""
    from autopilot_bridge.param_binding import gyro_bias_noise_density
    assert gyro_bias_noise_density(1.0e-3) == pytest.approx(EkfConfig().gyro_bias_noise_rad_s2_per_rt_hz)
    stds = []
    for p_nse in (1.0e-3, 1.0e-4):
        rng = np.random.default_rng(3)
        truth = KinematicTruth(lambda _t: np.zeros(3), _still)
        samples = [truth.step(rng) for _ in range(100)]
        nav = NavFilter(EkfConfig(position_source=PositionSource.EXTNAV))
        nav.initialise(np.mean([s[0] for s in samples], axis=0), truth.heading, truth.p[2],
                       gyro_flu_rad_s=np.mean([s[1] for s in samples], axis=0),
                       position_enu_m=truth.p.copy())
        nav.set_gyro_bias_noise(gyro_bias_noise_density(p_nse))
        window = []
        for _ in range(10000):    # 100 s at rest: the lower noise settles more slowly
            a, w = truth.step(rng)
            nav.predict(a, w, DT)
            window.append(w)
            if len(window) == 20:
                nav.fuse_zero_rate(np.mean(window, axis=0), 20 * DT)
                window.clear()
        at_rest = float(nav.gyro_bias_std_rad_s()[0])
        assert nav.gyro_bias_learned()
        for _ in range(3000):     # 30 s without any aiding
            a, w = truth.step(rng)
            nav.predict(a, w, DT)
        stds.append((at_rest, float(nav.gyro_bias_std_rad_s()[0])))
    (rest_hi, later_hi), (rest_lo, later_lo) = stds
    assert rest_lo < 0.5 * rest_hi
    assert later_lo - rest_lo < 0.2 * (later_hi - rest_hi)


def _ground_offset(q, height_m: float) -> np.ndarray:
    """Where the body-down ray of attitude ``q`` meets flat ground ``height_m`` below, from the
    nadir (ENU m)."""
    d = -quat_to_rotation_matrix(q)[:, 2]
    return height_m * d[:2] / -d[2]


def test_tilt_rows_are_the_derivative_of_the_camera_ray_on_the_ground():
    """A fix from a camera on the body, aligned with the filter's attitude: it moves by
    ``tilt_rows(h) @ dtheta`` when the truth is the estimate turned by a small dtheta (world
    frame), pitched 20 deg and banked 5 deg as in a gusty cruise; a yaw error moves nothing."""
    rng = np.random.default_rng(3)
    nav = _align(KinematicTruth(_still, _still), rng)
    nav._q = np.array(quat_from_aviation_euler(math.radians(5.0), math.radians(-20.0), 1.1))
    h = 100.0
    rows = nav.tilt_rows(h)
    for dtheta in ([1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [-6e-5, 8e-5, 0.0]):
        q_true = quat_multiply(quat_from_rotation_vector(*dtheta), nav._q)
        # the node puts the true ray's ground point where the estimated ray would meet the ground
        moved = _ground_offset(q_true, h) - _ground_offset(nav._q, h)
        assert np.allclose(rows @ np.asarray(dtheta), moved, rtol=0.02, atol=1e-6), (dtheta, moved)
        assert np.linalg.norm(moved) > 0.005
    assert not np.any(rows[:, 2])     # the node's heading is not the filter's


def _hover_on_tilted_fixes(model_tilt: bool) -> tuple[float, float]:
    """30 s hovering 100 m up, the filter started 1.5 deg off in roll, vision fixes at 10 Hz from a
    downward camera aligned with the filter's tilt (each off by the tilt error times the height).
    Returns the position error RMS of the last 10 s (m) and the final tilt error (deg)."""
    rng = np.random.default_rng(11)
    truth = KinematicTruth(_still, _still, p0=(0.0, 0.0, 100.0))
    nav = _align(truth, rng, gps=False)
    nav.set_position_source(PositionSource.EXTNAV)
    nav._q = np.array(quat_multiply(quat_from_rotation_vector(math.radians(1.5), 0.0, 0.0), nav._q))
    h = 100.0
    errors = []
    for k in range(3000):
        accel, gyro = truth.step(rng)
        nav.predict(accel, gyro, DT)
        if k % 5 == 0:
            nav.fuse_baro(truth.p[2] + rng.normal(0.0, 0.3))
            nav.fuse_compass((truth.heading + rng.normal(0.0, 0.01)) % (2 * math.pi))
        if k % 10 == 0:
            est_q = nav.state().q_wxyz
            fix = truth.p[:2] + _ground_offset(truth.q, h) - _ground_offset(est_q, h) + rng.normal(0.0, 1.0, 2)
            nav.fuse_vision_position(fix, np.eye(2), camera_height_m=h if model_tilt else 0.0)
        errors.append(np.linalg.norm(nav.state().position_enu_m[:2] - truth.p[:2]))
    est_up = quat_to_rotation_matrix(nav.state().q_wxyz) @ [0.0, 0.0, 1.0]
    true_up = quat_to_rotation_matrix(truth.q) @ [0.0, 0.0, 1.0]
    return (float(np.sqrt(np.mean(np.square(errors[-1000:])))),
            math.degrees(math.acos(min(1.0, float(est_up @ true_up)))))


def test_fixes_aligned_with_the_filters_tilt_error():
    """Fused as a position alone, fixes that carry the filter's own tilt error (times the height)
    feed it back: the estimate follows them and the tilt error grows (seen: 12.6 m, 4.8 deg). With
    the tilt rows (camera_height_m) the filter explains them by its tilt and stays near the truth
    (seen: 3.5 m, 1.4 deg)."""
    plain_m, plain_deg = _hover_on_tilted_fixes(False)
    tilt_m, tilt_deg = _hover_on_tilted_fixes(True)
    assert tilt_m < 0.5 * plain_m, (tilt_m, plain_m)
    assert tilt_deg < 1.6 < plain_deg, (tilt_deg, plain_deg)
