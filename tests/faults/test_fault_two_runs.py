"""Two runs started at once on the same MAVLink TCP port and UDP output (docs/faults.md).

Both configurations ask for TCP 5760 and the same UDP output: one autopilot gets 5760 (or neither,
if something else holds it), the other binds a free port and reports it; each run.json names its
own autopilot's port, each guidance node flies its own vehicle, and the two vehicles have distinct
MAVLink system ids. This is exactly the race, so the ports are not chosen by a fixture.
"""

from __future__ import annotations

import csv
import json
import socket
import time

import pytest
from pymavlink import mavutil
from support.fake_vehicle import free_port
from support.fault_run import FaultRun


def _udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_json_port(run: FaultRun, timeout_s: float = 240.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            meta = json.loads((run.run_dir / "run.json").read_text())
        except (OSError, ValueError):
            meta = {}
        if meta.get("mavlink_system_id"):
            return meta
        assert run.proc.poll() is None, run.run_dir
        time.sleep(0.2)
    raise AssertionError("run.json never named the bound MAVLink port")


def _heartbeat_sysid(port: int) -> int:
    conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=250)
    try:
        msg = conn.wait_heartbeat(timeout=60)
        assert msg is not None, f"no heartbeat on TCP {port}"
        return msg.get_srcSystem()
    finally:
        conn.close()


@pytest.fixture
def runs():
    started: list[FaultRun] = []
    yield started
    for r in started:
        r.kill()


def test_two_runs_at_once_each_fly_their_own_vehicle(runs, tmp_path):
    udp = f"127.0.0.1:{_udp_port()}"
    args = ["--set", "duration_s=15", "--set", "sim.gps.enabled=true",
            "--set", "perception.method=statistical", "--set", f"autopilot.mavlink_udp_out={udp}",
            "--set", "autopilot.mavlink_tcp_port=5760"]
    for name in ("a", "b"):
        runs.append(FaultRun(tmp_path / name, *args, scenario="scenarios/gps_denied.yaml"))
    metas = [_run_json_port(r) for r in runs]
    ports = [m["mavlink_tcp_port"] for m in metas]
    assert ports[0] != ports[1] and all(ports), ports
    sysids = [_heartbeat_sysid(p) for p in ports]       # a ground station following each run.json
    assert sysids == [m["mavlink_system_id"] for m in metas]
    assert sysids[0] != sysids[1], sysids
    for r in runs:
        assert r.finish() == 0, r.stderr[-3000:]
    for r, meta in zip(runs, metas, strict=True):
        mav = json.loads((r.run_dir / "mavlink.json").read_text())
        assert mav["tcp_port"] == meta["mavlink_tcp_port"]
        with (r.run_dir / "truth.csv").open(newline="") as f:
            z = [float(row["z_m"]) for row in csv.DictReader(f)]
        assert max(z) > 10.0, f"{r.run_dir.name} never took off"     # its own guidance flew it
        events = (r.run_dir / "events.csv").read_text()
        assert events.count("mission uploaded") == 1, r.run_dir.name


def test_a_chosen_sysid_in_use_is_refused(tmp_path):
    from scenenav.app.mavlink_claim import claim_sysid
    from scenenav.core.errors import UserError
    udp = f"127.0.0.1:{free_port()}"
    held = claim_sysid(udp, 7, True, "/runs/first")
    try:
        with pytest.raises(UserError, match="SYSID_THISMAV = 7: already used by the live run /runs/first"):
            claim_sysid(udp, 7, True, "/runs/second")
        other = claim_sysid(udp, 7, False, "/runs/third")     # not chosen: the next free id
        assert other.system_id != 7
        other.release()
    finally:
        held.release()
    again = claim_sysid(udp, 7, True, "/runs/fourth")          # released with its holder
    again.release()


def test_a_hub_port_taken_before_the_simulator_binds_it_starts_the_run_again(tmp_path, monkeypatch):
    """The launcher picks a free hub port, but another process may bind it first: the simulator
    then exits with EXIT_HUB_PORT_TAKEN and the launcher starts the run again on a new port, and
    run.json names the port the hub really listens on."""
    from scenenav.app import launcher
    blocker = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    blocker.bind(("127.0.0.1", 0))
    blocker.listen()
    taken = blocker.getsockname()[1]
    real = launcher.free_port
    handed = iter([taken])
    monkeypatch.setattr(launcher, "free_port", lambda host="127.0.0.1": next(handed, None) or real(host))
    out = tmp_path / "run"
    try:
        summary = launcher.run("scenarios/logging_flight.yaml", str(out),
                               ("duration_s=4", "perception.method=statistical"), progress=False)
    finally:
        blocker.close()
    meta = json.loads((out / "run.json").read_text())
    assert meta["hub_port"] != taken
    assert json.loads((out / "hub.json").read_text())["hub_port"] == meta["hub_port"]
    assert summary["end_reason"] == "duration reached"
    assert "address already in use" in (out / "logs" / "sim.log").read_text()
    with (out / "truth.csv").open(newline="") as f:
        assert len(list(csv.reader(f))) > 10
