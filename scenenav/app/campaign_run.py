"""``scenenav campaign``: fly a campaign's runs on Dask (a LocalCluster, or an existing cluster).

Dask does the scheduling, the retries and the rescheduling after a lost worker; this module only
says what one task is. One task = one flight = ``scenenav run`` of the run's resolved scenario
(``DIR/plan/<id>.yaml``), a subprocess in its own process group, into a fresh attempt folder
``DIR/runs/.partial/<id>-<attempt>``, which becomes ``DIR/runs/<id>/`` (atomic rename) once the flight
has ended, with the task's record ``campaign_run.json`` (status, exit status, wall and CPU time, host,
log tail). A run is complete when ``DIR/runs/<id>/campaign_run.json`` exists: re-running the command
skips it. Each task gives its flight a free MAVLink TCP port of its host and turns MAVLink UDP off, so
flights sharing a host never cross-talk (the Zenoh namespace and hub port are per run already).

* Workers: one thread each, one flight each (``resources={"flight": 1}``); the local default is one
  worker per core this process may use.
* A flight that fails (non-zero exit, no summary) or exceeds ``timeout_s`` is recorded as failed and
  raised, so Dask retries it once (``retries=1``); the campaign goes on.
* A worker killed mid-flight: its flight's launcher gets SIGTERM (PDEATHSIG) and stops its nodes; Dask
  reschedules the task, which flies a new attempt folder.
* Ctrl-C / SIGTERM: a Dask ``Event`` tells every task to stop its flight (SIGTERM to the launcher's
  group, which stops its nodes; SIGKILL after a grace period) and queued tasks not to start; the
  client waits for that, writes the table and exits 130. The next invocation resumes.

On a cluster, DIR must be on a filesystem shared by the client and the workers (run folders are
written in place, not shipped back); the workers need scenenav installed and ``--resources flight=1``.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from scenenav.app.campaign_spec import CampaignSpec, PlannedRun, expand, load_campaign, plan_json
from scenenav.core.errors import UserError
from scenenav.core.formats.atomic_file import write_atomic

log = logging.getLogger(__name__)

RECORD = "campaign_run.json"
PARTIAL = ".partial"
#: Seconds a stopped flight's launcher gets to stop its nodes (it gives each node 10 s on SIGINT,
#: scenenav.app.launcher.GRACE_S, and then writes the summary) before the group is killed.
STOP_GRACE_S = 45.0
POLL_S = 0.25
STOP_CHECK_S = 1.0
LOG_TAIL_LINES = 30
LOG_TAIL_CHARS = 4000
#: Wall seconds the client waits, after Ctrl-C, for the running flights to stop.
CANCEL_WAIT_S = STOP_GRACE_S + 30.0


class FlightFailed(RuntimeError):
    """A flight ended without a usable run folder (its record is already written)."""


@dataclass(frozen=True)
class FlightTask:
    run_id: str
    scenario_file: str       # DIR/plan/<id>.yaml
    runs_dir: str            # DIR/runs
    cwd: str                 # where relative paths of the scenario resolve (the client's cwd)
    timeout_s: float
    stop_event: str          # name of the campaign's Dask Event
    submitted_unix: float


def is_complete(runs_dir: Path, run_id: str, retry_failed: bool = False) -> bool:
    rec = read_record(runs_dir / run_id)
    if rec is None:
        return False
    return rec.get("status") == "ok" or (not retry_failed and rec.get("status") in ("failed", "timeout"))


def read_record(run_dir: Path) -> dict | None:
    try:
        return json.loads((run_dir / RECORD).read_text())
    except (OSError, ValueError):
        return None


def _write_json_atomic(path: Path, data: dict) -> None:
    write_atomic(path, json.dumps(data, indent=2, default=str))


def _tail_text(path: Path, lines: int) -> str:
    try:
        with path.open("rb") as f:
            f.seek(max(0, path.stat().st_size - 64_000))
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return ""
    return "\n".join(text.splitlines()[-lines:])


def log_tail(attempt_dir: Path, launcher_log: Path) -> str:
    """The end of the launcher's output, then of every node log that reports an error."""
    parts = [_tail_text(launcher_log, LOG_TAIL_LINES)]
    for node_log in sorted((attempt_dir / "logs").glob("*.log")):
        text = _tail_text(node_log, LOG_TAIL_LINES)
        if "Traceback" in text or " ERROR " in text or "error:" in text:
            parts.append(f"--- {node_log.name}\n" + "\n".join(text.splitlines()[-12:]))
    return "\n".join(p for p in parts if p)[-LOG_TAIL_CHARS:]


def _kill_nodes(attempt_dir: Path) -> None:
    """After the launcher was killed: SIGKILL any node it started that is still alive."""
    try:
        pids = json.loads((attempt_dir / "logs" / "pids.json").read_text())
    except (OSError, ValueError):
        return
    for pid in pids.values():
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if str(attempt_dir).encode() in cmdline:     # still our node, not a reused pid
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _signal_group(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except ProcessLookupError:   # it has just exited: wait4 collects it next
        pass


class _Stopper:
    """Reads the campaign's stop Event at most once a second (a scheduler round trip)."""

    def __init__(self, name: str) -> None:
        from distributed import Event
        self.event = Event(name)
        self.last = 0.0
        self.stopped = False

    def __call__(self) -> bool:
        now = time.monotonic()
        if not self.stopped and now - self.last >= STOP_CHECK_S:
            self.last = now
            try:
                self.stopped = bool(self.event.is_set())
            except Exception:   # scheduler gone: the campaign is over, stop the flight
                self.stopped = True
        return self.stopped


def _worker_name() -> str:
    try:
        from distributed import get_worker
        return str(get_worker().address)
    except (ImportError, ValueError):
        return ""


def warm_worker() -> bool:
    """Imports what ``fly`` needs, once per worker process, before the first flight is submitted (run on
    every worker by ``Client.run``): the import is a worker's start-up cost, paid by all workers at once
    instead of inside each one's first flight."""
    import scenenav.app.launcher  # noqa: F401
    import scenenav.core.bus  # noqa: F401
    return True


def fly(task: FlightTask) -> dict:
    """One flight (runs on a Dask worker). Returns its record; raises FlightFailed on a failed flight."""
    from scenenav.app.launcher import die_with_parent
    from scenenav.core.bus import free_port
    started = time.time()
    stop = _Stopper(task.stop_event)
    if stop():
        return {"run_id": task.run_id, "status": "cancelled"}
    runs_dir = Path(task.runs_dir)
    final = runs_dir / task.run_id
    previous = read_record(final)
    attempt = int(previous.get("attempts", 0)) + 1 if previous else 1
    tag = f"{task.run_id}-{uuid.uuid4().hex[:8]}"
    partial = runs_dir / PARTIAL / tag
    partial.parent.mkdir(parents=True, exist_ok=True)
    launcher_log = runs_dir / PARTIAL / f"{tag}.launcher.log"
    port = free_port()
    cmd = [sys.executable, "-m", "scenenav.app.cli", "run", task.scenario_file, "--out", str(partial),
           "--quiet", "--set", f"autopilot.mavlink_tcp_port={port}", "--set", "autopilot.mavlink_udp_out=none"]
    rc, cpu_s, why = None, None, ""
    with launcher_log.open("wb") as out:
        try:
            proc = subprocess.Popen(cmd, cwd=task.cwd, stdout=out, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, start_new_session=True,
                                    preexec_fn=die_with_parent)
        except OSError as exc:     # e.g. the client's folder is not on this worker's filesystem
            out.write(f"error: cannot start {' '.join(cmd)} in {task.cwd}: {exc}\n".encode())
            proc = None
    launch_unix = time.time()
    deadline = time.monotonic() + task.timeout_s
    signalled_at = None
    while proc is not None and rc is None:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            rc = os.waitstatus_to_exitcode(status)
            proc.returncode = rc
            cpu_s = usage.ru_utime + usage.ru_stime     # the launcher and every node it reaped
            break
        if signalled_at is None and (stop() or time.monotonic() > deadline):
            why = "cancelled" if stop.stopped else "timeout"
            _signal_group(proc.pid, signal.SIGTERM)     # the launcher stops its nodes in order
            signalled_at = time.monotonic()
        elif signalled_at is not None and time.monotonic() - signalled_at > STOP_GRACE_S:
            _signal_group(proc.pid, signal.SIGKILL)
            _kill_nodes(partial)
            signalled_at = float("inf")
        time.sleep(POLL_S)
    ended = time.time()
    if why == "cancelled":
        return {"run_id": task.run_id, "status": "cancelled"}   # the attempt folder is dropped next time
    ok = rc == 0 and why == "" and (partial / "summary.json").is_file()
    status = "ok" if ok else (why or "failed")
    partial.mkdir(parents=True, exist_ok=True)
    (partial / "logs").mkdir(exist_ok=True)
    shutil.move(str(launcher_log), partial / "logs" / "launcher.log")
    record = {"run_id": task.run_id, "status": status, "exit_status": rc, "attempts": attempt,
              "host": socket.gethostname(), "worker": _worker_name(), "mavlink_tcp_port": port,
              "wall_s": round(ended - launch_unix, 3), "cpu_s": None if cpu_s is None else round(cpu_s, 3),
              "submitted_unix": task.submitted_unix, "started_unix": started, "launched_unix": launch_unix,
              "ended_unix": ended,
              "log_tail": "" if ok else log_tail(partial, partial / "logs" / "launcher.log")}
    _write_json_atomic(partial / RECORD, record)
    if final.exists():
        shutil.rmtree(final)      # an earlier failed attempt of this run
    os.replace(partial, final)
    if not ok:
        raise FlightFailed(f"run {task.run_id}: {status} (exit status {rc}); see {final / 'logs'}")
    return record


# ---------------------------------------------------------------------------------------------- client

@dataclass
class CampaignResult:
    out_dir: Path
    planned: int
    skipped: int
    flown: int = 0
    failed: int = 0
    interrupted: bool = False
    received_unix: dict[str, float] = field(default_factory=dict)   # run id -> result at the client
    makespan_s: float = 0.0


def default_workers() -> int:
    """One flight per core this process may use (a lockstep flight keeps about one core busy)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def write_plan(out: Path, spec: CampaignSpec, runs: list[PlannedRun]) -> None:
    """``DIR/plan.json`` and ``DIR/plan/<id>.yaml`` (each run's resolved scenario)."""
    (out / "plan").mkdir(parents=True, exist_ok=True)
    for r in runs:
        f = out / "plan" / f"{r.run_id}.yaml"
        if not f.is_file():
            write_atomic(f, yaml.safe_dump(r.scenario, sort_keys=False))
    _write_json_atomic(out / "plan.json", plan_json(spec, runs))


class _IgnoreSigint:
    """Worker plugin for the local cluster: Ctrl-C in the terminal reaches the worker processes too
    (same process group); only the client handles it, and stops the flights through the Event."""

    name = "scenenav-ignore-sigint"

    def setup(self, worker) -> None:  # noqa: D102 - the Dask plugin hook
        import threading
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def _client(workers: int | None, scheduler: str | None):
    from distributed import Client, LocalCluster
    # Dask logs every worker's arrival and departure at INFO: keep them for --log-level INFO/DEBUG.
    level = logging.getLogger().getEffectiveLevel()
    logging.getLogger("distributed").setLevel(logging.ERROR if level >= logging.WARNING else level)
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise UserError(f"--scheduler {scheduler}: cannot connect ({exc}); expected the address of a "
                            "running Dask scheduler, e.g. tcp://HOST:8786") from None
        info = client.scheduler_info()
        offering = [w for w in info.get("workers", {}).values() if w.get("resources", {}).get("flight")]
        if info.get("workers") and not offering:
            client.close()
            raise UserError(f"--scheduler {scheduler}: no worker offers the resource 'flight'; start the "
                            "workers with --resources flight=1 --nthreads 1 (docs/campaigns.md)")
        return client, None
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreSigint(_IgnoreSigint, WorkerPlugin):
        pass
    n = workers or default_workers()
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, resources={"flight": 1},
                           dashboard_address=None, memory_limit=0, silence_logs=logging.ERROR)
    client = Client(cluster)
    client.register_plugin(IgnoreSigint())
    return client, cluster


def run_campaign(campaign_file: str, out_dir: str, workers: int | None = None, scheduler: str | None = None,
                 extra_sets: tuple[str, ...] = (), retry_failed: bool = False, max_runs: int | None = None,
                 max_repeat: int | None = None,
                 progress: bool = True, report_dir: str | None = None,
                 command: str | None = None) -> CampaignResult:
    """Expand, fly what is not complete yet, write results.parquet/csv and report.md."""
    from scenenav.app.campaign_report import write_outputs
    if workers is not None and workers < 1:
        raise UserError(f"--workers {workers}: expected an integer >= 1")
    if max_runs is not None and max_runs < 1:
        raise UserError(f"--max-runs {max_runs}: expected an integer >= 1")
    spec = load_campaign(campaign_file, extra_sets)
    if max_repeat is not None and max_repeat < 1:
        raise UserError(f"--repeat {max_repeat}: expected an integer >= 1")
    runs = expand(spec, max_repeat)
    if max_runs is not None:
        runs = runs[:max_runs]
    full_count = len(expand(spec)) if (max_runs or max_repeat) else len(runs)
    out = Path(out_dir).resolve()
    previous = out / "plan.json"
    if previous.is_file():
        try:
            other = json.loads(previous.read_text()).get("campaign")
        except ValueError:
            other = None
        if other not in (None, spec.name):
            raise UserError(f"{out}: holds campaign {other!r}, not {spec.name!r} (choose another --out)")
    out.mkdir(parents=True, exist_ok=True)
    write_plan(out, spec, runs)
    runs_dir = out / "runs"
    shutil.rmtree(runs_dir / PARTIAL, ignore_errors=True)     # attempts of an earlier, stopped invocation
    runs_dir.mkdir(exist_ok=True)
    todo = [r for r in runs if not is_complete(runs_dir, r.run_id, retry_failed)]
    result = CampaignResult(out, len(runs), len(runs) - len(todo))
    print(f"campaign {spec.name}: {len(runs)} runs planned ({out / 'plan.json'}), "
          f"{result.skipped} already complete, {len(todo)} to fly", file=sys.stderr, flush=True)
    from scenenav.app.signals import interrupt_on_stop_signals
    try:
        with interrupt_on_stop_signals():   # also when started with SIGINT ignored (a background job)
            if todo:
                _fly_all(spec, todo, out, workers, scheduler, progress, result)
    finally:
        write_outputs(out, spec, runs, report_dir, command, full_count)
    if result.interrupted:
        raise KeyboardInterrupt
    return result


def _fly_all(spec: CampaignSpec, todo: list[PlannedRun], out: Path, workers: int | None,
             scheduler: str | None, progress: bool, result: CampaignResult) -> None:
    from distributed import Event, as_completed, wait
    from tqdm import tqdm
    client, cluster = _client(workers, scheduler)
    stop_name = f"scenenav-campaign-stop-{uuid.uuid4().hex[:12]}"
    stop = Event(stop_name, client=client)
    bar = tqdm(total=len(todo), unit="run", desc=spec.name, disable=not (progress and sys.stderr.isatty()))
    futures = []
    t0 = time.time()
    try:
        client.run(warm_worker)
        cwd = os.getcwd()
        for r in todo:
            task = FlightTask(r.run_id, str(out / "plan" / f"{r.run_id}.yaml"), str(out / "runs"), cwd,
                              spec.timeout_s, stop_name, time.time())
            futures.append(client.submit(fly, task, key=f"flight-{r.run_id}-{uuid.uuid4().hex[:6]}",
                                         resources={"flight": 1}, retries=1, pure=False))
        for fut in as_completed(futures):
            rid = fut.key.split("-")[1]
            result.received_unix[rid] = time.time()
            if fut.status == "error":
                result.failed += 1
                log.warning("%s", fut.exception())
            else:
                result.flown += 1
            bar.update(1)
            bar.set_postfix(done=result.flown, failed=result.failed)
    except KeyboardInterrupt:
        result.interrupted = True
        print("interrupted: stopping the running flights (the next invocation resumes)",
              file=sys.stderr, flush=True)
        stop.set()
        try:
            wait(futures, timeout=CANCEL_WAIT_S)
        except TimeoutError:
            log.warning("flights still stopping after %.0f s; closing the cluster", CANCEL_WAIT_S)
    finally:
        result.makespan_s = time.time() - t0
        bar.close()
        client.close()
        if cluster is not None:
            cluster.close()
    print(f"campaign {spec.name}: {result.flown} flown, {result.failed} failed, {result.skipped} skipped "
          f"({result.makespan_s:.0f} s)", file=sys.stderr, flush=True)

