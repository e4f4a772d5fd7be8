"""``clock.camera_answer_ticks``: the simulator waits for a camera member's answer N ticks after the
frame went out (real Zenoh sessions), so ``ClockTick.camera_seq_acked`` names a frame first at the
tick N + 1 after its publication; the tick's sensors and clock go out before its frame and truth."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from scenenav.app.bench.sim import synthetic_world
from scenenav.core.bus import Bus, BusConfig, free_port
from scenenav.core.clock import ClockConfig
from scenenav.core.config import ConfigError
from scenenav.core.contracts import (
    CameraFrame,
    ClockTick,
    ImuSample,
    LockstepAck,
    LockstepRole,
    MotorCommand,
    TruthPose,
)
from scenenav.core.keys import Keys

LATENCY_TICKS = 5           # sim.camera.latency_s 0.05 s at 100 Hz


def _fly(answer_ticks: int) -> tuple[dict[int, int], list[str]]:
    """{frame seq: first tick whose ClockTick.camera_seq_acked covers it}, and the order of the keys
    the members saw (one session each, direct callbacks: publication order)."""
    from sitl.config import SimNodeConfig
    from sitl.node import SimulatorNode
    from sitl.physics import hover_motor_command
    from sitl.vehicle import VehicleParams
    ns, port = f"cat-{answer_ticks}-{int(time.time() * 1000) % 10**8}", free_port()
    cfg = SimNodeConfig(duration_s=0.6, expected_tick_members=1, expected_camera_members=1,
                        clock=ClockConfig(camera_answer_ticks=answer_ticks))
    node = SimulatorNode(cfg, synthetic_world(256, 256), BusConfig(ns, port, listen_hub=True))
    node.core.start_at(np.array([0.0, 0.0, 100.0]), 0.0)
    keys = Keys(ns)
    member = Bus(BusConfig(ns, port))
    hover = float(np.mean(hover_motor_command(VehicleParams())))
    covered: dict[int, int] = {}
    seen: list[str] = []
    lock = threading.Lock()

    def on_tick(m: ClockTick, _k: str) -> None:
        with lock:
            seen.append(f"clock {m.tick}")
            if m.state == "running":
                for seq in range(m.camera_seq_acked + 1):
                    covered.setdefault(seq, m.tick)
        member.publish(keys.motors, MotorCommand(m.timestamp_us, m.tick, (hover,) * 4, True, "ap"))

    def on_frame(m: CameraFrame, _k: str) -> None:
        with lock:
            seen.append(f"camera {m.timestamp_us // 10_000 + LATENCY_TICKS}")
        member.publish(keys.lockstep_ack("cam"), LockstepAck(m.timestamp_us, "cam", "camera", m.seq))

    def on_other(name: str):
        def handler(m, _k: str) -> None:
            with lock:
                seen.append(f"{name} {m.timestamp_us // 10_000}")
        return handler

    member.subscribe(keys.clock, ClockTick, on_tick)
    member.subscribe(keys.camera, CameraFrame, on_frame)
    member.subscribe(keys.imu, ImuSample, on_other("imu"))
    member.subscribe(keys.truth_pose, TruthPose, on_other("truth"))
    member.declare_token(keys.lockstep_member(LockstepRole.TICK, "ap"))
    member.declare_token(keys.lockstep_member(LockstepRole.CAMERA, "cam"))
    try:
        stats = node.run()
    finally:
        node.close()
        member.close()
    assert stats.ack_timeouts == 0
    assert stats.camera_frames >= 5
    return covered, seen


@pytest.mark.parametrize("answer_ticks", [0, 3])
def test_a_frame_is_covered_answer_ticks_plus_one_after_it_went_out(answer_ticks):
    covered, seen = _fly(answer_ticks)
    published = {seq: seq * 10 + LATENCY_TICKS for seq in range(6)}   # 10 Hz frames, 5 ticks late
    assert {seq: covered[seq] for seq in published if seq in covered} == \
        {seq: tick + answer_ticks + 1 for seq, tick in published.items() if seq in covered}
    assert len([s for s in published if s in covered]) >= 5
    # per tick: the IMU sample, then the clock, then the truth and (on a release tick) the frame
    for tick in (5, 15, 25):
        i_imu, i_clock = seen.index(f"imu {tick}"), seen.index(f"clock {tick}")
        assert i_imu < i_clock < seen.index(f"truth {tick}")
        assert i_clock < seen.index(f"camera {tick}")


def test_answer_ticks_must_be_fewer_than_the_ticks_between_frames():
    from sitl.config import SimNodeConfig
    SimNodeConfig(clock=ClockConfig(camera_answer_ticks=9))
    with pytest.raises(ConfigError, match="camera_answer_ticks"):
        SimNodeConfig(clock=ClockConfig(camera_answer_ticks=10))
    with pytest.raises(ConfigError, match="camera_answer_ticks"):
        ClockConfig(camera_answer_ticks=-1)
