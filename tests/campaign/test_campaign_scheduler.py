"""``--scheduler``: the same campaign submitted to an existing Dask cluster (a real ``dask scheduler``
and ``dask worker`` started here, as on a cluster's nodes)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from support.campaign_cli import SCRIPTED, start_campaign, wait_for, write_campaign

pytestmark = pytest.mark.slow

DASK = str(Path(sys.executable).with_name("dask"))


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.fixture
def cluster(tcp_port, tmp_path):
    """(address, start_worker): a scheduler on a free port; workers started on demand."""
    procs = []

    def start(*args):
        p = subprocess.Popen([DASK, *args], stdout=subprocess.DEVNULL, stderr=(tmp_path / f"dask-{len(procs)}.log").open("w"),
                             start_new_session=True)
        procs.append(p)
        return p
    start("scheduler", "--host", "127.0.0.1", "--port", str(tcp_port), "--no-dashboard")
    wait_for(lambda: _listening(tcp_port), 60, "the scheduler")
    address = f"tcp://127.0.0.1:{tcp_port}"

    def start_worker(*extra):
        start("worker", address, "--nthreads", "1", "--no-dashboard", *extra)
    yield address, start_worker
    for p in reversed(procs):
        os.killpg(p.pid, signal.SIGTERM)
        try:
            p.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)


def _workers(address: str) -> int:
    from distributed import Client
    with Client(address, timeout="10s") as c:
        return len(c.scheduler_info()["workers"])


def test_campaign_runs_on_an_existing_cluster(tmp_path, cluster):
    address, start_worker = cluster
    start_worker("--resources", "flight=1")
    wait_for(lambda: _workers(address) == 1, 60, "the worker to join")
    campaign = write_campaign(tmp_path / "remote.yaml", name="remote", base=str(SCRIPTED),
                              set={"duration_s": 5}, grid={"seed": [1, 2]})   # short: the cluster is under test
    out = tmp_path / "out"
    proc = start_campaign(campaign, out, "--scheduler", address)
    _stdout, stderr = proc.communicate(timeout=600)
    assert proc.returncode == 0, stderr
    rows = pq.read_table(out / "results.parquet").to_pylist()
    assert [r["run_status"] for r in rows] == ["ok", "ok"]
    assert all(r["run_worker"].startswith("tcp://127.0.0.1:") for r in rows)


def test_cluster_without_the_flight_resource_is_one_line_error(tmp_path, cluster):
    address, start_worker = cluster
    start_worker()
    wait_for(lambda: _workers(address) == 1, 60, "the worker to join")
    campaign = write_campaign(tmp_path / "remote.yaml", name="remote", base=str(SCRIPTED),
                              set={"duration_s": 10}, grid={"seed": [1]})
    proc = start_campaign(campaign, tmp_path / "out", "--scheduler", address)
    _stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert stderr.strip().splitlines()[-1].startswith("error: --scheduler") and "flight=1" in stderr
    assert "Traceback" not in stderr
