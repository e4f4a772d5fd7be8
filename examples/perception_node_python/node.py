#!/usr/bin/env python3
"""A minimal scenenav perception node: zenoh, numpy and OpenCV only (no scenenav module).

Written from docs/interfaces.md: it reads the run's ``run.json``, joins the run's bus, and for every
camera frame publishes one VisionFix (normalised cross-correlation of the north-up, map-scaled
capture against the reference map) followed by the frame's LockstepAck. It leaves when the run ends
(a ClockTick with ``state: "finished"``) or on SIGINT/SIGTERM.

    python node.py RUN_DIR [--node-id ID]
    python node.py RUN_DIR --hub tcp/192.168.1.10:PORT --listen tcp/192.168.1.20:0   # another machine

RUN_DIR may also come from the environment variable SCENENAV_RUN_DIR. Without ``--node-id`` the node
takes the id of the first ``perception:ID`` in run.json's ``external`` list (``scenenav run
--external perception:ID``), else ``example_ncc``. On another machine (the run started with
``external.listen_host``), give RUN_DIR a copy of run.json, ``--hub`` one of its
``bus.remote_endpoints``, ``--listen`` an address of this machine (links can then form from
either side; docs/interfaces.md "A node on another machine"), and
``--reference`` the reference map's copy if it is not at run.json's path.
"""

from __future__ import annotations

import argparse
import bisect
import json
import logging
import math
import os
import queue
import signal
import struct
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import zenoh

log = logging.getLogger("example_ncc")

METHOD = "example-ncc"        # VisionFix.method: any short name of what the node does
MIN_PEAK = 0.45               # below: no match (valid false)
MAX_SECOND_PEAK_RATIO = 0.9   # above: ambiguous match (valid, not accepted)
EXCLUSION_PX = 6              # around the peak, ignored when looking for the second peak
MIN_ALTITUDE_M = 20.0         # lower, the footprint is too small to match
HISTORY = 200                 # compass / baro samples kept (10 s at 20 Hz)
CAMERA_FRAME_VERSION = 2     # docs/interfaces.md, CameraFrame: the header with the lens calibration


# --------------------------------------------------------------------------------- the run
def wait_for_run_json(run_dir: Path, timeout_s: float = 300.0) -> dict:
    """run.json appears once the run's hub listens: wait for it, then read it."""
    path = run_dir / "run.json"
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            if time.monotonic() > deadline:
                raise SystemExit(f"{path}: not there after {timeout_s:.0f} s (is the run started?)") from None
            time.sleep(0.1)


def zenoh_config(endpoint: str, listen: str = "tcp/127.0.0.1:0") -> zenoh.Config:
    """Peer (on loopback by default), multicast scouting off, connect to the hub and retry until it
    answers."""
    return zenoh.Config.from_json5(json.dumps({
        "mode": "peer",
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
        "listen": {"endpoints": [listen]},
        "connect": {"endpoints": [endpoint], "timeout_ms": -1, "exit_on_failure": False,
                    "retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}},
    }))


# ------------------------------------------------------------------------------- messages
def encode(msg_type: str, version: int, fields: dict) -> bytes:
    """JSON object with type and version; NaN and infinities as null."""
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v
    return json.dumps({"type": msg_type, "version": version,
                       **{k: clean(v) for k, v in fields.items()}}).encode()


def decode(payload: bytes, msg_type: str, version: int) -> dict:
    obj = json.loads(payload)
    if not isinstance(obj, dict) or obj.get("type") != msg_type or obj.get("version") != version:
        raise ValueError(f"not a {msg_type} version {version}")
    return obj


def decode_camera_frame(payload: bytes) -> tuple[dict, np.ndarray]:
    """uint32 LE header length, JSON header, raw pixels; ValueError on anything malformed."""
    if len(payload) < 4:
        raise ValueError("truncated header length")
    (n,) = struct.unpack_from("<I", payload)
    if n > len(payload) - 4:
        raise ValueError("header length beyond the payload")
    header = decode(payload[4:4 + n], "CameraFrame", CAMERA_FRAME_VERSION)
    w, h, enc = header["width_px"], header["height_px"], header["encoding"]
    channels = {"rgb8": 3, "mono8": 1}.get(enc)
    if channels is None or not (isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0):
        raise ValueError(f"bad image {w}x{h} {enc}")
    raw = payload[4 + n:]
    if len(raw) != w * h * channels:
        raise ValueError(f"{len(raw)} pixel bytes, expected {w * h * channels}")
    pixels = np.frombuffer(raw, np.uint8).reshape((h, w, channels) if channels > 1 else (h, w))
    for name in ("timestamp_us", "seq"):
        if not isinstance(header.get(name), int):
            raise ValueError(f"{name}: expected an integer")
    for name in ("intrinsics_fx_fy_cx_cy_px", "distortion_k1_k2_p1_p2"):
        value = header.get(name)
        if not (isinstance(value, list) and len(value) == 4
                and all(isinstance(x, (int, float)) and math.isfinite(x) for x in value)):
            raise ValueError(f"{name}: expected 4 finite numbers")
    return header, pixels


def undistort(gray: np.ndarray, header: dict) -> np.ndarray:
    """The ideal pinhole image (docs/interfaces.md, CameraFrame): OpenCV's camera matrix takes the
    principal point in pixel indices, the header's is continuous (0.5 px apart)."""
    dist = np.array(header["distortion_k1_k2_p1_p2"], dtype=np.float64)
    if not dist.any():
        return gray
    fx, fy, cx, cy = header["intrinsics_fx_fy_cx_cy_px"]
    k = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    return cv2.undistort(gray, k, dist)


# ------------------------------------------------------------------------------- matching
class Matcher:
    """North-up, map-scaled capture matched by NCC against the whole reference map."""

    def __init__(self, reference_path: str, m_per_px: float):
        ref = cv2.imread(reference_path, cv2.IMREAD_GRAYSCALE)
        if ref is None:
            raise SystemExit(f"{reference_path}: cannot read the reference map")
        self.ref = ref.astype(np.float32)
        self.m_per_px = float(m_per_px)

    def template(self, gray: np.ndarray, heading_rad: float, altitude_m: float, fov_deg: float):
        """Rotate clockwise by the heading (image top = forward -> north up), scale to map pixels,
        keep the largest square inside the rotated image."""
        h_px, w_px = gray.shape
        footprint_m = 2.0 * altitude_m * math.tan(math.radians(fov_deg) / 2.0)   # across the width
        s = (footprint_m / w_px) / self.m_per_px          # map pixels per camera pixel
        if s < 1.0:                                       # shrinking: blur first (no aliasing)
            gray = cv2.GaussianBlur(gray, (0, 0), 0.5 * math.sqrt(1.0 / (s * s) - 1.0))
        c, si = abs(math.cos(heading_rad)), abs(math.sin(heading_rad))
        side = int(s * min(w_px, h_px) / (c + si))
        if side < 16 or side >= min(self.ref.shape):
            return None
        m = cv2.getRotationMatrix2D(((w_px - 1) / 2.0, (h_px - 1) / 2.0), -math.degrees(heading_rad), s)
        m[0, 2] += (side - 1) / 2.0 - (w_px - 1) / 2.0
        m[1, 2] += (side - 1) / 2.0 - (h_px - 1) / 2.0
        return cv2.warpAffine(gray, m, (side, side), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)

    def match(self, tpl: np.ndarray) -> dict:
        r = cv2.matchTemplate(self.ref, tpl, cv2.TM_CCOEFF_NORMED)
        _, peak, _, (col, row) = cv2.minMaxLoc(r)
        masked = r.copy()
        e = EXCLUSION_PX
        masked[max(0, row - e):row + e + 1, max(0, col - e):col + e + 1] = -1.0
        second = float(masked.max())
        side = masked[masked > -1.0]
        psr = (peak - float(side.mean())) / max(float(side.std()), 1e-6)
        u = col + tpl.shape[1] / 2.0          # continuous map pixel of the template centre
        v = row + tpl.shape[0] / 2.0
        H, W = self.ref.shape
        x = (u - W / 2.0) * self.m_per_px
        y = (H / 2.0 - v) * self.m_per_px
        return {"x": x, "y": y, "peak": float(peak), "psr": float(psr),
                "second_ratio": second / peak if peak > 0 else math.nan}


# ---------------------------------------------------------------------------------- the node
class PerceptionNode:
    def __init__(self, run_dir: Path, node_id: str | None, hub: str | None = None,
                 listen: str = "tcp/127.0.0.1:0", reference: str | None = None):
        meta = wait_for_run_json(run_dir)
        self.node_id = node_id or next((s.split(":", 1)[1] for s in meta.get("external", [])
                                        if s.startswith("perception:")), "example_ncc")
        self.camera = meta["camera"]
        self.matcher = Matcher(reference or meta["reference_map"], meta["m_per_px"])
        prefix = meta["bus"]["key_prefix"]
        self.key = lambda tail: f"{prefix}/{tail}"
        self.headings: list[tuple[int, float]] = []
        self.altitudes: list[tuple[int, float]] = []
        self.lock = threading.Lock()
        self.frames: queue.Queue = queue.Queue()
        self.stop = threading.Event()
        self.malformed = 0
        self.answered = 0

        hub = hub or meta["bus"]["endpoint"]
        self.session = zenoh.open(zenoh_config(hub, listen))
        pub = lambda tail: self.session.declare_publisher(   # noqa: E731
            self.key(tail), congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE)
        self.fix_pub = pub(f"perception/fix/{self.node_id}")
        self.ack_pub = pub(f"lockstep/ack/{self.node_id}")
        self.subs = [
            self.session.declare_subscriber(self.key("sensors/compass"), self.on_compass),
            self.session.declare_subscriber(self.key("sensors/baro"), self.on_baro),
            self.session.declare_subscriber(self.key("sensors/camera"), self.on_camera),
            self.session.declare_subscriber(self.key("clock"), self.on_clock),
        ]
        # subscribed: now announce ourselves (lockstep member first, then the node token)
        lv = self.session.liveliness()
        self.tokens = [lv.declare_token(self.key(f"lockstep/member/camera/{self.node_id}")),
                       lv.declare_token(self.key(f"nodes/perception/{self.node_id}"))]
        self.publish_info()
        self.worker = threading.Thread(target=self.work, daemon=True)
        self.worker.start()
        log.info("perception node %s up on %s", self.node_id, hub)

    def publish_info(self) -> None:
        self.session.put(self.key(f"info/{self.node_id}"), encode("NodeInfo", 1, {
            "timestamp_us": 0, "node_id": self.node_id, "role": "perception", "detail": METHOD}))

    # zenoh callbacks: decode, store, hand frames to the worker (never block here)
    def on_compass(self, sample) -> None:
        self._store(sample, "CompassSample", "heading_rad", self.headings)

    def on_baro(self, sample) -> None:
        self._store(sample, "BaroSample", "altitude_m", self.altitudes)

    def _store(self, sample, msg_type: str, field: str, history: list) -> None:
        try:
            m = decode(sample.payload.to_bytes(), msg_type, 1)
            item = (int(m["timestamp_us"]), float("nan") if m[field] is None else float(m[field]))
        except (ValueError, KeyError, TypeError):
            self.malformed += 1
            return
        with self.lock:
            bisect.insort(history, item)      # subscribers may deliver out of order: keep sorted
            del history[:-HISTORY]

    def on_camera(self, sample) -> None:
        try:
            self.frames.put(decode_camera_frame(sample.payload.to_bytes()))
        except (ValueError, KeyError, TypeError) as exc:   # malformed: count, log, keep running
            self.malformed += 1
            log.warning("dropped a malformed camera frame (%s), %d so far", exc, self.malformed)

    def on_clock(self, sample) -> None:
        try:
            if decode(sample.payload.to_bytes(), "ClockTick", 1)["state"] == "finished":
                self.stop.set()                # the run has ended: leave
        except (ValueError, KeyError, TypeError):
            self.malformed += 1

    def at(self, history: list, t_us: int) -> float | None:
        """The newest sample taken at or before the capture time."""
        with self.lock:
            i = bisect.bisect_right(history, (t_us, math.inf)) - 1
            return history[i][1] if i >= 0 else None

    # worker: one VisionFix per frame, then the ack
    def work(self) -> None:
        first = True
        while not self.stop.is_set():
            try:
                header, pixels = self.frames.get(timeout=0.2)
            except queue.Empty:
                continue
            if first:
                # A put right after connecting can go out before the recorder's subscription has
                # reached this session (then nobody receives it); once a frame has arrived, the
                # routes are known: say it again (NodeInfo is idempotent).
                self.publish_info()
                first = False
            try:
                fix = self.process(header, pixels)
            except Exception:               # whatever one frame did: still answer it
                log.exception("frame %s failed", header["seq"])
                fix = self.fix(header, valid=False)
            self.publish_fix(fix)
            self.publish_ack(header)

    def process(self, header: dict, pixels: np.ndarray) -> dict:
        t0 = time.perf_counter()
        t_us = header["timestamp_us"]
        heading, altitude = self.at(self.headings, t_us), self.at(self.altitudes, t_us)
        if heading is None or altitude is None or not (math.isfinite(heading) and math.isfinite(altitude)) \
                or altitude < MIN_ALTITUDE_M:
            return self.fix(header, valid=False)
        gray = pixels if pixels.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(pixels), cv2.COLOR_RGB2GRAY)
        gray = undistort(gray, header)
        tpl = self.matcher.template(gray.astype(np.float32), heading, altitude, float(header["fov_deg"]))
        t1 = time.perf_counter()
        if tpl is None:
            return self.fix(header, valid=False)
        r = self.matcher.match(tpl)
        t2 = time.perf_counter()
        valid = r["peak"] >= MIN_PEAK
        accepted = valid and r["second_ratio"] <= MAX_SECOND_PEAK_RATIO
        sigma_m = max(0.5, 10.0 * (1.0 - r["peak"]))     # a rough 1-sigma from the peak height
        return self.fix(header, valid=valid, accepted=accepted, xy=(r["x"], r["y"]),
                        cov=(sigma_m ** 2, 0.0, 0.0, sigma_m ** 2), peak=r["peak"], psr=r["psr"],
                        second=r["second_ratio"], align_ms=(t1 - t0) * 1e3, ncc_ms=(t2 - t1) * 1e3,
                        total_ms=(time.perf_counter() - t0) * 1e3)

    def fix(self, header: dict, valid: bool, accepted: bool = False, xy=(math.nan, math.nan),
            cov=(math.nan,) * 4, peak=math.nan, psr=math.nan, second=math.nan, align_ms=0.0,
            ncc_ms=0.0, total_ms=0.0) -> dict:
        return {"timestamp_us": header["timestamp_us"],         # the frame's capture time
                "frame_seq": header["seq"], "node_id": self.node_id, "method": METHOD,
                "valid": valid, "accepted": accepted and valid,
                "position_xy_enu_m": list(xy), "covariance_xy_m2": list(cov),
                "p_true": math.nan, "p_classes": [math.nan] * 4,   # no classifier here
                "ncc_peak": peak, "ncc_psr": psr, "ncc_second_peak_ratio": second,
                "time_align_ms": align_ms, "time_ncc_ms": ncc_ms, "time_cnn_ms": 0.0,
                "time_lookup_ms": 0.0, "time_total_ms": total_ms,
                "heading_rad": math.nan, "heading_std_rad": math.nan}   # no heading measured here

    def publish_fix(self, fix: dict) -> None:
        self.fix_pub.put(encode("VisionFix", 2, fix))

    def publish_ack(self, header: dict) -> None:
        self.ack_pub.put(encode("LockstepAck", 1, {
            "timestamp_us": header["timestamp_us"], "node_id": self.node_id, "role": "camera",
            "seq": header["seq"]}))
        self.answered += 1

    def close(self) -> None:
        self.stop.set()
        self.worker.join(timeout=5)
        for token in self.tokens:
            token.undeclare()
        self.session.close()
        log.info("perception node %s: %d frames answered, %d malformed messages dropped",
                 self.node_id, self.answered, self.malformed)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("run_dir", nargs="?", default=os.environ.get("SCENENAV_RUN_DIR"),
                   help="the run folder (default: $SCENENAV_RUN_DIR)")
    p.add_argument("--node-id", help="node id on the bus (default: from run.json's external list)")
    p.add_argument("--hub", help="the hub's Zenoh endpoint (default: run.json's bus.endpoint; from another "
                                 "machine one of bus.remote_endpoints)")
    p.add_argument("--listen", default="tcp/127.0.0.1:0",
                   help="where this node listens for the run's other nodes (default tcp/127.0.0.1:0; on "
                        "another machine tcp/<its address>:0)")
    p.add_argument("--reference", help="the reference map (default: run.json's reference_map)")
    args = p.parse_args(argv)
    if not args.run_dir:
        p.error("give RUN_DIR or set SCENENAV_RUN_DIR")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    node = PerceptionNode(Path(args.run_dir), args.node_id, args.hub, args.listen, args.reference)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: node.stop.set())
    while not node.stop.wait(0.2):
        pass
    node.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
