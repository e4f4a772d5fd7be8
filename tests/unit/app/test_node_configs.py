"""The app layer derives each node's configuration from the scenario (scenenav/app/nodes.py)."""

from __future__ import annotations

from guidance.config import GuidanceNodeConfig, RouteEnd
from perception.config import ExpectedCamera, PerceptionNodeConfig
from scenenav.app.nodes import guidance_config_from_scenario, perception_camera
from scenenav.app.scenario import ScenarioConfig, load_scenario


def test_guidance_config_follows_the_scenario():
    cfg = load_scenario(None, ("flight.mode=autopilot", "guidance.enabled=true",
                               "guidance.goals_enu_m=[[10,20],[30,40]]", "flight.start_enu_m=[1,2]",
                               "flight.altitude_m=80", "autopilot.mission_end=rtl",
                               "guidance.footprint_m=0", "guidance.clearance_m=15",
                               "sim.camera.fov_deg=50"))
    node_cfg, planner_cfg = guidance_config_from_scenario(cfg, 5761, lockstep=True)
    assert node_cfg.start_enu_m == (1.0, 2.0)
    assert node_cfg.goals_enu_m == ((10.0, 20.0), (30.0, 40.0))
    assert node_cfg.end is RouteEnd.RTL and node_cfg.mavlink_url == "tcp:127.0.0.1:5761"
    assert planner_cfg.altitude_m == 80.0 and planner_cfg.footprint_width_m == 0.0
    assert planner_cfg.clearance_m == 15.0 and planner_cfg.camera_fov_deg == 50.0


def test_perception_expects_the_scenarios_camera():
    assert perception_camera(ScenarioConfig()) == ExpectedCamera(60.0, 200, 200)
    cfg = load_scenario(None, ("sim.camera.fov_deg=45", "sim.camera.width_px=320",
                               "sim.camera.height_px=240"))
    assert perception_camera(cfg) == ExpectedCamera(45.0, 320, 240)


def test_sections_live_in_their_packages():
    cfg = ScenarioConfig()
    assert isinstance(cfg.perception, PerceptionNodeConfig)
    assert isinstance(cfg.guidance, GuidanceNodeConfig)
