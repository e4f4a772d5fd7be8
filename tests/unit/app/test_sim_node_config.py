"""The app layer resolves the simulator node's config from the scenario (the node never reads it)."""

from __future__ import annotations

from types import SimpleNamespace

from scenenav.app.nodes import sim_node_config
from scenenav.app.scenario import FlightMode, bowtie_route, load_scenario
from scenenav.core.camera_geometry import ground_footprint_m

WORLD = SimpleNamespace(width_px=900, height_px=1000, m_per_px=0.53, manifest=SimpleNamespace(name="w"))


def test_scripted_flight_gets_the_fitted_route():
    cfg = load_scenario(None, ("flight.mode=scripted", "seed=4", "duration_s=33"))
    node = sim_node_config(cfg, WORLD, ("tick", "camera", "camera", "recorder"))
    assert node.scripted is not None and not node.end_with_mission
    assert node.scripted.route_enu_m == bowtie_route(WORLD, cfg.flight.altitude_m, cfg.sim.camera.fov_deg)
    assert node.scripted.altitude_m == cfg.flight.altitude_m
    assert (node.seed, node.duration_s, node.sim, node.clock) == (4, 33.0, cfg.sim, cfg.clock)
    assert (node.expected_tick_members, node.expected_camera_members) == (1, 2)


def test_autopilot_flight_starts_on_the_ground_and_ends_with_the_mission():
    cfg = load_scenario(None, ("flight.mode=autopilot", "flight.start_heading_deg=90"))
    node = sim_node_config(cfg, WORLD)
    assert cfg.flight.mode == FlightMode.AUTOPILOT
    assert node.scripted is None and node.end_with_mission and node.start_heading_deg == 90.0
    idle = sim_node_config(load_scenario(None, ("flight.mode=idle",)), WORLD)
    assert idle.scripted is None and not idle.end_with_mission


def test_bowtie_inset_is_half_the_camera_footprint():
    route = bowtie_route(WORLD, 100.0, 60.0, margin_m=10.0)
    half_fp = ground_footprint_m(100.0, 60.0) / 2.0
    assert route[1][0] == WORLD.width_px * WORLD.m_per_px / 2 - half_fp - 10.0
