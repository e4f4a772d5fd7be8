"""A node on another machine joins a run started with ``external.listen_host``.

The "other machine" is a Linux network namespace joined to this one by a veth pair: its own
interfaces, its own loopback (it cannot reach this machine's 127.0.0.1), one /30 link to this
machine, as a companion computer on a LAN. The example node (examples/perception_node_python)
runs there with ``--hub`` one of run.json's ``bus.remote_endpoints`` and ``--listen`` its own
address. With ``external.listen_host`` set to this machine's address on that link the run waits for it, every node of the run links
to it (gossip gives them its address) and the autopilot flies on its fixes, and a viewer there
gets the live view's (``--live``) server info; with the default (127.0.0.1) the same node cannot
reach the run, which ends with its one-line message.

Without the rights to create a namespace (not root, or no ``ip``), the node runs on this machine
but connects only through this machine's first non-loopback address, and listens there: the hub
still has to listen beyond loopback for it to join (the weaker form; the test says which it ran;
``support.other_machine``).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from support import REPO_ROOT
from support.external_flight import EXAMPLE_NODE, external_flight
from support.other_machine import OtherMachine

EXAMPLE = EXAMPLE_NODE
NODE_ID = "remote1"
RUN_TIMEOUT_S = 300
#: The flight of tests/e2e/test_external_node.py (GPS off, the vehicle navigates on the node's fixes).
SCENARIO = {**external_flight("remote_node", 20),
            "external": {"nodes": [f"perception:{NODE_ID}"], "join_timeout_s": 60}}


VIEWER = r'''
import asyncio, json, sys
import websockets

async def main(url):
    async with websockets.connect(url, subprotocols=["foxglove.websocket.v1"], max_size=None) as ws:
        first = json.loads(await asyncio.wait_for(ws.recv(), 30))
        print("subprotocol", ws.subprotocol, "first op", first.get("op"), flush=True)

asyncio.run(main(sys.argv[1]))
'''


def _fly(tmp: Path, machine: OtherMachine, name: str, overrides: list[str]) -> dict:
    scenario = tmp / f"{name}.yaml"
    scenario.write_text(yaml.safe_dump(SCENARIO))
    out = tmp / name
    run = subprocess.Popen([sys.executable, "-m", "scenenav.app.cli", "run", str(scenario), "--out", str(out),
                            "--quiet", *overrides], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, cwd=REPO_ROOT, stdin=subprocess.DEVNULL)
    node = None
    try:
        deadline = time.monotonic() + 120
        while not (out / "run.json").exists():
            assert run.poll() is None and time.monotonic() < deadline, run.communicate()
            time.sleep(0.2)
        meta = json.loads((out / "run.json").read_text())
        viewer = None
        if "--live" in overrides:       # the live view comes up beside the recorder, before the wait
            while not (out / "live.json").exists():
                assert run.poll() is None and time.monotonic() < deadline, run.communicate()
                time.sleep(0.2)
            port = json.loads((out / "live.json").read_text())["port"]
            (tmp / "viewer.py").write_text(VIEWER)
            viewer = machine.start([sys.executable, str(tmp / "viewer.py"), f"ws://{machine.host_addr}:{port}"],
                                   tmp / f"{name}-viewer.log")
            assert viewer.wait(timeout=60) == 0, (tmp / f"{name}-viewer.log").read_text()
        node = machine.start([sys.executable, str(EXAMPLE), str(out), "--hub",
                              f"tcp/{machine.host_addr}:{meta['hub_port']}", "--listen",
                              f"tcp/{machine.node_addr}:0"], tmp / f"{name}-node.log")
        stdout, stderr = run.communicate(timeout=RUN_TIMEOUT_S)
    finally:
        for proc in (run, node):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
    return {"code": run.returncode, "stdout": stdout, "stderr": stderr, "out": out, "meta": meta,
            "node_log": (tmp / f"{name}-node.log").read_text(),
            "viewer_log": (tmp / f"{name}-viewer.log").read_text() if viewer else None}


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("remote")
    machine = OtherMachine()
    try:
        yield {"machine": machine,
               # one interface's address, the harder case: the run's own nodes must reach the hub
               # there too (nothing answers on 127.0.0.1); 0.0.0.0 is the GCS test's
               "open": _fly(tmp, machine, "open", ["--live", "--live-port", "0", "--set",
                                                   f"external.listen_host={machine.host_addr}"]),
               "local": _fly(tmp, machine, "local", ["--set", "external.listen_host=127.0.0.1",
                                                     "--set", "external.join_timeout_s=4"])}
    finally:
        machine.close()


def test_a_node_on_another_machine_flies_the_vehicle(flights):
    f = flights["open"]
    machine = flights["machine"]
    print("other machine:", machine.describe())
    assert f["code"] == 0, (f["stderr"][-2000:], f["node_log"][-2000:])
    bus = f["meta"]["bus"]
    hub = f"tcp/{machine.host_addr}:{f['meta']['hub_port']}"
    assert bus["listen_host"] == machine.host_addr and bus["remote_endpoints"] == [hub], bus
    assert bus["endpoint"] == hub
    run = f["out"]
    joined = json.loads((run / "external.json").read_text())
    assert joined["joined"] == [f"perception:{NODE_ID}"] and joined["unlinked"] == [], joined
    from scenenav.app.evaluation import read_csv
    fixes = read_csv(run / "fixes.csv")
    sim = json.loads((run / "sim_stats.json").read_text())
    assert len(fixes["t_s"]) == sim["camera_frames"] and sim["ack_timeouts"] == 0
    assert set(fixes["node_id"]) == {NODE_ID}
    stats = json.loads((run / "autopilot_stats.json").read_text())
    assert stats["core"]["vision_fused"] > 10, stats["core"]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["gps_used"] is False and summary["rms_error_m"] < 5.0, summary
    # the live view listened on the run's listen_host too: the viewer there got the server info
    assert "subprotocol foxglove.websocket.v1 first op serverInfo" in f["viewer_log"], f["viewer_log"]
    live = json.loads((run / "live.json").read_text())
    assert live["host"] == machine.host_addr and live["url"] == f"ws://{machine.host_addr}:{live['port']}"


def test_by_default_the_run_stays_on_its_machine(flights):
    f = flights["local"]
    assert f["code"] == 1, f["stderr"][-2000:]
    assert "remote_endpoints" not in f["meta"]["bus"] and "listen_host" not in f["meta"]["bus"]
    errors = [line for line in f["stderr"].splitlines() if "ERROR" in line]
    assert len(errors) == 1 and f"external node perception:{NODE_ID} did not join within 4 s" in errors[0]
    assert json.loads((f["out"] / "external.json").read_text())["missing"] == [f"perception:{NODE_ID}"]
