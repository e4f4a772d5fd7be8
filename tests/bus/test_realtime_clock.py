"""The simulator's realtime clock with a slow control-tick member (a real Zenoh session): physics
never runs a tick ahead of the autopilot's answer, and a machine too slow for the speed-up makes the
run fall behind the wall clock (reported once) instead of flying on stale motor commands."""

from __future__ import annotations

import threading
import time

import numpy as np

from scenenav.app.bench.sim import synthetic_world
from scenenav.core.bus import Bus, BusConfig, free_port
from scenenav.core.clock import ClockConfig
from scenenav.core.contracts import ClockMode, ClockTick, Event, LockstepAck, LockstepRole, MotorCommand
from scenenav.core.keys import Keys

ANSWER_DELAY_S = 0.03          # three tick periods at 100 Hz, 1x


def test_realtime_waits_for_a_slow_autopilot_and_reports_falling_behind():
    from sitl.config import SimNodeConfig
    from sitl.node import SimulatorNode
    from sitl.physics import hover_motor_command
    from sitl.vehicle import VehicleParams
    ns, port = f"rt-{int(time.time() * 1000) % 10**8}", free_port()
    cfg = SimNodeConfig(duration_s=0.5, expected_tick_members=1, expected_camera_members=0,
                        clock=ClockConfig(mode=ClockMode.REALTIME, speed_factor=1.0, tick_rate_hz=100.0))
    node = SimulatorNode(cfg, synthetic_world(256, 256), BusConfig(ns, port, listen_hub=True))
    node.core.start_at(np.array([0.0, 0.0, 100.0]), 0.0)
    keys = Keys(ns)
    member = Bus(BusConfig(ns, port))
    hover = float(np.mean(hover_motor_command(VehicleParams())))
    acked: list[int] = []
    ahead_of_answer: list[int] = []
    events: list[str] = []
    lock = threading.Lock()

    pending: list[ClockTick] = []
    more = threading.Condition(lock)
    done = threading.Event()

    def on_tick(m: ClockTick, _k: str) -> None:     # on arrival: was the previous tick answered?
        if m.state != "running":
            return
        with lock:
            if m.tick > (acked[-1] if acked else -1) + 1:
                ahead_of_answer.append(m.tick)
            pending.append(m)
            more.notify()

    def answer() -> None:                          # the slow autopilot: 30 ms per tick
        while not done.is_set():
            with lock:
                while not pending and not done.is_set():
                    more.wait(0.1)
                if done.is_set():
                    return
                m = pending.pop(0)
            time.sleep(ANSWER_DELAY_S)
            member.publish(keys.motors, MotorCommand(m.timestamp_us, m.tick, (hover,) * 4, True, "other"))
            with lock:
                acked.append(m.tick)
            member.publish(keys.lockstep_ack("slow-ap"),
                           LockstepAck(m.timestamp_us, "slow-ap", "tick", m.tick))

    worker = threading.Thread(target=answer, daemon=True)
    worker.start()
    member.subscribe(keys.clock, ClockTick, on_tick)
    member.subscribe(keys.events("sim"), Event, lambda e, _k: events.append(e.text))
    member.declare_token(keys.lockstep_member(LockstepRole.TICK, "slow-ap"))
    try:
        stats = node.run()
    finally:
        done.set()
        worker.join(5)
        node.close()
        member.close()
    assert stats.ticks == 51
    assert ahead_of_answer == [], f"ticks published before the previous answer: {ahead_of_answer[:5]}"
    assert stats.ack_timeouts == 0
    # 51 answers of 30 ms each: ~1.5 s of wall time for 0.5 simulated s
    assert stats.wall_time_s > 51 * ANSWER_DELAY_S * 0.9
    assert stats.realtime_lag_s > 0.5
    behind = [t for t in events if "fell behind" in t]
    assert len(behind) == 1, events
