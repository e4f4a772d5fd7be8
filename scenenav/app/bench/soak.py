"""``scenenav bench soak``: a long GPS-denied flight under churn, then: did anything grow?

Kept out of ``make test`` (it flies 30 simulated minutes by default). The flight is
``scenarios/gps_denied.yaml`` without the guidance node: GPS off, the autopilot navigates on the
perception node's fixes, flying laps of gps_denied's loop as the guidance planner plans it (around
the bad matching areas of the world's assistant map: straight bowtie laps would cross the lake,
where the vision failsafe rightly lands the vehicle) until the duration is reached. The laps are
the autopilot's own route mission: a guidance upload would exceed the 700 mission items. Meanwhile

* the perception node is swapped every ``swap_every_s`` simulated seconds (make-before-break,
  ``perception.swap_every_s``: each swap is a new process running the CNN, alternately named
  ``perception`` and ``perception-2``), and
* a fuzzer sends ``fuzz_frames_per_min`` garbage frames a minute to the autopilot's MAVLink TCP port
  (MAVLink v2 frames of random message ids and payloads with a wrong checksum, truncated frames and
  stray bytes: all must be counted and dropped, none may command the vehicle).

Every process of the run (and the simulator's render worker) is sampled every few wall seconds:
resident memory (``VmRSS``) and open file descriptors, from ``/proc``. The figures compare each
process role at simulated minute 5 with the end of the flight (for perception: the node in charge
then), and the lockstep counters (``sim_stats.json``: ticks flown, answers that timed out;
``autopilot_stats.json``: ticks out of order) say whether any tick was dropped.

Issue 14's targets: memory of every process within 10 % of its value at minute 5, no file
descriptor growth, no dropped lockstep tick.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import random
import socket
import struct
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import yaml

from scenenav.app.json_output import emit_json
from scenenav.core.config import check
from scenenav.core.formats.run_folder import MAVLINK_FILE

log = logging.getLogger(__name__)

#: Issue 14: memory growth allowed between minute 5 and the end.
MEMORY_GROWTH_LIMIT = 0.10
BASELINE_SIM_S = 300.0
SCENARIO = Path(__file__).resolve().parents[3] / "scenarios" / "gps_denied.yaml"
RENDER_WORKER = "sim/render_worker"
#: Wall seconds a process runs before it is sampled (a new perception node loads its CNN first).
SETTLE_WALL_S = 20.0
#: The node ids a perception swap alternates between.
PERCEPTION_ROLES = ("perception", "perception-2")
#: Samples whose smallest fd count is a process's fd floor at minute 5 and at the end. Zenoh opens
#: and closes sockets and other peers' shared-memory segments as it goes (seen here: the autopilot
#: between 31 and 35 fds from one sample to the next, always back to 31): a leak raises the floor,
#: a transient fd does not.
FD_FLOOR_SAMPLES = 6


@dataclass(frozen=True)
class SoakConfig:
    duration_s: float = 1800.0          # simulated seconds
    swap_every_s: float = 120.0         # simulated seconds between perception swaps
    fuzz_frames_per_min: int = 10000    # garbage MAVLink frames a minute (simulated or wall, whichever is more)
    sample_period_s: float = 5.0        # wall seconds between /proc samples
    seed: int = 2
    baseline_s: float = BASELINE_SIM_S  # simulated time of the baseline sample (issue 14: minute 5)

    def __post_init__(self) -> None:
        check(math.isfinite(self.baseline_s) and 1.0 <= self.baseline_s <= 3600.0, "baseline_s",
              self.baseline_s, "1 .. 3600 simulated s")
        check(math.isfinite(self.duration_s) and self.baseline_s + 10.0 <= self.duration_s <= 4 * 3600.0,
              "duration_s", self.duration_s,
              f"{self.baseline_s + 10.0:.0f} .. 14400 simulated s (at least 10 s after the baseline at "
              f"{self.baseline_s:.0f} s)")
        check(10.0 <= self.swap_every_s <= self.duration_s, "swap_every_s", self.swap_every_s,
              "10 s .. the duration")
        check(0 <= self.fuzz_frames_per_min <= 600_000, "fuzz_frames_per_min", self.fuzz_frames_per_min,
              "0 .. 600000")
        check(0.5 <= self.sample_period_s <= 60.0, "sample_period_s", self.sample_period_s, "0.5 .. 60 s")


@dataclass
class Sample:
    sim_time_s: float
    rss_mb: float
    fds: int
    #: what the fds are (``fd_kinds``: socket, pipe, shm, anon, file, dev, other -> count)
    fd_kinds: dict[str, int] = field(default_factory=dict)
    #: what its TCP sockets are (``tcp_sockets``: "listen", "<state> <what>" -> count)
    tcp: dict[str, int] = field(default_factory=dict)


@dataclass
class RoleFigures:
    role: str
    at_minute_5: Sample | None = None
    at_end: Sample | None = None
    peak_rss_mb: float = 0.0
    #: fd counts of the first ``FD_FLOOR_SAMPLES`` samples from minute 5 on, and of the newest ones
    fds_from_minute_5: list[int] = field(default_factory=list)
    fds_last: list[int] = field(default_factory=list)
    #: the fd kinds of the floor sample (the fewest fds) at minute 5 and at the end
    kinds_minute_5: dict[str, int] = field(default_factory=dict)
    kinds_end: dict[str, int] = field(default_factory=dict)
    #: the TCP sockets of those two floor samples
    tcp_minute_5: dict[str, int] = field(default_factory=dict)
    tcp_end: dict[str, int] = field(default_factory=dict)
    _end_kinds: list[dict[str, int]] = field(default_factory=list, repr=False)
    _end_tcp: list[dict[str, int]] = field(default_factory=list, repr=False)

    def add(self, sample: Sample, baseline: bool, end: bool) -> None:
        """Record a steady sample: ``baseline`` once minute 5 is reached, ``end`` up to the end window."""
        if baseline:
            if self.at_minute_5 is None:
                self.at_minute_5 = sample
            if len(self.fds_from_minute_5) < FD_FLOOR_SAMPLES:
                if not self.fds_from_minute_5 or sample.fds < min(self.fds_from_minute_5):
                    self.kinds_minute_5 = dict(sample.fd_kinds)
                    self.tcp_minute_5 = dict(sample.tcp)
                self.fds_from_minute_5.append(sample.fds)
        if end:
            self.at_end = sample
            self.fds_last = [*self.fds_last, sample.fds][-FD_FLOOR_SAMPLES:]
            self._end_kinds = [*self._end_kinds, dict(sample.fd_kinds)][-FD_FLOOR_SAMPLES:]
            self._end_tcp = [*self._end_tcp, dict(sample.tcp)][-FD_FLOOR_SAMPLES:]
            floor = min(range(len(self.fds_last)), key=lambda i: (self.fds_last[i], -i))
            self.kinds_end = self._end_kinds[floor]
            self.tcp_end = self._end_tcp[floor]

    @property
    def memory_growth(self) -> float | None:
        if self.at_minute_5 is None or self.at_end is None or self.at_minute_5.rss_mb <= 0:
            return None
        return self.at_end.rss_mb / self.at_minute_5.rss_mb - 1.0

    @property
    def fd_floor_minute_5(self) -> int | None:
        return min(self.fds_from_minute_5) if self.fds_from_minute_5 else None

    @property
    def fd_floor_end(self) -> int | None:
        return min(self.fds_last) if self.fds_last else None

    @property
    def fd_growth(self) -> int | None:
        """Growth of the fd floor (the fewest fds over ``FD_FLOOR_SAMPLES`` samples) from minute 5
        to the end."""
        if self.fd_floor_minute_5 is None or self.fd_floor_end is None:
            return None
        return self.fd_floor_end - self.fd_floor_minute_5


@dataclass
class SoakResult:
    config: SoakConfig
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    end_reason: str = ""
    swaps: int = 0
    fuzz_frames_sent: int = 0
    mavlink_frames_dropped: int | None = None
    ticks: int = 0
    ticks_expected: int = 0
    lockstep_timeouts: int | None = None
    autopilot_ticks_out_of_order: int | None = None
    roles: list[RoleFigures] = field(default_factory=list)

    @property
    def memory_ok(self) -> bool:
        growths = [r.memory_growth for r in self.roles]
        return bool(growths) and all(g is not None and g <= MEMORY_GROWTH_LIMIT for g in growths)

    @property
    def fds_ok(self) -> bool:
        growths = [r.fd_growth for r in self.roles]
        return bool(growths) and all(g is not None and g <= 0 for g in growths)

    @property
    def ticks_ok(self) -> bool:
        return (self.lockstep_timeouts == 0 and self.autopilot_ticks_out_of_order == 0
                and self.ticks >= self.ticks_expected)

    def to_dict(self) -> dict:
        return {
            "config": asdict(self.config), "sim_time_s": round(self.sim_time_s, 1),
            "wall_time_s": round(self.wall_time_s, 1), "end_reason": self.end_reason,
            "swaps": self.swaps, "fuzz_frames_sent": self.fuzz_frames_sent,
            "mavlink_frames_dropped": self.mavlink_frames_dropped, "ticks": self.ticks,
            "ticks_expected": self.ticks_expected, "lockstep_timeouts": self.lockstep_timeouts,
            "autopilot_ticks_out_of_order": self.autopilot_ticks_out_of_order,
            "memory_within_10_percent": self.memory_ok, "no_fd_growth": self.fds_ok,
            "no_dropped_tick": self.ticks_ok,
            "roles": [{"role": r.role,
                       "rss_mb_at_minute_5": None if r.at_minute_5 is None else round(r.at_minute_5.rss_mb, 1),
                       "rss_mb_at_end": None if r.at_end is None else round(r.at_end.rss_mb, 1),
                       "peak_rss_mb": round(r.peak_rss_mb, 1),
                       "memory_growth": None if r.memory_growth is None else round(r.memory_growth, 4),
                       "fds_at_minute_5": r.fd_floor_minute_5, "fds_at_end": r.fd_floor_end,
                       "fd_growth": r.fd_growth, "fd_kinds_at_minute_5": r.kinds_minute_5,
                       "fd_kinds_at_end": r.kinds_end, "tcp_at_minute_5": r.tcp_minute_5,
                       "tcp_at_end": r.tcp_end} for r in self.roles],
        }


# ------------------------------------------------------------------------------------------ /proc
def _rss_mb(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _fd_count(pid: int) -> int | None:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


# fd link target prefix -> kind, first match wins (``/dev/shm/`` before ``/dev/`` before ``/``)
_FD_KINDS = (("socket:", "socket"), ("pipe:", "pipe"), ("anon_inode:", "anon"), ("/dev/shm/", "shm"),
             ("/dev/", "dev"), ("/", "file"))


def fd_kind(target: str) -> str:
    """The kind of an fd from its ``/proc/PID/fd`` link target."""
    return next((kind for prefix, kind in _FD_KINDS if target.startswith(prefix)), "other")


def fd_kinds(pid: int) -> dict[str, int]:
    """How many fds of each kind (:func:`fd_kind`) the process holds (empty if it is gone)."""
    out: dict[str, int] = {}
    try:
        names = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return out
    for name in names:
        try:
            kind = fd_kind(os.readlink(f"/proc/{pid}/fd/{name}"))
        except OSError:
            continue
        out[kind] = out.get(kind, 0) + 1
    return dict(sorted(out.items()))


# /proc/net/tcp state codes (include/net/tcp_states.h)
_TCP_STATES = {"01": "established", "02": "syn-sent", "03": "syn-recv", "04": "fin-wait1", "05": "fin-wait2",
               "06": "time-wait", "07": "close", "08": "close-wait", "09": "last-ack", "0A": "listen",
               "0B": "closing"}


def tcp_sockets(pid: int, named_ports: dict[int, str] | None = None) -> dict[str, int]:
    """The process's TCP sockets by state and far end: ``"listen"``, or ``"<state> <name>"`` where
    the name is ``named_ports``' name of the local or remote port (e.g. the Zenoh hub, the MAVLink
    port), else ``"peer"`` (empty if the process is gone)."""
    named = named_ports or {}
    try:
        names = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return {}
    inodes = set()
    for name in names:
        try:
            target = os.readlink(f"/proc/{pid}/fd/{name}")
        except OSError:
            continue      # closed meanwhile (the listing's own fd, for one)
        if target.startswith("socket:["):
            inodes.add(target[len("socket:["):-1])
    out: dict[str, int] = {}
    for table in ("tcp", "tcp6"):
        try:
            with open(f"/proc/{pid}/net/{table}") as f:
                rows = f.read().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            cols = row.split()
            if len(cols) < 10 or cols[9] not in inodes:
                continue
            state = _TCP_STATES.get(cols[3], cols[3])
            lport, rport = int(cols[1].rsplit(":", 1)[1], 16), int(cols[2].rsplit(":", 1)[1], 16)
            key = "listen" if state == "listen" else \
                f"{state} {named.get(lport) or named.get(rport) or 'peer'}"
            out[key] = out.get(key, 0) + 1
    return dict(sorted(out.items()))


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(x) for x in f.read().split()]
    except OSError:
        return []


def _last_sim_time(run_dir: Path) -> float | None:
    try:
        with (run_dir / "truth.csv").open("rb") as f:
            f.seek(max(0, (run_dir / "truth.csv").stat().st_size - 400))
            return float(f.read().splitlines()[-1].split(b",")[0])
    except (OSError, ValueError, IndexError):
        return None


class Sampler(threading.Thread):
    """Samples every role's RSS and fds; keeps the sample nearest minute 5 and the newest one."""

    def __init__(self, run_dir: Path, cfg: SoakConfig) -> None:
        super().__init__(name="soak-sampler", daemon=True)
        self.run_dir = run_dir
        self.cfg = cfg
        self.stop = threading.Event()
        self.roles: dict[str, RoleFigures] = {}

    def _pids(self) -> dict[str, int]:
        """Role -> pid of every live process of the run. The two perception node ids keep their
        own roles, each new process of a role replacing the last."""
        try:
            pids = json.loads((self.run_dir / "logs" / "pids.json").read_text())
        except (OSError, ValueError):
            return {}
        out = {name: pid for name, pid in pids.items() if _rss_mb(pid) is not None}
        sim = pids.get("sim")
        if sim is not None:
            for child in _children(sim):
                out[RENDER_WORKER] = child
        return out

    def _named_ports(self) -> dict[int, str]:
        """The run's known TCP ports (run.json): the Zenoh hub and the autopilot's MAVLink port."""
        try:
            meta = json.loads((self.run_dir / "run.json").read_text())
        except (OSError, ValueError):
            return {}
        ports = {meta.get("hub_port"): "zenoh hub", meta.get("mavlink_tcp_port"): "mavlink"}
        return {int(p): name for p, name in ports.items() if isinstance(p, int) and p > 0}

    def run(self) -> None:
        end_window_s = self.cfg.duration_s - 3.0 * self.cfg.sample_period_s
        first_seen: dict[int, float] = {}
        while not self.stop.wait(self.cfg.sample_period_s):
            t = _last_sim_time(self.run_dir)
            if t is None:
                continue
            now = time.monotonic()
            pids = self._pids()
            # Every node holds a Zenoh connection to each other node (peers gossip and connect
            # directly), so each process's fd count follows how many nodes are alive: during a
            # perception handover two perception processes are. Minute 5 and the end are compared
            # only at steady moments, one perception node alive, so like is compared with like.
            steady = sum(1 for role in pids if role in PERCEPTION_ROLES) <= 1
            for role, pid in pids.items():
                # a process is compared once it settled (loaded its models, opened its files)
                if now - first_seen.setdefault(pid, now) < SETTLE_WALL_S:
                    continue
                rss, fds = _rss_mb(pid), _fd_count(pid)
                if rss is None or fds is None:
                    continue
                fig = self.roles.setdefault(role, RoleFigures(role))
                fig.peak_rss_mb = max(fig.peak_rss_mb, rss)
                sample = Sample(t, rss, fds, fd_kinds(pid), tcp_sockets(pid, self._named_ports()))
                if steady:
                    fig.add(sample, baseline=t >= self.cfg.baseline_s, end=t <= end_window_s)


# ------------------------------------------------------------------------------------------ fuzz
def _garbage_frame(rng: random.Random) -> bytes:
    kind = rng.random()
    if kind < 0.6:      # a MAVLink v2 frame, random message id and payload, wrong checksum
        payload = rng.randbytes(rng.randint(0, 255))
        header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, rng.randint(0, 255), 255, 190,
                             rng.randint(0, 0xFFFF), rng.randint(0, 0xFF))
        return header + payload + struct.pack("<H", rng.randint(0, 0xFFFF))
    if kind < 0.8:      # a truncated frame
        return bytes([0xFD, rng.randint(10, 255)]) + rng.randbytes(rng.randint(0, 8))
    return rng.randbytes(rng.randint(1, 64))    # stray bytes


class Fuzzer(threading.Thread):
    """Sends ``fuzz_frames_per_min`` garbage frames a minute (simulated or wall minute, whichever
    gives more) to the run's MAVLink TCP port."""

    def __init__(self, run_dir: Path, cfg: SoakConfig) -> None:
        super().__init__(name="soak-fuzzer", daemon=True)
        self.run_dir = run_dir
        self.cfg = cfg
        self.stop = threading.Event()
        self.sent = 0
        self.wall_s = 0.0      # since the MAVLink port appeared
        self.sim_s = 0.0       # simulated time last seen in truth.csv

    def _port(self) -> int | None:
        try:
            return int(json.loads((self.run_dir / MAVLINK_FILE).read_text())["tcp_port"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def due(self, wall_s: float, sim_s: float) -> int:
        """Frames that should have been sent by now: ``fuzz_frames_per_min`` a minute of simulated
        time or of wall time, whichever is more (the run may be slower or faster than real time)."""
        return int(self.cfg.fuzz_frames_per_min * max(wall_s, sim_s) / 60.0)

    def run(self) -> None:
        rng = random.Random(self.cfg.seed)
        max_burst = max(1, self.cfg.fuzz_frames_per_min // 60)     # at most a second's worth at once
        sock = None
        t0 = time.monotonic()
        sim_s = 0.0
        while not self.stop.wait(0.1):
            if self.cfg.fuzz_frames_per_min == 0:
                return
            if sock is None:
                port = self._port()
                if port is None:
                    t0 = time.monotonic()       # the count starts when the port is there
                    continue
                try:
                    sock = socket.create_connection(("127.0.0.1", port), timeout=2.0)
                except OSError:
                    sock = None
                    continue
            sim_s = _last_sim_time(self.run_dir) or sim_s
            self.wall_s = time.monotonic() - t0
            self.sim_s = sim_s
            burst = min(max_burst, self.due(self.wall_s, sim_s) - self.sent)
            if burst <= 0:
                continue
            try:
                sock.sendall(b"".join(_garbage_frame(rng) for _ in range(burst)))
                self.sent += burst
            except OSError:
                sock.close()
                sock = None
        if sock is not None:
            sock.close()


# ------------------------------------------------------------------------------------------ run
def soak_scenario(cfg: SoakConfig) -> dict:
    """scenarios/gps_denied.yaml without guidance (its goals define the lap), for ``duration_s``."""
    data = yaml.safe_load(SCENARIO.read_text())
    data["name"] = "soak"
    data["seed"] = cfg.seed
    data["duration_s"] = cfg.duration_s
    data.pop("guidance", None)
    data.setdefault("autopilot", {})["mission_end"] = "rtl"
    # both nodes run the CNN, so the navigation stays what gps_denied.yaml flies; every swap is a
    # new process
    data.setdefault("perception", {}).update({"method": "cnn", "swap_at_s": cfg.swap_every_s,
                                              "swap_every_s": cfg.swap_every_s, "swap_method": "cnn"})
    return data


def _lap_route(cfg: SoakConfig) -> list[list[float]]:
    """gps_denied.yaml's guided loop (home through its goals), planned once as the guidance node
    plans it, repeated for ``duration_s`` at its cruise speed."""
    from guidance.planner import join_legs, plan_through
    from scenenav.app.launcher import resolve_guidance_map
    from scenenav.app.nodes import guidance_config_from_scenario, load_world_for
    from scenenav.app.scenario import load_scenario
    from scenenav.core.formats.assistant_map_file import read_probability_map
    scen = resolve_guidance_map(load_scenario(SCENARIO), progress=False)
    run_cfg, planner_cfg = guidance_config_from_scenario(scen, 0, lockstep=True)
    world = load_world_for(scen)
    probability = read_probability_map(scen.guidance.assistant_map).probability
    lap = join_legs(plan_through(probability, world.m_per_px,
                                 (tuple(run_cfg.start_enu_m), *run_cfg.goals_enu_m), planner_cfg))
    length = sum(math.dist(a, b) for a, b in zip(lap, lap[1:], strict=False))
    laps = int(math.ceil(cfg.duration_s * scen.flight.speed_m_s / max(length, 1.0))) + 1
    return [[float(x), float(y)] for x, y in lap[1:]] * laps


def run_soak(cfg: SoakConfig, out_dir: Path | None = None, progress: bool = True) -> SoakResult:
    from scenenav.app import launcher
    from scenenav.core.bus import free_port
    work = Path(out_dir) if out_dir else Path(tempfile.mkdtemp(prefix="scenenav-soak-"))
    work.mkdir(parents=True, exist_ok=True)
    run_dir = work / "run"
    data = soak_scenario(cfg)
    data["flight"]["route_enu_m"] = _lap_route(cfg)
    data.setdefault("autopilot", {}).update({"mavlink_tcp_port": free_port(), "mavlink_udp_out": "none"})
    scen_path = work / "soak.yaml"
    scen_path.write_text(yaml.safe_dump(data, sort_keys=False))
    result = SoakResult(cfg)
    sampler, fuzzer = Sampler(run_dir, cfg), Fuzzer(run_dir, cfg)
    sampler.start()
    fuzzer.start()
    t0 = time.monotonic()
    try:
        summary = launcher.run(str(scen_path), str(run_dir), (), progress=progress)
    finally:
        sampler.stop.set()
        fuzzer.stop.set()
        sampler.join(10)
        fuzzer.join(10)
    result.wall_time_s = time.monotonic() - t0
    result.end_reason = str(summary.get("end_reason"))
    result.sim_time_s = _last_sim_time(run_dir) or 0.0
    result.fuzz_frames_sent = fuzzer.sent
    result.roles = sorted(sampler.roles.values(), key=lambda r: r.role)
    sim_stats = _read_json(run_dir / "sim_stats.json")
    ap_stats = _read_json(run_dir / "autopilot_stats.json")
    result.ticks = int(sim_stats.get("ticks", 0))
    result.ticks_expected = int(round(cfg.duration_s * 100.0))
    result.lockstep_timeouts = sim_stats.get("ack_timeouts")
    # the node writes its counters at exit; a counter that never counted is not in the file
    result.autopilot_ticks_out_of_order = int(ap_stats.get("clock_out_of_order", 0)) if ap_stats else None
    mav = ap_stats.get("mavlink", {})
    if isinstance(mav, dict):
        result.mavlink_frames_dropped = sum(int(mav.get(k, 0)) for k in ("bad_crc", "parse_errors", "unknown",
                                                                         "truncated"))
    result.swaps = max(0, _read_text(run_dir / "events.csv").count("node up: perception/") - 1)
    return result


def _read_text(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def _per_min(count: int, seconds: float) -> float:
    return count * 60.0 / seconds if seconds > 0 else 0.0


def format_table(r: SoakResult) -> str:
    c = r.config
    lines = [f"soak: {r.sim_time_s:.0f} simulated s in {r.wall_time_s:.0f} wall s ({r.end_reason}); "
             f"{r.swaps} perception swaps (every {c.swap_every_s:.0f} s); {r.fuzz_frames_sent} fuzz frames "
             f"(asked {c.fuzz_frames_per_min}/min; sent {_per_min(r.fuzz_frames_sent, r.sim_time_s):.0f} per "
             f"simulated min, {_per_min(r.fuzz_frames_sent, r.wall_time_s):.0f} per wall min)",
             f"{'process':<20} {'RSS min 5':>10} {'RSS end':>9} {'growth':>8} {'peak':>8} "
             f"{'fds min 5':>9} {'fds end':>8}  (fds: the fewest over {FD_FLOOR_SAMPLES} samples, and their range)"]
    for f in r.roles:
        g = f.memory_growth
        lines.append(f"{f.role:<20} {_mb(f.at_minute_5):>10} {_mb(f.at_end):>9} "
                     f"{'-' if g is None else f'{100 * g:+.1f} %':>8} {f.peak_rss_mb:>6.0f} MB "
                     f"{_fds(f.fd_floor_minute_5):>9} {_fds(f.fd_floor_end):>8}  "
                     f"{_fd_range(f.fds_from_minute_5)} / {_fd_range(f.fds_last)}")
    for f in r.roles:
        if f.fd_growth:
            lines.append(f"{f.role} fds by kind, floor at minute 5 -> at the end: {_kinds(f.kinds_minute_5)} -> "
                         f"{_kinds(f.kinds_end)}")
            lines.append(f"{f.role} TCP sockets, same samples: {_kinds(f.tcp_minute_5)} -> {_kinds(f.tcp_end)}")
    lines.append(f"ticks {r.ticks} of {r.ticks_expected}; lockstep answers timed out: {r.lockstep_timeouts}; "
                 f"autopilot ticks out of order: {r.autopilot_ticks_out_of_order}; MAVLink frames dropped "
                 f"(bad CRC or unparsable): {r.mavlink_frames_dropped}")
    lines.append(f"targets: memory within 10 % of minute 5: {'yes' if r.memory_ok else 'NO'}; "
                 f"no fd growth: {'yes' if r.fds_ok else 'NO'}; no dropped tick: {'yes' if r.ticks_ok else 'NO'}")
    return "\n".join(lines)


def _kinds(kinds: dict[str, int]) -> str:
    return ", ".join(f"{k} {n}" for k, n in kinds.items()) or "-"


def _fds(n: int | None) -> str:
    return "-" if n is None else str(n)


def _fd_range(fds: list[int]) -> str:
    return f"{min(fds)}-{max(fds)}" if fds else "-"


def _mb(s: Sample | None) -> str:
    return "-" if s is None else f"{s.rss_mb:.0f} MB"


def _cmd_bench_soak(args: argparse.Namespace) -> int:
    cfg = SoakConfig(duration_s=args.duration_s, swap_every_s=args.swap_every_s,
                     fuzz_frames_per_min=args.fuzz_per_min, baseline_s=args.baseline_s)
    result = run_soak(cfg, Path(args.out) if args.out else None, progress=not args.json)
    if args.json:
        emit_json(result.to_dict())
    else:
        print(format_table(result))
    sys.stdout.flush()
    return 0


def register_bench(bench_subparsers) -> None:
    """Add ``soak`` to the ``scenenav bench`` sub-commands."""
    p = bench_subparsers.add_parser(
        "soak", help="30 simulated minutes of GPS-denied flying with perception swaps and MAVLink fuzz; "
                     "memory, file descriptors and lockstep ticks afterwards (not part of make test)",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration-s", type=float, default=SoakConfig.duration_s,
                   help="simulated seconds to fly (default 1800)")
    p.add_argument("--swap-every-s", type=float, default=SoakConfig.swap_every_s,
                   help="simulated seconds between perception swaps (default 120)")
    p.add_argument("--fuzz-per-min", type=int, default=SoakConfig.fuzz_frames_per_min,
                   help="garbage MAVLink frames a minute on the TCP port (default 10000)")
    p.add_argument("--baseline-s", type=float, default=SoakConfig.baseline_s,
                   help="simulated time of the baseline sample the end is compared with (default 300)")
    p.add_argument("--out", default="", help="keep the run folder here (default: a temporary folder)")
    p.add_argument("--json", action="store_true", help="print only JSON on stdout instead of a table")
    p.set_defaults(func=_cmd_bench_soak)
