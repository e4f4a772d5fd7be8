"""The guidance node against a real MAVLink server (in-memory vehicle) over a real Zenoh bus:
start sequence, replan on drift, replan when the assistant map file changes."""

from __future__ import annotations

import json
import os
import threading
import time
import uuid

import numpy as np
import pytest
from support.fake_vehicle import running_server

from guidance.config import GuidanceRunConfig, PlannerConfig, RouteEnd
from guidance.node import GuidanceNode
from scenenav.core.bus import Bus, BusConfig, free_port
from scenenav.core.contracts import ClockMode, ClockTick, NavEstimate, RunState
from scenenav.core.formats.world_manifest import WorldManifest
from scenenav.core.frames import pixel_to_world
from scenenav.core.keys import Keys

M_PER_PX = 2.0
SIZE_PX = 300
START, GOAL = (-250.0, 0.0), (250.0, 0.0)


def lake_map(r_m: float = 80.0, cx_m: float = 0.0) -> np.ndarray:
    prob = np.full((SIZE_PX, SIZE_PX), 0.9, dtype=np.float32)
    v, u = np.mgrid[0:SIZE_PX, 0:SIZE_PX]
    x, y = pixel_to_world(u + 0.5, v + 0.5, SIZE_PX, SIZE_PX, M_PER_PX)
    prob[np.hypot(x - cx_m, y) <= r_m] = 0.1
    return prob


def wait_until(pred, timeout_s: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.05)
    return False


@pytest.fixture
def setup(tmp_path):
    map_path = tmp_path / "map.npz"
    np.savez(map_path, probability=lake_map())
    ns = f"t{uuid.uuid4().hex[:8]}"
    hub = Bus(BusConfig(ns, free_port(), listen_hub=True))
    world = WorldManifest(1, "lakeworld", SIZE_PX, SIZE_PX, M_PER_PX, 48.0, 11.0, "generated", None,
                          False, False)
    with running_server() as (server, vehicle):
        cfg = GuidanceRunConfig(start_enu_m=START, goals_enu_m=(GOAL,), assistant_map=str(map_path),
                                 altitude_m=100.0, end=RouteEnd.LAND, replan_drift_m=40.0,
                                 check_period_s=1.0, start_after_s=1.0,
                                 mavlink_url=f"tcp:127.0.0.1:{server.tcp_port}", lockstep=False)
        node = GuidanceNode(world, BusConfig(ns, hub.cfg.hub_port), cfg,
                            PlannerConfig(footprint_m=0.0, clearance_m=10.0, unvisited_weight=0.0),
                            out_dir=tmp_path)
        thread = threading.Thread(target=node.run, daemon=True)
        thread.start()
        try:
            yield {"hub": hub, "keys": Keys(ns), "node": node, "vehicle": vehicle, "map": map_path,
                   "dir": tmp_path}
        finally:
            node.stop()
            thread.join(timeout=10)
            node.close()
            hub.close()


def tick(s, t_s: float, est_xy: tuple[float, float] | None = None) -> None:
    t_us = int(t_s * 1e6)
    if est_xy is not None:
        s["hub"].publish(s["keys"].nav_estimate, NavEstimate(
            t_us, (est_xy[0], est_xy[1], 100.0), (10.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 0.0,
            (1.0, 1.0, 1.0), 6, "perception"))
        time.sleep(0.2)
    s["hub"].publish(s["keys"].clock, ClockTick(t_us, int(t_s * 100), 10000, -1,
                                                ClockMode.REALTIME.value, RunState.RUNNING.value))


def missions(vehicle) -> list[int]:
    return [c[1][0] for c in list(vehicle.calls) if c[0] == "mission_changed"]


def test_start_then_replan_on_drift_and_on_map_change(setup):
    s = setup
    v = s["vehicle"]
    assert wait_until(lambda: s["hub"].session is not None)
    time.sleep(1.0)                                   # the node's session joins the hub
    tick(s, 0.5)
    time.sleep(0.5)
    assert missions(v) == []                          # before start_after_s nothing happens
    tick(s, 1.0)
    assert wait_until(lambda: s["node"].phase.value == "flying"), v.calls
    names = [c[0] for c in v.calls]
    assert names.index("mission_changed") < names.index("arm") < names.index("start_mission")
    first = json.loads((s["dir"] / "route.json").read_text())
    assert first["route_bad_fraction"] == [0.0] and first["straight_line_bad_fraction"][0] > 0.2
    n_items = missions(v)[0]
    assert n_items == len(first["waypoints"]) + 1      # take-off + waypoints[1:] + land (home apart)

    # on the route: no replan
    on_route = (first["waypoints"][2]["x_m"], first["waypoints"][2]["y_m"])
    tick(s, 3.0, on_route)
    time.sleep(1.0)
    assert len(missions(v)) == 1

    # blown 100 m off the route: replan from the estimate to the goal
    here = (-150.0, -170.0)
    tick(s, 5.0, here)
    assert wait_until(lambda: len(missions(v)) == 2), v.calls
    second = json.loads((s["dir"] / "route-1.json").read_text())
    assert second["waypoints"][0]["x_m"] == pytest.approx(here[0])
    assert second["waypoints"][-1]["x_m"] == pytest.approx(GOAL[0])
    assert wait_until(lambda: any(c[0] == "set_current_mission_item" for c in list(v.calls))), v.calls

    # the map changes under the route: a new lake where the vehicle heads; replan again
    np.savez(s["map"], probability=lake_map(r_m=60.0, cx_m=150.0))
    os.utime(s["map"], (time.time() + 5, time.time() + 5))
    tick(s, 7.0, (second["waypoints"][1]["x_m"], second["waypoints"][1]["y_m"]))
    assert wait_until(lambda: len(missions(v)) == 3), v.calls
    third = json.loads((s["dir"] / "route-2.json").read_text())
    assert third["route_bad_fraction"] == [0.0]
    assert wait_until(lambda: s["node"].stats["replans"] == 2)    # counted once AUTO is re-sent
    assert s["node"].stats["replan_failures"] == 0
