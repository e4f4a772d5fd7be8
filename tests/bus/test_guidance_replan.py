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

from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from guidance.config import GuidanceRunConfig, PlannerConfig, RouteEnd
from guidance.node import GuidanceNode
from scenenav.core.bus import Bus, BusConfig, free_port
from scenenav.core.contracts import ClockMode, ClockTick, LockstepAck, NavEstimate, RunState
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
    yield from running_guidance(tmp_path, lockstep=False)


@pytest.fixture
def lockstep_setup(tmp_path):
    yield from running_guidance(tmp_path, lockstep=True)


def running_guidance(tmp_path, lockstep: bool):
    map_path = tmp_path / "map.npz"
    np.savez(map_path, probability=lake_map())
    ns = f"t{uuid.uuid4().hex[:8]}"
    hub = Bus(BusConfig(ns, free_port(), listen_hub=True))
    world = WorldManifest(1, "lakeworld", SIZE_PX, SIZE_PX, M_PER_PX, 48.0, 11.0, "generated", None,
                          False, False)
    with running_server(params=ParameterStore(PARAM_SPECS)) as (server, vehicle):
        cfg = GuidanceRunConfig(start_enu_m=START, goals_enu_m=(GOAL,), assistant_map=str(map_path),
                                 altitude_m=100.0, end=RouteEnd.LAND, replan_drift_m=40.0,
                                 check_period_s=1.0, start_after_s=1.0,
                                 mavlink_url=f"tcp:127.0.0.1:{server.tcp_port}", lockstep=lockstep)
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


def estimate(s, t_s: float, est_xy: tuple[float, float]) -> None:
    s["hub"].publish(s["keys"].nav_estimate, NavEstimate(
        int(round(t_s * 1e6)), (est_xy[0], est_xy[1], 100.0), (10.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 0.0,
        (1.0, 1.0, 1.0), 6, "perception"))


def tick(s, t_s: float, est_xy: tuple[float, float] | None = None,
         mode: ClockMode = ClockMode.REALTIME) -> None:
    if est_xy is not None:
        estimate(s, t_s, est_xy)
        time.sleep(0.2)
    s["hub"].publish(s["keys"].clock, ClockTick(int(round(t_s * 1e6)), int(round(t_s * 100)), 10000, -1,
                                                mode.value, RunState.RUNNING.value))


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


def test_routes_stay_inside_the_autopilots_geofence(setup):
    """The node downloads the fence (mission_type FENCE) and FENCE_*: an inclusion polygon that
    leaves only the way south of the lake, an exclusion circle on that way; the route keeps
    FENCE_MARGIN inside, the cruise altitude FENCE_MARGIN below FENCE_ALT_MAX."""
    from support.fake_vehicle import gcs_connection, wait_for

    from guidance.fence import Fence, FenceCommand, distance_to_edges_m
    from scenenav.core.frames import enu_to_geodetic
    s = setup
    server = s["node"].cfg.mavlink_url
    port = int(server.rsplit(":", 1)[1])
    rect = [(-290.0, -220.0), (290.0, -220.0), (290.0, 40.0), (-290.0, 40.0)]
    lat, lon = enu_to_geodetic(np.array([p[0] for p in rect]), np.array([p[1] for p in rect]), 48.0, 11.0)
    clat, clon = enu_to_geodetic(0.0, -120.0, 48.0, 11.0)
    items = [(FenceCommand.POLYGON_VERTEX_INCLUSION, 4.0, float(a), float(o)) for a, o in zip(lat, lon, strict=True)]
    items.append((FenceCommand.CIRCLE_EXCLUSION, 20.0, float(clat), float(clon)))
    conn = gcs_connection(port)
    for name, value in (("FENCE_ENABLE", 1), ("FENCE_TYPE", 5), ("FENCE_MARGIN", 5.0), ("FENCE_ALT_MAX", 60.0)):
        conn.mav.param_set_send(1, 1, name.encode(), value, 9)
        assert wait_for(conn, "PARAM_VALUE", 5.0, lambda m, n=name: m.param_id == n) is not None
    conn.mav.mission_count_send(1, 1, len(items), 1)
    while True:
        req = wait_for(conn, ["MISSION_REQUEST_INT", "MISSION_ACK"], 5.0)
        assert req is not None
        if req.get_type() == "MISSION_ACK":
            assert req.type == 0
            break
        cmd, p1, a, o = items[req.seq]
        conn.mav.mission_item_int_send(1, 1, req.seq, 0, cmd, 0, 1, p1, 0, 0, 0, int(a * 1e7), int(o * 1e7), 0, 1)
    conn.close()
    assert wait_until(lambda: s["hub"].session is not None)
    time.sleep(1.0)
    tick(s, 1.0)
    assert wait_until(lambda: s["node"].phase.value == "flying"), s["vehicle"].calls
    fence: Fence = s["node"].fence
    assert len(fence.inclusion_polygons) == 1 and len(fence.exclusion_circles) == 1
    route = json.loads((s["dir"] / "route.json").read_text())
    pts = np.array([[w["x_m"], w["y_m"]] for w in route["waypoints"]])
    dense = np.concatenate([np.linspace(a, b, 30) for a, b in zip(pts[:-1], pts[1:], strict=False)])
    assert fence.allowed(dense).all()
    assert dense[:, 1].max() < 40.0 - 5.0 + 1e-6                 # the north way is outside the fence
    assert distance_to_edges_m(dense, fence.inclusion_polygons[0]).min() >= 5.0 - 1e-6
    assert np.hypot(dense[:, 0], dense[:, 1] + 120.0).min() >= 25.0 - 1e-6
    assert s["node"].altitude_m() == pytest.approx(55.0)         # FENCE_ALT_MAX - FENCE_MARGIN


def test_in_lockstep_the_node_holds_the_clock_through_start_and_replans(lockstep_setup):
    """In lockstep the node stays a tick member in flight. Each ack answers ahead through the tick
    before the next start try or check (ticks at 100 Hz, checks every simulated second), so the
    ticks between send nothing; the ack of a tick whose check replans comes only after the new
    mission is uploaded (the replan lands at a fixed simulated time); the check uses the estimate of
    the tick's time even when a later one has already arrived (the links race)."""
    s = setup = lockstep_setup
    v = s["vehicle"]
    acks: list[int] = []
    uploaded: dict[int, int] = {}                   # ack seq -> missions uploaded when it arrived

    def on_ack(msg: LockstepAck, _k: str) -> None:
        uploaded[msg.seq] = len(missions(v))
        acks.append(msg.seq)

    s["hub"].subscribe(s["keys"].lockstep_ack("guidance"), LockstepAck, on_ack)
    assert wait_until(lambda: s["hub"].session is not None)
    time.sleep(1.0)

    def step(t_s: float) -> None:                   # as the simulator: the next tick once answered
        seq = int(round(t_s * 100))
        tick(setup, t_s, mode=ClockMode.LOCKSTEP)
        assert wait_until(lambda: bool(acks) and max(acks) >= seq, 30.0), (t_s, acks, v.calls)

    step(0.5)
    assert acks == [99] and uploaded[99] == 0       # through the tick before the start try at 1 s
    step(1.0)                                       # start: plan, upload, arm, AUTO before the ack
    assert acks == [99, 199] and uploaded[199] == 1 and s["node"].phase.value == "flying"
    assert any(c[0] == "start_mission" for c in list(v.calls))
    first = json.loads((s["dir"] / "route.json").read_text())
    on_route = (first["waypoints"][2]["x_m"], first["waypoints"][2]["y_m"])
    for t in (1.01, 1.02, 1.5):                     # flying, nothing due: answered already
        step(t)
    time.sleep(0.3)
    assert acks == [99, 199] and s["node"]._member_token is not None

    # the estimate of t = 2.0 is on the route; one of t = 2.05, 100 m off, has already arrived: the
    # check at t = 2.0 must not replan on it
    for t_e in (1.9, 1.95, 2.0):
        estimate(s, t_e, on_route)
    estimate(s, 2.05, (-150.0, -170.0))
    time.sleep(0.3)
    step(2.0)
    assert acks[-1] == 299 and uploaded[299] == 1 and s["node"].stats["replans"] == 0

    # the estimate of t = 3.0 is off the route: the ack of that tick comes after the new mission
    for t_e in (2.95, 3.0):
        estimate(s, t_e, (-150.0, -170.0))
    step(3.0)
    assert acks[-1] == 399 and uploaded[399] == 2 and s["node"].stats["replans"] == 1
    assert any(c[0] == "set_current_mission_item" for c in list(v.calls))
    assert s["node"].stats["estimate_late"] == 0
