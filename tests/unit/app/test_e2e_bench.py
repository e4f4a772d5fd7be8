"""``scenenav bench e2e``'s measuring parts: CPU time of a run's processes from /proc, the window of
the simulator loop from its log, and the bench scenario (a valid, short GPS-denied mission)."""

import json
import subprocess
import sys
import time

import pytest

from scenenav.app.bench.e2e import GOALS_ENU_M, GPS_DENIED, CpuSampler, E2eBenchConfig, _at, _finish_wall_time, scenario
from scenenav.app.scenario import FlightMode, load_scenario
from scenenav.core.errors import UserError

#: burn {s} s of CPU, then write this process's id to {marker}, then idle
BUSY = ("import os, time\nt = time.process_time()\nwhile time.process_time() - t < {s}: pass\n"
        "open({marker!r}, 'w').write(str(os.getpid()))\ntime.sleep(60)\n")


def _wait_for(path, timeout_s=120.0):
    deadline = time.monotonic() + timeout_s
    while not path.exists() or not path.read_text():
        assert time.monotonic() < deadline, f"{path} not written"
        time.sleep(0.05)
    return int(path.read_text())


def test_sampler_measures_a_child_and_its_descendants(tmp_path):
    # a "node" that burns 0.4 s of CPU and starts a child burning 0.3 s, like the simulator's renderer
    node_done, worker_done = tmp_path / "node.pid", tmp_path / "worker.pid"
    code = ("import subprocess, sys\n"
            f"subprocess.Popen([sys.executable, '-c', {BUSY.format(s=0.3, marker=str(worker_done))!r}])\n"
            + BUSY.format(s=0.4, marker=str(node_done)))
    (tmp_path / "logs").mkdir()
    proc = subprocess.Popen([sys.executable, "-c", code])
    worker = None
    try:
        (tmp_path / "logs" / "pids.json").write_text(json.dumps({"sim": proc.pid}))
        with CpuSampler(tmp_path, 0.05) as sampler:
            t0 = time.time()
            _wait_for(node_done)
            worker = _wait_for(worker_done)
            time.sleep(0.3)
            t1 = time.time()
    finally:
        if worker is not None:
            subprocess.run(["kill", str(worker)], check=False)
        proc.kill()
        proc.wait()
    # CPU from before the first sample counts from 0 (the sampler starts before the launch)
    assert sampler.cpu_between("sim", t0 - 1.0, t1) >= 0.39
    assert sampler.cpu_between("sim/render_worker", t0 - 1.0, t1) >= 0.29
    assert sampler.cpu_between("launcher", t0, t1) >= 0.0
    assert sampler.cpu_between("nobody", t0, t1) == 0.0


def test_interpolation_between_samples():
    s = [(10.0, 1.0), (12.0, 3.0)]
    assert _at(s, 9.0) == 0.0 and _at(s, 11.0) == pytest.approx(2.0) and _at(s, 20.0) == 3.0


def test_the_loop_end_is_read_from_the_simulator_log(tmp_path):
    log = tmp_path / "sim.log"
    log.write_text("2026-12-01 16:27:09,036 INFO sitl.node: lockstep member joined: perception\n"
                   "2026-12-01 16:28:19,032 INFO sitl.node: simulation finished: mission complete at "
                   "t=302.5s (4.3x real time)\n")
    t = _finish_wall_time(log)
    assert t is not None and time.strftime("%H:%M:%S", time.localtime(t)) == "16:28:19"
    assert t % 1.0 == pytest.approx(0.032, abs=1e-3)
    assert _finish_wall_time(tmp_path / "missing.log") is None


def test_the_bench_scenario_is_a_gps_denied_guided_mission(tmp_path):
    path = tmp_path / "bench.yaml"
    import yaml
    path.write_text(yaml.safe_dump(scenario(E2eBenchConfig(), 5999)))
    cfg = load_scenario(path)
    assert cfg.flight.mode == FlightMode.AUTOPILOT and not cfg.sim.gps.enabled
    assert cfg.perception.method == "cnn" and cfg.guidance.enabled
    assert [tuple(g) for g in cfg.guidance.goals_enu_m] == list(GOALS_ENU_M)
    assert cfg.autopilot.mavlink_tcp_port == 5999 and cfg.autopilot.mavlink_udp_out == "none"
    # everything else is scenarios/gps_denied.yaml's (camera, reference, decision rule, clearance)
    full = load_scenario(GPS_DENIED)
    assert cfg.sim.camera == full.sim.camera and cfg.perception == full.perception
    assert cfg.guidance.clearance_m == full.guidance.clearance_m


def test_bad_settings_are_user_errors():
    with pytest.raises(UserError, match="duration_s"):
        E2eBenchConfig(duration_s=0.0)
