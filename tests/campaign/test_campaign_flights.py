"""``scenenav campaign`` end to end: real Dask (a 2-worker LocalCluster), real 10 to 20-second flights
(scripted mode: no autopilot needed), real process trees."""

from __future__ import annotations

import json
import os
import signal

import pyarrow.parquet as pq
import pytest
from support.campaign_cli import (
    SCRIPTED,
    flights_running,
    processes_mentioning,
    start_campaign,
    wait_for,
    write_campaign,
)

pytestmark = pytest.mark.slow

#: The flights of the campaigns that run to the end: short, the campaign machinery is under test.
FLIGHT_S = 10
#: The flights of the Ctrl-C test: long enough that two are in the air when the signal comes.
STOPPED_FLIGHT_S = 12


def _table(out):
    return pq.read_table(out / "results.parquet").to_pylist()


def _finish(proc, timeout_s=900):
    stdout, stderr = proc.communicate(timeout=timeout_s)
    return proc.returncode, stdout, stderr


@pytest.mark.timeout(900)     # four short flights plus one flown again, two at a time, then a resume
def test_four_runs_complete_through_a_worker_kill_then_rerun_flies_nothing(tmp_path):
    """Four runs on two workers; a Dask worker is SIGKILLed during the first flight: its flight
    stops its nodes and is flown again, no row is lost, and a second invocation flies nothing."""
    campaign = write_campaign(tmp_path / "four.yaml", name="four", base=str(SCRIPTED),
                              set={"duration_s": FLIGHT_S},
                              grid={"perception.method": ["statistical", "none"], "seed": [1, 2]})
    out = tmp_path / "out"
    proc = start_campaign(campaign, out, "--workers", "2")
    try:
        launchers = wait_for(lambda: flights_running(out), 180, "a flight to start")
        worker_pid = launchers[0][1]
        assert worker_pid != proc.pid                 # the launcher's parent is a Dask worker process
        os.kill(worker_pid, signal.SIGKILL)
        rc, _stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert rc == 0, stderr
    rows = _table(out)
    assert len(rows) == 4 and all(r["run_status"] == "ok" and r["run_exit_status"] == 0 for r in rows), \
        [r["run_status"] for r in rows]
    assert sorted((r["override.perception.method"], r["override.seed"]) for r in rows) == sorted(
        (m, s) for m in ("statistical", "none") for s in (1, 2))
    assert all(r["override.duration_s"] == FLIGHT_S and r["sim_time_s"] >= FLIGHT_S - 0.5 for r in rows)
    assert {r["perception_method"] for r in rows} == {"statistical", "none"}
    assert len({r["run_mavlink_tcp_port"] for r in rows}) == 4       # every run its own port
    for r in rows:   # what was flown is the planned scenario
        assert (out / "runs" / r["run_id"] / "summary.json").is_file()
    report = (out / "report.md").read_text()
    assert "perception.method=statistical" in report and "perception.method=none" in report
    assert (out / "error_cdf.png").stat().st_size > 0 and (out / "success_rate.png").stat().st_size > 0
    # the killed worker's flight stopped its nodes (PDEATHSIG -> the launcher's clean stop)
    wait_for(lambda: not processes_mentioning(str(out)), 90, "the killed worker's flight to stop")
    records = {r["run_id"]: (out / "runs" / r["run_id"] / "campaign_run.json").read_text() for r in rows}

    rc, _stdout, stderr = _finish(start_campaign(campaign, out, "--workers", "2"))
    assert rc == 0, stderr
    assert "4 already complete, 0 to fly" in stderr
    assert {r["run_id"]: (out / "runs" / r["run_id"] / "campaign_run.json").read_text() for r in rows} == records
    assert len(_table(out)) == 4


def test_failing_run_is_recorded_and_the_others_complete(tmp_path):
    campaign = write_campaign(tmp_path / "fail.yaml", name="fail", base=str(SCRIPTED),
                              set={"duration_s": FLIGHT_S},
                              grid={"case": {"good-1": {"seed": 1}, "good-2": {"seed": 2},
                                             "bad": {"world": str(tmp_path / "no-such-world")}}})
    out = tmp_path / "out"
    rc, _stdout, stderr = _finish(start_campaign(campaign, out, "--workers", "2"))
    assert rc == 1, stderr                              # the campaign ran to its end, with a failure
    rows = {r["override.case"]: r for r in _table(out)}
    assert set(rows) == {"good-1", "good-2", "bad"}
    assert rows["good-1"]["run_status"] == rows["good-2"]["run_status"] == "ok"
    bad = rows["bad"]
    assert bad["run_status"] == "failed" and bad["run_exit_status"] == 2
    assert bad["run_attempts"] == 2                     # retried once by Dask
    assert "no-such-world" in bad["run_log_tail"] and "error:" in bad["run_log_tail"]
    assert "Failed runs" in (out / "report.md").read_text()
    record = json.loads((out / "runs" / bad["run_id"] / "campaign_run.json").read_text())
    assert record["status"] == "failed"


def test_ctrl_c_leaves_no_orphans_and_a_readable_table_then_resumes(tmp_path):
    campaign = write_campaign(tmp_path / "stop.yaml", name="stop", base=str(SCRIPTED),
                              set={"duration_s": STOPPED_FLIGHT_S}, grid={"seed": [1, 2, 3]})
    out = tmp_path / "out"
    proc = start_campaign(campaign, out, "--workers", "2")
    try:
        wait_for(lambda: len(flights_running(out)) == 2 and
                 all((p / "truth.csv").is_file() for p in (out / "runs" / ".partial").glob("*-*") if p.is_dir()),
                 180, "two flights in the air")
        os.killpg(proc.pid, signal.SIGINT)               # Ctrl-C at the terminal: the whole group
        rc, _stdout, stderr = _finish(proc, 300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert rc == 130, stderr
    assert processes_mentioning(str(out)) == []         # no launcher, no node left on the worker host
    rows = _table(out)
    assert len(rows) == 3
    assert {r["run_status"] for r in rows} <= {"ok", "pending"} and "pending" in {r["run_status"] for r in rows}
    done_before = sum(r["run_status"] == "ok" for r in rows)

    rc, _stdout, stderr = _finish(start_campaign(campaign, out, "--workers", "2"))
    assert rc == 0, stderr
    assert f"{done_before} already complete, {3 - done_before} to fly" in stderr
    assert all(r["run_status"] == "ok" for r in _table(out))


def test_flight_over_its_time_limit_is_stopped_and_recorded(tmp_path):
    campaign = write_campaign(tmp_path / "slow.yaml", name="slow", base=str(SCRIPTED), timeout_s=10,
                              set={"duration_s": 600}, grid={"seed": [1]})
    out = tmp_path / "out"
    rc, _stdout, stderr = _finish(start_campaign(campaign, out, "--workers", "1"))
    assert rc == 1, stderr
    (row,) = _table(out)
    assert row["run_status"] == "timeout" and row["run_attempts"] == 2
    assert row["run_exit_status"] == 130                  # the launcher stopped on the SIGTERM it got
    assert processes_mentioning(str(out)) == []
