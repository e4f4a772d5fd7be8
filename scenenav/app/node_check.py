"""``scenenav node check ROLE -- COMMAND...``: does a node someone wrote keep the bus contract?

The check flies a short lockstep run (``scenenav run --external ROLE:ID``, by default the scripted
flight over the default world), starts COMMAND once the run's ``run.json`` exists (``{run_dir}``
and ``{node_id}`` in COMMAND are replaced; the environment has ``SCENENAV_RUN_DIR`` and
``SCENENAV_NODE_ID``), watches the bus with its own Zenoh session, sends the node malformed camera
frames part-way, and judges each rule of docs/interfaces.md ("Conformance") with a reason:

* ``liveliness``: ``nodes/<role>/<id>`` and ``lockstep/member/camera/<id>`` declared, the clock started with them;
* ``acks``: a LockstepAck (role camera, the frame's seq) for every frame within ``--ack-timeout-s``;
* ``fixes``: a VisionFix for every frame (valid or not), published before the frame's ack, or (a
  node that holds its fixes, like the built-in one with ``perception.confirm_successors``) before the
  ack of a frame captured at most ``HELD_FIX_MAX_AGE_S`` later;
* ``encoding``: every message on the node's keys decodes with the real codec (type, version, fields);
* ``timestamps``: fix and ack carry the frame's capture time, ``frame_seq`` and ``node_id`` are right;
* ``fields``: ranges and units (positions on the map, probabilities in [0, 1], times >= 0, ...);
* ``covariance``: the 2x2 covariance of each valid fix is finite, symmetric, positive semi-definite;
* ``malformed``: after the malformed frames the node still runs, stays live and answers the next frames;
* ``leaves``: the node exits by itself, with code 0, after the run's last ClockTick (state finished).

Only the ``perception`` role has a conformance profile so far.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from autopilot_bridge.config import FlightCoreConfig
from scenenav.app.launcher import RUN_FILE
from scenenav.core.bus import Bus, BusConfig
from scenenav.core.contracts import (
    CameraFrame,
    ClockTick,
    DecodeError,
    LockstepAck,
    LockstepRole,
    RunState,
    VisionFix,
    decode,
)
from scenenav.core.errors import UserError
from scenenav.core.keys import Keys, check_name

log = logging.getLogger(__name__)

ROLES = ("perception",)
#: A held fix must leave before the ack of a frame captured at most this much later: the autopilot
#: fuses no fix older than its vision_max_age_s.
HELD_FIX_MAX_AGE_S = FlightCoreConfig.vision_max_age_s
RULES = ("liveliness", "acks", "fixes", "encoding", "timestamps", "fields", "covariance", "malformed",
         "leaves")
#: Answers the node gives before the check sends it the malformed frames.
INJECT_AFTER_ACKS = 10
#: Wall seconds the node may take to leave after the run's end.
LEAVE_TIMEOUT_S = 10.0
#: A node seen gone up to this long before the check saw the last ClockTick still left on it (s).
LEAVE_EARLY_TOL_S = 0.5
#: Wall seconds to wait for run.json (the run's hub) after the launcher started.
RUN_JSON_TIMEOUT_S = 240.0
#: What the simulator logs when a lockstep member it expected was not there when its clock started.
SIM_MEMBERS_LATE = "not every expected node joined"
#: Wall seconds the check run waits for the node to declare its token.
JOIN_TIMEOUT_S = 60.0
#: Frames the node must answer after the malformed ones to pass ``malformed``.
ANSWERS_AFTER_MALFORMED = 3
#: Relative tolerance of the covariance symmetry and of the smallest eigenvalue (PSD).
COV_REL_TOL = 1e-6
#: How far outside the map a valid fix may lie (a match at the edge of the reference), metres.
MAP_MARGIN_M = 200.0


def malformed_frames() -> list[tuple[str, bytes]]:
    """Payloads on ``sensors/camera`` that are not CameraFrames (docs/interfaces.md, section 3)."""
    def frame(header: dict, n_pixel_bytes: int) -> bytes:
        h = json.dumps({"type": "CameraFrame", "version": CameraFrame.VERSION, "timestamp_us": 0, "seq": 0,
                        "width_px": 4, "height_px": 4, "encoding": "rgb8", "fov_deg": 60.0, "mount": "gimbal",
                        "intrinsics_fx_fy_cx_cy_px": [3.46, 3.46, 2.0, 2.0],
                        "distortion_k1_k2_p1_p2": [0.0, 0.0, 0.0, 0.0], **header}).encode()
        return len(h).to_bytes(4, "little") + h + bytes(n_pixel_bytes)
    return [
        ("truncated length", b"\x05\x00"),
        ("header length beyond the payload", (1000).to_bytes(4, "little") + b"{}"),
        ("header not JSON", (9).to_bytes(4, "little") + b"not json!" + bytes(48)),
        ("unknown version", frame({"version": 99}, 48)),
        ("seq not an integer", frame({"seq": None}, 48)),
        ("pixel bytes do not match the size", frame({}, 47)),
    ]


@dataclass
class RuleResult:
    rule: str
    passed: bool
    detail: str

    def to_dict(self) -> dict:
        return {"rule": self.rule, "passed": self.passed, "detail": self.detail}


@dataclass
class Observed:
    """What the check's own session saw on the bus (wall times: ``time.monotonic``)."""

    frames: dict[int, tuple[float, int]] = field(default_factory=dict)     # seq -> (wall, capture us)
    fixes: list[tuple[float, VisionFix]] = field(default_factory=list)
    acks: list[tuple[float, LockstepAck]] = field(default_factory=list)
    bad: list[tuple[str, str]] = field(default_factory=list)               # (key, why) undecodable
    tokens: list[tuple[float, str, bool]] = field(default_factory=list)
    finished_at: float | None = None
    injected_at: float | None = None
    last_seq_before_inject: int = -1


class Observer:
    """A Zenoh session on the run's bus recording the node's traffic; sends the malformed frames."""

    def __init__(self, bus_cfg: BusConfig, role: str, node_id: str):
        self.keys = Keys(bus_cfg.namespace)
        self.node_id = node_id
        self.seen = Observed()
        self.lock = threading.Lock()
        self.bus = Bus(bus_cfg)
        k = self.keys
        self.bus.subscribe_raw(k.camera, self._on_frame)
        self.bus.subscribe_raw(k.vision_fix(node_id), self._on_fix)
        self.bus.subscribe_raw(k.lockstep_ack(node_id), self._on_ack)
        self.bus.subscribe(k.clock, ClockTick, self._on_clock)
        for key in (k.node_alive(role, node_id), k.lockstep_member(LockstepRole.CAMERA, node_id)):
            self.bus.watch_liveliness(key, self._on_token)

    def _on_frame(self, payload: bytes, _key: str) -> None:
        try:
            f = decode(CameraFrame, payload)
        except DecodeError:
            return          # our own malformed frames come back here
        with self.lock:
            self.seen.frames.setdefault(f.seq, (time.monotonic(), f.timestamp_us))

    def _decode_into(self, cls: type, payload: bytes, key: str, into: list) -> None:
        try:
            msg = decode(cls, payload)
        except DecodeError as exc:
            with self.lock:
                self.seen.bad.append((key, str(exc)))
            return
        with self.lock:
            into.append((time.monotonic(), msg))

    def _on_fix(self, payload: bytes, key: str) -> None:
        self._decode_into(VisionFix, payload, key, self.seen.fixes)

    def _on_ack(self, payload: bytes, key: str) -> None:
        self._decode_into(LockstepAck, payload, key, self.seen.acks)
        with self.lock:
            due = len(self.seen.acks) == INJECT_AFTER_ACKS and self.seen.injected_at is None
            if due:
                self.seen.injected_at = time.monotonic()
                self.seen.last_seq_before_inject = max(self.seen.frames, default=-1)
        if due:   # not from Zenoh's receive thread: a blocking publish there could stall it
            threading.Thread(target=self._inject, daemon=True).start()

    def _inject(self) -> None:
        for _name, payload in malformed_frames():
            self.bus.put_raw(self.keys.camera, payload)

    def _on_clock(self, msg: ClockTick, _key: str) -> None:
        if msg.state == RunState.FINISHED.value:
            with self.lock:
                if self.seen.finished_at is None:
                    self.seen.finished_at = time.monotonic()

    def _on_token(self, key: str, alive: bool) -> None:
        with self.lock:
            self.seen.tokens.append((time.monotonic(), key, alive))

    def close(self) -> None:
        self.bus.close()


# ------------------------------------------------------------------------------------ the rules
def _first(items: list, n: int = 3) -> str:
    return ", ".join(str(i) for i in items[:n]) + (" ..." if len(items) > n else "")


@dataclass(frozen=True)
class RunSide:
    """What the run itself saw of the node (its simulator's files): did the clock start with it?"""

    joined_before_clock: bool = True     # external.json: the simulator saw nodes/<role>/<id> first
    member_at_start: bool = True         # no "not every expected node joined" from the simulator


def judge(seen: Observed, keys: Keys, role: str, node_id: str, ack_timeout_s: float,
          map_half_extent_m: tuple[float, float], node_alive_after_inject: bool | None,
          exit_code: int | None, left_after_s: float | None, run: RunSide = RunSide()) -> list[RuleResult]:
    """Every rule of the perception profile from what was observed (pure: unit-testable).

    Liveliness is judged from the run's side (the simulator waited for the tokens before its
    clock started): the check's own session may see a token after the first frame, since tokens
    and samples from different peers reach it by different paths."""
    out: list[RuleResult] = []
    frames = seen.frames
    node_key = keys.node_alive(role, node_id)
    member_key = keys.lockstep_member(LockstepRole.CAMERA, node_id)
    short = {k: k.split("/", 2)[2] for k in (node_key, member_key)}
    never = [short[k] for k in (node_key, member_key)
             if not any(key == k and alive for _, key, alive in seen.tokens)]
    problems = []
    if not frames:
        problems.append("no camera frame was published")
    if never:
        problems.append(f"never declared: {', '.join(never)}")
    if not run.joined_before_clock:
        problems.append(f"the run's clock did not start with {short[node_key]} (not declared in time)")
    if not run.member_at_start:
        problems.append(f"the simulator started without {short[member_key]} (declare it before "
                        f"{short[node_key]})")
    out.append(RuleResult("liveliness", not problems, "; ".join(problems) or
                          f"{short[node_key]} and {short[member_key]} declared; the clock started with them"))

    acks: dict[int, float] = {}
    wrong_role = []
    for t, a in seen.acks:
        if a.role != LockstepRole.CAMERA.value:
            wrong_role.append(a.seq)
        acks.setdefault(a.seq, t)
    missing = sorted(s for s in frames if s not in acks)
    slow = sorted(s for s in frames if s in acks and acks[s] - frames[s][0] > ack_timeout_s)
    unknown = sorted(s for s in acks if s not in frames)
    problems = []
    if missing:
        problems.append(f"{len(missing)} of {len(frames)} frames never acknowledged (seq {_first(missing)})")
    if slow:
        problems.append(f"{len(slow)} acknowledged later than {ack_timeout_s:g} s (seq {_first(slow)})")
    if wrong_role:
        problems.append(f"role not 'camera' in the acks of seq {_first(wrong_role)}")
    if unknown:
        problems.append(f"acks of frames never published (seq {_first(unknown)})")
    if not frames:
        problems.append("no camera frame was published: nothing was acknowledged")
    out.append(RuleResult("acks", bool(frames) and not problems, "; ".join(problems) or
                          f"all {len(frames)} frames acknowledged within {ack_timeout_s:g} s"))

    fixes: dict[int, tuple[float, VisionFix]] = {}
    for t, f in seen.fixes:
        fixes.setdefault(f.frame_seq, (t, f))
    no_fix = sorted(s for s in frames if s not in fixes)
    def held_in_time(seq: int, t: float) -> bool:
        """A held fix (published with a later frame's answer) came before the ack of a frame
        captured at most HELD_FIX_MAX_AGE_S after its own."""
        cap = frames[seq][1]
        return any(s2 > seq and 0 <= frames[s2][1] - cap <= HELD_FIX_MAX_AGE_S * 1e6 and t <= acks.get(s2, -math.inf)
                   for s2 in frames)
    after_ack = sorted(s for s, (t, _) in fixes.items()
                       if s in acks and t > acks[s] and (s not in frames or not held_in_time(s, t)))
    n_valid = sum(1 for _, f in fixes.values() if f.valid)
    problems = []
    if no_fix:
        problems.append(f"{len(no_fix)} of {len(frames)} frames without a VisionFix (seq {_first(no_fix)}); "
                        "publish valid: false when there is no match")
    if after_ack:
        problems.append(f"the fix came after the ack for seq {_first(after_ack)} (publish the fix first, "
                        f"from the same session; a held fix before the ack of a frame at most "
                        f"{HELD_FIX_MAX_AGE_S:g} s younger)")
    if not frames:
        problems.append("no camera frame was published: no fix was due")
    out.append(RuleResult("fixes", bool(frames) and not problems, "; ".join(problems) or
                          f"a VisionFix for every frame ({n_valid} valid, {len(fixes) - n_valid} invalid)"))

    # the rules below judge what the node sent: with nothing sent they cannot pass
    nothing = "" if (seen.fixes or seen.acks) else "no fix or ack came from the node: nothing to judge"
    out.append(RuleResult("encoding", not seen.bad and not nothing,
                          f"{len(seen.bad)} undecodable messages, first on {seen.bad[0][0]}: {seen.bad[0][1]}"
                          if seen.bad else nothing or f"{len(seen.fixes)} fixes and {len(seen.acks)} acks decode"))

    problems = []
    bad_t = [f.frame_seq for _, f in fixes.values()
             if f.frame_seq in frames and f.timestamp_us != frames[f.frame_seq][1]]
    if bad_t:
        s = bad_t[0]
        problems.append(f"VisionFix.timestamp_us is not the frame's capture time for seq {_first(bad_t)} "
                        f"(seq {s}: {fixes[s][1].timestamp_us} us, captured {frames[s][1]} us)")
    bad_at = sorted({a.seq for _, a in seen.acks if a.seq in frames and a.timestamp_us != frames[a.seq][1]})
    if bad_at:
        problems.append(f"LockstepAck.timestamp_us is not the frame's capture time for seq {_first(bad_at)}")
    bad_id = sorted({f.frame_seq for _, f in seen.fixes if f.node_id != node_id}
                    | {a.seq for _, a in seen.acks if a.node_id != node_id})
    if bad_id:
        problems.append(f"node_id is not {node_id!r} in the messages of seq {_first(bad_id)}")
    problems += [nothing] if nothing else []
    out.append(RuleResult("timestamps", not problems, "; ".join(problems) or
                          "fixes and acks carry the capture time, their frame_seq and node id"))

    problems = _field_problems([f for _, f in fixes.values()], map_half_extent_m)
    problems += [nothing] if nothing else []
    out.append(RuleResult("fields", not problems, "; ".join(problems) or
                          "every field within its range and unit"))

    bad_cov = []
    for _, f in fixes.values():
        if not f.valid:
            continue
        c = np.asarray(f.covariance_xy_m2, dtype=float).reshape(2, 2)
        scale = max(float(np.max(np.abs(c))), 1e-12) if np.all(np.isfinite(c)) else math.nan
        if not math.isfinite(scale):
            bad_cov.append((f.frame_seq, "not finite"))
        elif abs(c[0, 1] - c[1, 0]) > COV_REL_TOL * scale:
            bad_cov.append((f.frame_seq, f"not symmetric ({c[0, 1]:g} vs {c[1, 0]:g})"))
        elif float(np.linalg.eigvalsh(0.5 * (c + c.T)).min()) < -COV_REL_TOL * scale:
            bad_cov.append((f.frame_seq, "not positive semi-definite"))
    out.append(RuleResult("covariance", not bad_cov and not nothing,
                          f"{len(bad_cov)} valid fixes with a bad covariance, first seq {bad_cov[0][0]}: "
                          f"{bad_cov[0][1]}" if bad_cov else nothing or "every valid fix: finite, symmetric, PSD"))

    if seen.injected_at is None:
        out.append(RuleResult("malformed", False, f"the node gave fewer than {INJECT_AFTER_ACKS} answers: "
                                                  "no malformed frame was sent"))
    else:
        later = [s for s in acks if s > seen.last_seq_before_inject and acks[s] > seen.injected_at]
        # gone for good: the token went away after the malformed frames and was not back before the
        # run's end (a token that blinks is Zenoh's link, e.g. a lease on a loaded machine, not the node).
        # The end is the last frame seen, not the finished tick: a node that leaves on that tick, as it
        # should, may have its token's removal arrive here before the tick does (two links), which
        # failed a correct node in 2 of 5 checks (black-box test, 2026-12-06)
        end = seen.finished_at if seen.finished_at is not None else math.inf
        if frames:
            end = min(end, max(t for t, _cap in frames.values()))
        changes = sorted((t, alive) for t, key, alive in seen.tokens
                         if key == node_key and seen.injected_at < t < end)
        down = bool(changes) and not changes[-1][1]
        problems = []
        if node_alive_after_inject is False:
            problems.append("the process exited after the malformed frames")
        if down:
            problems.append("its liveliness token went away after the malformed frames")
        if len(later) < ANSWERS_AFTER_MALFORMED:
            problems.append(f"{len(later)} frames answered after the malformed ones (expected at least "
                            f"{ANSWERS_AFTER_MALFORMED})")
        out.append(RuleResult("malformed", not problems, "; ".join(problems) or
                              f"{len(malformed_frames())} malformed frames sent; the node kept running and answered {len(later)} "
                              "frames after them"))

    if seen.finished_at is None:
        out.append(RuleResult("leaves", False, "the run did not end (no ClockTick with state finished)"))
    elif left_after_s is not None and left_after_s < -LEAVE_EARLY_TOL_S:
        out.append(RuleResult("leaves", False, f"exited (code {exit_code}) {-left_after_s:.1f} s before the "
                                               "run ended"))
    elif exit_code is None:
        out.append(RuleResult("leaves", False, f"still running {LEAVE_TIMEOUT_S:g} s after the run ended "
                                               "(leave on the ClockTick with state finished)"))
    elif exit_code != 0:
        out.append(RuleResult("leaves", False, f"exited with code {exit_code}"))
    else:
        gone = any(key == node_key and not alive and t >= seen.finished_at for t, key, alive in seen.tokens)
        out.append(RuleResult("leaves", True, f"exited with code 0, {left_after_s:.1f} s after the run ended"
                                              + ("" if gone else " (token removal not seen: the check's "
                                                 "session may have closed first)")))
    return out


def _field_problems(fixes: list[VisionFix], half_extent_m: tuple[float, float]) -> list[str]:
    """Range and unit violations of VisionFix fields (docs/interfaces.md)."""
    problems: dict[str, list[int]] = {}

    def bad(what: str, seq: int) -> None:
        problems.setdefault(what, []).append(seq)

    hx, hy = half_extent_m[0] + MAP_MARGIN_M, half_extent_m[1] + MAP_MARGIN_M
    for f in fixes:
        s = f.frame_seq
        if not f.method:
            bad("method is empty", s)
        if f.accepted and not f.valid:
            bad("accepted without valid", s)
        x, y = f.position_xy_enu_m
        if f.valid and not (math.isfinite(x) and math.isfinite(y)):
            bad("a valid fix without a finite position", s)
        elif f.valid and (abs(x) > hx or abs(y) > hy):
            bad(f"position off the map (more than {MAP_MARGIN_M:g} m outside; ENU metres from the map "
                "centre?)", s)
        for name in ("p_true", *(f"p_classes[{i}]" for i in range(4))):
            v = f.p_true if name == "p_true" else f.p_classes[int(name[-2])]
            if not math.isnan(v) and not 0.0 <= v <= 1.0:
                bad(f"{name} outside [0, 1]", s)
        pc = np.asarray(f.p_classes, dtype=float)
        if np.all(np.isfinite(pc)) and abs(float(pc.sum()) - 1.0) > 1e-3:
            bad("p_classes do not sum to 1", s)
        if not math.isnan(f.ncc_peak) and not -1.0 <= f.ncc_peak <= 1.0:
            bad("ncc_peak outside [-1, 1]", s)
        if not math.isnan(f.ncc_second_peak_ratio) and f.ncc_second_peak_ratio < 0:
            bad("ncc_second_peak_ratio < 0", s)
        for name in ("time_align_ms", "time_ncc_ms", "time_cnn_ms", "time_lookup_ms", "time_total_ms"):
            v = getattr(f, name)
            if not math.isnan(v) and v < 0:
                bad(f"{name} < 0", s)
        if math.isfinite(f.heading_rad):
            if not 0.0 <= f.heading_rad < 2.0 * math.pi + 1e-9:
                bad("heading_rad outside [0, 2 pi) (radians clockwise from north, not degrees)", s)
            if not (math.isfinite(f.heading_std_rad) and f.heading_std_rad > 0.0):
                bad("a heading_rad without a positive heading_std_rad", s)
    return [f"{what} (seq {_first(seqs)})" for what, seqs in problems.items()]


# ---------------------------------------------------------------------------------- the command
@dataclass(frozen=True)
class CheckOptions:
    role: str
    command: tuple[str, ...]
    node_id: str = "node_under_check"
    duration_s: float = 10.0
    ack_timeout_s: float = 10.0
    scenario: str | None = None
    overrides: tuple[str, ...] = ()
    out: str | None = None


def check_options(opts: CheckOptions) -> None:
    """Bad input is one line before anything starts."""
    if opts.role not in ROLES:
        raise UserError(f"node check {opts.role!r}: no conformance profile for this role; expected "
                        f"one of {', '.join(ROLES)}")
    if not opts.command:
        raise UserError("node check: no command; expected `scenenav node check perception -- python "
                        "my_node.py {run_dir}`")
    try:
        check_name("node id", opts.node_id)
    except ValueError as exc:
        raise UserError(f"node check --node-id: {exc}") from None
    if not opts.duration_s > 0 or not opts.ack_timeout_s > 0:
        raise UserError(f"node check: --duration-s {opts.duration_s} and --ack-timeout-s "
                        f"{opts.ack_timeout_s}: expected numbers > 0 s")
    if opts.out is not None and Path(opts.out).exists() and any(Path(opts.out).iterdir()):
        raise UserError(f"{opts.out}: folder exists and is not empty (choose a new --out)")


def run_check(opts: CheckOptions, say: Callable[[str], None] = lambda _t: None) -> dict:
    """Fly the check run, start the node, judge it; returns the report (``passed``, ``rules``)."""
    from scenenav.app.scenario import load_scenario
    check_options(opts)
    overrides = ("clock.mode=lockstep", f"duration_s={opts.duration_s}",
                 f"external.join_timeout_s={JOIN_TIMEOUT_S}",
                 f"clock.member_timeout_s={opts.ack_timeout_s}", "perception.lockstep=true",
                 # the node under check is the only camera member: if it dies, nobody joins again
                 "clock.rejoin_timeout_s=0",
                 # the autopilot waits for a fix less long than the simulator for the autopilot
                 f"autopilot.vision_wait_s={opts.ack_timeout_s / 2}",
                 "recorder.camera_every_n=0", "autopilot.mavlink_tcp_port=0",
                 "autopilot.mavlink_udp_out=none", *opts.overrides)
    load_scenario(opts.scenario, overrides, (f"{opts.role}:{opts.node_id}",))   # bad keys: one line now
    out = Path(opts.out) if opts.out else Path(tempfile.mkdtemp(prefix="scenenav-node-check-"))
    out.mkdir(parents=True, exist_ok=True)
    run_dir = out / "run"
    launcher_cmd = [sys.executable, "-m", "scenenav.app.cli", "run", *([opts.scenario] if opts.scenario else []),
                    "--out", str(run_dir), "--quiet", "--external", f"{opts.role}:{opts.node_id}",
                    *(a for o in overrides for a in ("--set", o))]
    say(f"node check: flying a {opts.duration_s:g} s lockstep run in {run_dir}")
    with (out / "launcher.log").open("wb") as launcher_log, (out / "node.log").open("wb") as node_log:
        launcher = subprocess.Popen(launcher_cmd, stdout=launcher_log, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL)
        node: subprocess.Popen | None = None
        observer: Observer | None = None
        try:
            meta = _wait_run_json(run_dir, launcher)
            keys = Keys(meta["namespace"])
            hub = meta["bus"]["endpoint"].split("/", 1)[1].rsplit(":", 1)[0]   # tcp/HOST:PORT
            observer = Observer(BusConfig(meta["namespace"], int(meta["hub_port"]), host=hub),
                                opts.role, opts.node_id)
            command = [a.replace("{run_dir}", str(run_dir)).replace("{node_id}", opts.node_id)
                       for a in opts.command]
            say(f"node check: starting {shlex.join(command)}")
            env = {**os.environ, "SCENENAV_RUN_DIR": str(run_dir), "SCENENAV_NODE_ID": opts.node_id}
            try:
                node = subprocess.Popen(command, stdout=node_log, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, env=env, start_new_session=True)
            except OSError as exc:
                raise UserError(f"node check: cannot start {command[0]!r}: {exc.strerror or exc}") from None
            alive_after_inject, exited_at = _watch(launcher, node, observer)
            launcher.wait()
            exit_code, left_after = _await_leave(node, observer.seen, exited_at)
            seen = observer.seen
        finally:
            if observer is not None:
                observer.close()
            for proc in (node, launcher):
                if proc is not None and proc.poll() is None:
                    _interrupt(proc)
    half = (meta["m_per_px"] * _map_size(meta)[0] / 2.0, meta["m_per_px"] * _map_size(meta)[1] / 2.0)
    rules = judge(seen, keys, opts.role, opts.node_id, opts.ack_timeout_s, half, alive_after_inject,
                  exit_code, left_after, run_side(run_dir, f"{opts.role}:{opts.node_id}"))
    report = {"role": opts.role, "node_id": opts.node_id, "command": list(opts.command),
              "passed": all(r.passed for r in rules), "rules": [r.to_dict() for r in rules],
              "frames": len(seen.frames), "fixes": len(seen.fixes), "acks": len(seen.acks),
              "check_dir": str(out), "run_dir": str(run_dir), "node_log": str(out / "node.log")}
    (out / "check.json").write_text(json.dumps(report, indent=2))
    return report


def run_side(run_dir: Path, spec: str) -> RunSide:
    """RunSide from the run folder: external.json and the simulator's log."""
    from scenenav.app.nodes import EXTERNAL_FILE
    try:
        joined = spec in (json.loads((run_dir / EXTERNAL_FILE).read_text()).get("joined") or [])
    except (OSError, ValueError, AttributeError):
        joined = False
    try:
        sim_log = (run_dir / "logs" / "sim.log").read_text(errors="replace")
    except OSError:
        sim_log = ""
    return RunSide(joined_before_clock=joined, member_at_start=SIM_MEMBERS_LATE not in sim_log)


def _map_size(meta: dict) -> tuple[int, int]:
    from scenenav.core.formats.world_manifest import read_manifest
    m = read_manifest(Path(meta["world_dir"]))
    return m.width_px, m.height_px


def _wait_run_json(run_dir: Path, launcher: subprocess.Popen) -> dict:
    deadline = time.monotonic() + RUN_JSON_TIMEOUT_S
    path = run_dir / RUN_FILE
    while time.monotonic() < deadline:
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            pass
        if launcher.poll() is not None:
            raise UserError(f"node check: the run ended before its hub listened (exit code "
                            f"{launcher.returncode}; see {run_dir.parent / 'launcher.log'})")
        time.sleep(0.05)
    raise UserError(f"node check: {path} not written within {RUN_JSON_TIMEOUT_S:.0f} s "
                    f"(see {run_dir.parent / 'launcher.log'})")


def _watch(launcher: subprocess.Popen, node: subprocess.Popen, observer: Observer
           ) -> tuple[bool | None, float | None]:
    """Until the run ends: did the node process survive the malformed frames, i.e. run on until the
    run's clock finished (None: they were never sent), and when did it exit (None: not yet)? A node
    that exits before it ever declared its token ends the run at once (nothing would join)."""
    alive: bool | None = None
    exited_at: float | None = None
    while launcher.poll() is None:
        seen = observer.seen
        if exited_at is None and node.poll() is not None:
            exited_at = time.monotonic()
            if not seen.tokens:
                log.warning("the node exited (code %s) before it joined: ending the check run",
                            node.returncode)
                _interrupt(launcher)
        time.sleep(0.1)
    if exited_at is None and node.poll() is not None:
        exited_at = time.monotonic()
    if observer.seen.injected_at is not None:
        # judged once the run is over, not a fixed while after the frames: a node that takes longer
        # to die on a loaded machine still died, and one that leaves at the run's end while the
        # launcher closes the run did not
        alive = _survived(exited_at, node.returncode, observer.seen.finished_at)
    return alive, exited_at


def _survived(exited_at: float | None, returncode: int | None, finished_at: float | None) -> bool:
    """The node survived the malformed frames: it is still running, or it left cleanly (exit code 0)
    after the run's clock finished (the normal end; the launcher may still be closing the run then).
    A non-zero exit is a crash whenever it is seen: a short run's clock can finish before a dying
    node's process is gone."""
    if exited_at is None:
        return True
    return returncode == 0 and finished_at is not None and exited_at >= finished_at


def _await_leave(node: subprocess.Popen, seen: Observed, exited_at: float | None
                 ) -> tuple[int | None, float | None]:
    """The node's exit code and how long after the run's end it left (negative: before)."""
    end = seen.finished_at if seen.finished_at is not None else time.monotonic()
    if exited_at is None:
        try:
            node.wait(max(0.0, end + LEAVE_TIMEOUT_S - time.monotonic()))
        except subprocess.TimeoutExpired:
            return None, None
        exited_at = time.monotonic()
    return node.returncode, exited_at - end


def _interrupt(proc: subprocess.Popen) -> None:
    for sig, wait_s in ((signal.SIGINT, 10.0), (signal.SIGKILL, 5.0)):
        try:
            proc.send_signal(sig)
            proc.wait(wait_s)
            return
        except subprocess.TimeoutExpired:
            continue
        except ProcessLookupError:
            return


def format_report(report: dict) -> str:
    lines = [f"node check: {report['role']} node {report['node_id']} "
             f"({report['frames']} frames, {report['fixes']} fixes, {report['acks']} acks)"]
    for r in report["rules"]:
        lines.append(f"  {'PASS' if r['passed'] else 'FAIL'}  {r['rule']:<11} {r['detail']}")
    failed = [r["rule"] for r in report["rules"] if not r["passed"]]
    lines.append(f"result: {'PASS' if not failed else 'FAIL (' + ', '.join(failed) + ')'}; "
                 f"node log: {report['node_log']}; run folder: {report['run_dir']}")
    return "\n".join(lines) + "\n"
