"""SimulatorCore: one tick returns the samples due at it; the same seed gives the same outputs."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from scenenav.core.contracts import CameraFrame
from sitl.config import BatteryConfig, GpsConfig, ScriptedFlight, SimConfig, WindConfig
from sitl.core import SimulatorCore, TickOutput
from sitl.physics import hover_motor_command

ORIGIN = (47.397742, 8.545594)
TICK_HZ = 100.0


def _core(seed: int = 3, sim: SimConfig | None = None) -> SimulatorCore:
    core = SimulatorCore(sim or SimConfig(wind=WindConfig((1.0, -2.0, 0.0), 0.5)), TICK_HZ, seed, *ORIGIN)
    core.start_at(np.array([0.0, 0.0, 30.0]), 0.3, np.full(4, core.params.hover_rotor_speed_rad_s))
    return core


def _fly(core: SimulatorCore, ticks: int) -> list[TickOutput]:
    hover = hover_motor_command(core.params)
    outs = []
    for _ in range(ticks):
        outs.append(core.sense())
        core.advance(hover)
    return outs


def _published(out: TickOutput) -> tuple:
    return (out.truth, out.imu, out.baro, out.compass, out.gps, out.power,
            None if out.camera_request is None else (out.camera_request.seq, out.camera_request.capture_us,
                                                     tuple(out.camera_request.position_enu_m)),
            out.camera_release)


def test_one_tick_returns_what_is_due():
    core = _core()
    try:
        outs = _fly(core, 21)
    finally:
        core.close()
    first = outs[0]
    assert first.tick == 0 and first.timestamp_us == 0
    assert first.baro is not None and first.compass is not None and first.gps is not None
    assert first.power is not None and first.camera_request is not None and first.camera_request.seq == 0
    assert first.camera_release is None                  # 50 ms capture latency: 5 ticks later
    one = outs[1]
    assert one.timestamp_us == 10_000 and one.imu.tick == 1 and one.imu.dt_s == pytest.approx(0.01)
    assert (one.baro, one.compass, one.gps, one.power, one.camera_request, one.camera_release) == (None,) * 6
    assert outs[5].baro is not None and outs[5].compass is not None and outs[5].gps is None
    assert outs[5].camera_release is not None and outs[5].camera_release.seq == 0
    assert outs[5].camera_release.capture_us == 0
    assert outs[10].power is not None and outs[10].camera_request.seq == 1
    assert outs[20].gps is not None
    assert sum(o.gps is not None for o in outs) == 2       # 5 Hz
    # hovering: the truth stays near the start, the accelerometer reads about +g on body z
    assert np.allclose(outs[-1].truth.position_enu_m, (0.0, 0.0, 30.0), atol=0.2)
    assert outs[-1].imu.accel_flu_m_s2[2] == pytest.approx(9.80665, abs=0.3)


def test_same_seed_same_outputs_other_seed_other_noise():
    a, b, c = _core(seed=5), _core(seed=5), _core(seed=6)
    try:
        out_a, out_b, out_c = _fly(a, 60), _fly(b, 60), _fly(c, 60)
    finally:
        for core in (a, b, c):
            core.close()
    assert [_published(o) for o in out_a] == [_published(o) for o in out_b]
    assert out_a[10].imu != out_c[10].imu


def test_gps_off_publishes_no_fix():
    core = _core(sim=SimConfig(gps=GpsConfig(enabled=False)))
    try:
        assert all(o.gps is None for o in _fly(core, 25))
    finally:
        core.close()


def test_battery_does_not_change_the_truth_and_sags_under_load():
    plain = _core(seed=2)
    noisy_small = _core(seed=2, sim=SimConfig(wind=WindConfig((1.0, -2.0, 0.0), 0.5),
                                              battery=BatteryConfig(capacity_mah=500.0, voltage_noise_std_v=0.05,
                                                                    current_noise_std_a=0.2)))
    try:
        a, b = _fly(plain, 120), _fly(noisy_small, 120)
    finally:
        plain.close()
        noisy_small.close()
    assert [o.truth for o in a] == [o.truth for o in b]
    assert [o.imu for o in a] == [o.imu for o in b]
    power = [o.power for o in a if o.power is not None]
    assert len(power) == 12                                   # 10 Hz
    assert 18.0 < power[-1].current_a < 25.0                  # hover: about 21 A
    cells_full = 3 * 4.173
    assert power[-1].voltage_v == pytest.approx(cells_full - 0.01 * power[-1].current_a, abs=0.01)
    assert power[-1].voltage_v < power[1].voltage_v          # charge drawn
    noisy = [o.power for o in b if o.power is not None]
    assert noisy[-1] != power[-1]


def test_scripted_flight_follows_the_route_and_ignores_motors():
    core = SimulatorCore(SimConfig(), TICK_HZ, 0, *ORIGIN)
    core.start_scripted(ScriptedFlight(((0.0, 0.0), (20.0, 0.0)), altitude_m=50.0, speed_m_s=10.0))
    try:
        outs = []
        while not core.route_complete:
            outs.append(core.sense())
            core.advance(np.ones(4))                         # ignored
        assert len(outs) == 201                               # 2 s at 100 Hz, both ends included
        assert outs[100].truth.position_enu_m == pytest.approx((10.0, 0.0, 50.0))
        assert outs[100].truth.heading_rad == pytest.approx(math.pi / 2.0)     # flying east
        assert outs[100].imu.accel_flu_m_s2[2] == pytest.approx(9.80665, abs=0.3)
    finally:
        core.close()


def test_camera_frame_applies_the_effects():
    sim = SimConfig()
    sim = dataclasses.replace(sim, camera=dataclasses.replace(sim.camera, noise_std=5.0, latency_s=0.0))
    core = _core(sim=sim)
    try:
        out = core.sense()
        assert out.camera_release is not None and out.camera_release.seq == 0   # no latency
        image = np.full((sim.camera.height_px, sim.camera.width_px, 3), 100, dtype=np.uint8)
        frame = core.camera_frame(out.camera_release, image)
    finally:
        core.close()
    assert isinstance(frame, CameraFrame)
    assert frame.fov_deg == sim.camera.fov_deg and frame.width_px == sim.camera.width_px
    assert frame.timestamp_us == 0 and not np.array_equal(frame.pixels, image)
