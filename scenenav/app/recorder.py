"""Recorder node: writes the run folder's logs from the bus.

Inputs: everything under ``scenenav/<ns>/**`` (it is the one node besides evaluation that reads
``truth/``). Outputs (files in the run folder):

* ``bus.mcap`` — every bus message but the camera frames (JSON, with a JSON schema per type), and
  the view channels of ``scenenav.app.viz`` (``viz/...``: camera frames every
  ``camera_every_n``-th as ``foxglove.RawImage``, poses, paths, fixes, route, maps, events), the
  same channels the live view (``scenenav run --live``) streams, so one Foxglove layout
  (docs/foxglove-layout.json) opens both. A chunk is closed and
  written to the file when it fills and at least every ``recorder.mcap_chunk_s`` wall seconds, so a
  recorder killed by SIGKILL loses at most that much; :func:`recover_mcap` (run by the launcher,
  by ``scenenav summarize`` and by the recorder itself after a write error) then cuts the file after
  its last whole record and appends a footer, so the standard ``mcap`` reader opens it.
* ``truth.csv``, ``fixes.csv``, ``estimates.csv``, ``status.csv``, ``events.csv`` — flushed every
  second of wall time and on exit, so Ctrl-C leaves them readable (rows whole).
* per perception node (``perception_nodes`` in ``recorder_stats.json``): its method (from its
  ``NodeInfo``, else from its fixes), fixes, valid and accepted fixes, first and last fix time.

Off the lockstep's critical path: Zenoh's receive thread only queues the samples (a FIFO without
Python, ``Bus.subscribe_inbox``); the recorder's thread takes what arrived every
:data:`DRAIN_PERIOD_S` wall seconds and writes it in one batch (a few wake-ups per second instead of
one per message, nothing dropped; a stop drains the FIFO before the files close).

A full disk (ENOSPC, or any write error) stops all output once: the files keep what was written,
the recorder logs one line naming the disk and its free space, publishes that as an event and keeps
draining the bus until it is stopped.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import threading
import time
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from scenenav.app.scenario import RecorderConfig
from scenenav.app.viz import VizMessage, VizState, bus_schema
from scenenav.core.bus import Bus, BusConfig
from scenenav.core.contracts import (
    AutopilotStatus,
    CameraFrame,
    DecodeError,
    Event,
    NavEstimate,
    NodeInfo,
    Severity,
    TruthPose,
    VisionFix,
    decode,
    message_type,
)
from scenenav.core.keys import Keys, type_for_key
from scenenav.core.presence import announce_node

log = logging.getLogger(__name__)

NODE_ID = "recorder"
#: The recorder's thread takes the samples that arrived every this many wall seconds (a SIGKILL loses
#: at most these, besides the unclosed MCAP chunk and the CSV rows of the last second).
DRAIN_PERIOD_S = 0.05
#: Samples the FIFO holds between two drains (some 50 per simulated second at 100 Hz: room for
#: minutes); when full, Zenoh's receive thread waits for the recorder instead of dropping.
INBOX_CAPACITY = 1 << 16

TRUTH_COLUMNS = ["t_s", "x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "heading_deg",
                 "qw", "qx", "qy", "qz"]
FIX_COLUMNS = ["t_s", "frame_seq", "node_id", "method", "valid", "accepted", "x_m", "y_m",
               "cov_xx_m2", "cov_xy_m2", "cov_yy_m2", "p_true", "p_bad", "ncc_peak", "ncc_psr",
               "ncc_second_peak_ratio", "time_align_ms", "time_ncc_ms", "time_cnn_ms",
               "time_lookup_ms", "time_total_ms", "heading_deg", "heading_std_deg"]
ESTIMATE_COLUMNS = ["t_s", "x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "heading_deg",
                    "std_x_m", "std_y_m", "std_z_m", "position_source", "vision_node_id"]
STATUS_COLUMNS = ["t_s", "armed", "mode", "landed", "mission_seq", "mission_count",
                  "mission_complete", "gps_used"]
EVENT_COLUMNS = ["t_s", "node_id", "severity", "text"]

def _fmt(v: float) -> str:
    return "" if (isinstance(v, float) and not math.isfinite(v)) else f"{v:.6g}" if isinstance(v, float) else str(v)


class _Csv:
    """A CSV file written in whole rows: rows collect in memory and go to the file in one
    ``write`` call per flush, so a killed recorder never leaves half a row behind."""

    def __init__(self, path: Path, columns: list[str]):
        self._f = path.open("wb", buffering=0)
        self._buf = io.StringIO()
        self._w = csv.writer(self._buf)
        self._w.writerow(columns)
        self.flush()

    #: Rows go to the file once this many characters are pending (as often as a buffered file
    #: would write them, so readers following the file see rows as soon as before).
    FLUSH_CHARS = 8192

    def row(self, values) -> None:
        self._w.writerow([_fmt(v) for v in values])
        if self._buf.tell() >= self.FLUSH_CHARS:
            self.flush()

    def flush(self) -> None:
        data = self._buf.getvalue().encode("utf-8")
        if data:
            self._buf.seek(0)
            self._buf.truncate()
            view = memoryview(data)
            while view:
                view = view[self._f.write(view):]

    def close(self) -> None:
        try:
            self.flush()
        finally:
            self._f.close()


class RecorderNode:
    def __init__(self, out_dir: Path, cfg: RecorderConfig, bus_cfg: BusConfig,
                 viz_maps: tuple[VizMessage, ...] = ()):
        self.out = Path(out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.cfg = cfg
        self.keys = Keys(bus_cfg.namespace)
        self._lock = threading.Lock()
        self._mcap_file = (self.out / "bus.mcap").open("wb")
        self._mcap = Writer(self._mcap_file, compression=CompressionType.ZSTD, chunk_size=512 * 1024)
        self._mcap.start(profile="", library="scenenav-recorder")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._seq = 0
        self._truth_count = 0
        self.counts: dict[str, int] = {}
        self.dropped = 0
        self.truth = _Csv(self.out / "truth.csv", TRUTH_COLUMNS)
        self.fixes = _Csv(self.out / "fixes.csv", FIX_COLUMNS)
        self.estimates = _Csv(self.out / "estimates.csv", ESTIMATE_COLUMNS)
        self.status = _Csv(self.out / "status.csv", STATUS_COLUMNS)
        self.events = _Csv(self.out / "events.csv", EVENT_COLUMNS)
        self._csvs = [self.truth, self.fixes, self.estimates, self.status, self.events]
        self._last_flush = time.monotonic()
        self._last_chunk = time.monotonic()
        self._closed = False
        self.write_failed: str | None = None     # why output stopped (disk full), once
        self._last_fix: tuple[str, int] | None = None     # (node id, timestamp_us) of the newest fix
        self._perception_live: list[str] = []             # live perception nodes, newest last
        self._sim_time_us = 0
        self.viz = VizState(cfg.camera_every_n)
        self._viz_maps = viz_maps                         # written with the first message
        self.perception_nodes: dict[str, dict[str, Any]] = {}
        self._types: dict[str, type | None] = {}           # message class per concrete key
        self.bus = Bus(bus_cfg)
        self._inbox = self.bus.subscribe_inbox(self.keys.everything, INBOX_CAPACITY)
        self._stop = threading.Event()
        self._drainer = threading.Thread(target=self._drain_loop, name="recorder", daemon=True)
        self._drainer.start()
        self.bus.watch_liveliness(self.keys.node_alive_all, self._on_node)
        self.presence = announce_node(self.bus, self.keys, "recorder", NODE_ID)

    def _drain_loop(self) -> None:
        while not self._stop.wait(DRAIN_PERIOD_S):
            self.drain()

    def drain(self) -> int:
        """Write every sample that has arrived (in arrival order); the number written."""
        take = self._inbox.take
        n = 0
        while True:
            sample = take()
            if sample is None:
                return n
            n += 1
            try:
                self._on_sample(*sample)
            except Exception:  # noqa: BLE001 - one bad message must not stop the recording
                log.exception("recording a sample of %s failed", sample[1])

    def set_viz_maps(self, maps) -> None:
        """The view's map grids (``scenenav.app.viz.map_messages``), written with the next message
        (at log time 0: a player shows them from the start)."""
        with self._lock:
            self._viz_maps = tuple(maps)

    def _log_event(self, t_us: int, severity: int, text: str) -> None:
        """An event the recorder itself observed (written to events.csv and the log)."""
        log.info("%s", text)
        with self._lock:
            if not self._closed and self.write_failed is None:
                try:
                    self.events.row([t_us * 1e-6, NODE_ID, severity, text])
                except OSError as exc:
                    self._stop_output(exc)

    def _on_node(self, key: str, alive: bool) -> None:
        parts = key.split("/")
        if len(parts) < 2:
            return
        role, node = parts[-2], parts[-1]
        if role == "perception":
            with self._lock:
                if node in self._perception_live:
                    self._perception_live.remove(node)
                if alive:
                    self._perception_live.append(node)   # newest last: the one followed
        self._log_event(self._sim_time_us, 6, f"node {'up' if alive else 'down'}: {role}/{node}")

    def _track_fix_source(self, msg: VisionFix) -> None:
        """Log when the followed fix source (the newest live perception node) changes, and the
        gap between the old source's last fix and the new one's first."""
        followed = self._perception_live[-1] if self._perception_live else msg.node_id
        if msg.node_id != followed:
            return
        last = self._last_fix
        if last is not None and last[0] != msg.node_id:
            gap_s = (msg.timestamp_us - last[1]) * 1e-6
            self.events.row([msg.timestamp_us * 1e-6, NODE_ID, 5,
                             f"fix source changed: {last[0]} -> {msg.node_id} ({msg.method}), "
                             f"gap in fixes {gap_s:.2f} s"])
            log.info("fix source changed %s -> %s, gap %.2f s", last[0], msg.node_id, gap_s)
        self._last_fix = (msg.node_id, msg.timestamp_us)

    def _node_stats(self, node_id: str) -> dict[str, Any]:
        st = self.perception_nodes.get(node_id)
        if st is None:
            st = {"method": None, "fix_methods": {}, "fixes": 0, "valid": 0, "accepted": 0,
                  "first_fix_s": None, "last_fix_s": None}
            self.perception_nodes[node_id] = st
        return st

    def _count_fix(self, msg: VisionFix) -> None:
        """Per-node figures: the node's method (its NodeInfo, else the methods its fixes name),
        fixes, valid and accepted ones, the capture times of its first and last fix."""
        st = self._node_stats(msg.node_id)
        st["fix_methods"][msg.method] = st["fix_methods"].get(msg.method, 0) + 1
        st["fixes"] += 1
        st["valid"] += int(msg.valid)
        st["accepted"] += int(msg.valid and msg.accepted)
        t = msg.timestamp_us * 1e-6
        st["first_fix_s"] = t if st["first_fix_s"] is None else min(st["first_fix_s"], t)
        st["last_fix_s"] = t if st["last_fix_s"] is None else max(st["last_fix_s"], t)

    # --------------------------------------------------------------------------------- mcap
    def _channel(self, key: str, schema_name: str, schema: bytes, type_name: str = "") -> int:
        ch = self._channels.get(key)
        if ch is None:
            sid = self._schemas.get(schema_name)
            if sid is None:
                sid = self._mcap.register_schema(schema_name, "jsonschema", schema)
                self._schemas[schema_name] = sid
            ch = self._mcap.register_channel(key, "json", sid,
                                             {"scenenav_type": type_name} if type_name else {})
            self._channels[key] = ch
        return ch

    def _add(self, channel: int, payload: bytes, t_ns: int) -> None:
        self._seq += 1
        self._mcap.add_message(channel, t_ns, payload, t_ns, self._seq)

    def _write_viz(self, messages) -> None:
        for v in messages:
            self._add(self._channel(v.topic, v.schema_name, v.schema), v.payload, v.log_time_ns)

    def _on_sample(self, payload: bytes, key: str) -> None:
        try:
            cls = self._types[key]
        except KeyError:
            type_name = type_for_key(self.keys, key)
            cls = message_type(type_name) if type_name is not None else None
            if len(self._types) < 4096:         # bounded: keys are few, a flood of others is not
                self._types[key] = cls
        if cls is None:
            return
        type_name = cls.__name__
        try:
            msg = decode(cls, payload)
        except DecodeError as exc:
            self.dropped += 1
            if self.dropped <= 5 or self.dropped % 100 == 0:
                log.warning("recorder dropped malformed %s on %s: %s", type_name, key, exc)
            return
        with self._lock:
            if self._closed:
                return
            self.counts[type_name] = self.counts.get(type_name, 0) + 1
            self._sim_time_us = max(self._sim_time_us, int(msg.timestamp_us))
            t_ns = int(msg.timestamp_us) * 1000
            if isinstance(msg, CameraFrame):
                payload = b""                   # recorded as viz/camera (foxglove.RawImage)
            announce = False
            try:
                self._write(key, type_name, msg, payload, t_ns)
            except OSError as exc:
                announce = self._stop_output(exc)
        if announce:        # outside the lock: the recorder hears its own event
            self._announce_write_failure()

    def _write(self, key: str, type_name: str, msg: Any, payload: bytes, t_ns: int) -> None:
        if self.write_failed is not None:
            return
        if isinstance(msg, VisionFix):
            self._track_fix_source(msg)
            self._count_fix(msg)
        elif isinstance(msg, NodeInfo) and msg.role == "perception":
            self._node_stats(msg.node_id)["method"] = msg.detail
        if self._viz_maps:
            self._write_viz(self._viz_maps)
            self._viz_maps = ()
        if payload:
            self._add(self._channel(key, *bus_schema(type_name), type_name), payload, t_ns)
        self._write_viz(self.viz.on_message(msg))
        self._to_csv(msg)
        now = time.monotonic()
        if now - self._last_flush > 1.0:
            self._flush_csv()
            self._write_viz(self.viz.route_messages(self.out, self._sim_time_us))
            self._last_flush = now
        if now - self._last_chunk > self.cfg.mcap_chunk_s:
            self._mcap.flush()          # close the chunk: a crash now loses at most this chunk
            self._last_chunk = now

    def _stop_output(self, exc: OSError) -> bool:
        """A write failed (disk full): stop writing and log it; True the first time only."""
        if self.write_failed is not None:
            return False
        from scenenav.app.preflight import free_bytes, mount_point
        where, free = free_bytes(self.out)
        self.write_failed = (f"recorder stopped writing {self.out}: {exc.strerror or exc} "
                             f"({free / 1e6:.1f} MB free on {mount_point(where)})")
        log.error("%s", self.write_failed)
        return True

    def _announce_write_failure(self) -> None:
        try:
            self.bus.publish(self.keys.events(NODE_ID), Event(self._sim_time_us, NODE_ID,
                                                              int(Severity.ERROR), self.write_failed))
        except Exception:  # noqa: BLE001 - the bus may be closing; the log has it
            log.debug("could not publish the disk-full event", exc_info=True)

    # ---------------------------------------------------------------------------------- csv
    def _to_csv(self, msg: Any) -> None:
        t = msg.timestamp_us * 1e-6
        if isinstance(msg, TruthPose):
            self._truth_count += 1
            if (self._truth_count - 1) % self.cfg.truth_every_n_ticks == 0:
                self.truth.row([t, *msg.position_enu_m, *msg.velocity_enu_m_s,
                                math.degrees(msg.heading_rad), *msg.q_wxyz])
        elif isinstance(msg, VisionFix):
            c = msg.covariance_xy_m2
            self.fixes.row([t, msg.frame_seq, msg.node_id, msg.method, int(msg.valid),
                            int(msg.accepted), *msg.position_xy_enu_m, c[0], c[1], c[3],
                            msg.p_true, msg.p_classes[0], msg.ncc_peak, msg.ncc_psr,
                            msg.ncc_second_peak_ratio, msg.time_align_ms, msg.time_ncc_ms,
                            msg.time_cnn_ms, msg.time_lookup_ms, msg.time_total_ms,
                            math.degrees(msg.heading_rad), math.degrees(msg.heading_std_rad)])
        elif isinstance(msg, NavEstimate):
            self.estimates.row([t, *msg.position_enu_m, *msg.velocity_enu_m_s,
                                math.degrees(msg.heading_rad), *msg.position_std_m,
                                msg.position_source, msg.vision_node_id])
        elif isinstance(msg, AutopilotStatus):
            self.status.row([t, int(msg.armed), msg.mode, int(msg.landed), msg.mission_seq,
                             msg.mission_count, int(msg.mission_complete), int(msg.gps_used)])
        elif isinstance(msg, Event):
            self.events.row([t, msg.node_id, msg.severity, msg.text])

    def _flush_csv(self) -> None:
        for c in self._csvs:
            c.flush()

    def close(self) -> dict:
        self._stop.set()
        self._drainer.join(timeout=10.0)
        self.presence.close()
        self.bus.close()
        self.drain()                    # what arrived before the session closed
        with self._lock:
            if not self._closed:
                self._closed = True
                steps = [*(c.close for c in self._csvs)]
                if self.write_failed is None:
                    steps.append(self._mcap.finish)
                for step in steps:
                    try:
                        step()
                    except OSError as exc:
                        self._stop_output(exc)
                try:
                    self._mcap_file.close()
                except OSError as exc:
                    self._stop_output(exc)
                if self.write_failed is not None:       # the footer is missing: cut and finish
                    recover_mcap(self.out / "bus.mcap")
        return {"counts": dict(self.counts), "dropped": self.dropped,
                "write_failed": self.write_failed, "perception_nodes": self.perception_nodes}


# ------------------------------------------------------------------------------ mcap recovery
_MCAP_MAGIC = b"\x89MCAP0\r\n"


def mcap_is_complete(path: Path) -> bool:
    """Does the file end with the MCAP footer magic (what the standard reader needs)?"""
    try:
        with Path(path).open("rb") as f:
            size = f.seek(0, 2)
            if size < 2 * len(_MCAP_MAGIC):
                return False
            f.seek(size - len(_MCAP_MAGIC))
            return f.read() == _MCAP_MAGIC
    except OSError:
        return False


_OP_CHUNK = 0x06
_OP_DATA_END = 0x0F
_OP_FOOTER = 0x02


def _whole_records_end(path: Path) -> int:
    """File offset just past the last whole record of an MCAP data section (a record whose length
    prefix says it ends beyond the file was torn by the crash)."""
    size = path.stat().st_size
    with path.open("rb") as f:
        if f.read(len(_MCAP_MAGIC)) != _MCAP_MAGIC:
            raise ValueError("no MCAP magic")
        offset = len(_MCAP_MAGIC)
        while offset + 9 <= size:
            head = f.read(9)
            opcode, length = head[0], int.from_bytes(head[1:], "little")
            if opcode in (_OP_DATA_END, _OP_FOOTER) or offset + 9 + length > size:
                break
            f.seek(length, 1)
            offset += 9 + length
    return offset


def recover_mcap(path: Path) -> int | None:
    """Finish an unfinished ``bus.mcap`` (no footer: its writer was killed or the disk filled) in
    place: cut it after its last whole record and append a data end and a footer without a summary
    section, which the standard reader (``mcap.reader.make_reader``) reads record by record. Needs
    no free space (the cut frees more than the 41 bytes appended). Returns the number of messages
    the standard reader then returns, or None when the file was complete or is not an MCAP file."""
    path = Path(path)
    if not path.is_file() or mcap_is_complete(path):
        return None
    try:
        end = _whole_records_end(path)
    except (OSError, ValueError):
        return None
    with path.open("r+b") as f:
        f.truncate(end)
        f.seek(end)
        f.write(bytes([_OP_DATA_END]) + (4).to_bytes(8, "little") + (0).to_bytes(4, "little"))
        f.write(bytes([_OP_FOOTER]) + (20).to_bytes(8, "little") + bytes(20))
        f.write(_MCAP_MAGIC)
    try:
        return count_mcap_messages(path)
    except Exception:  # noqa: BLE001 - a chunk cut inside (bad CRC): say so, keep the file
        log.warning("%s: recovered, but a chunk is unreadable", path)
        return 0


def count_mcap_messages(path: Path) -> int:
    """Messages the standard (indexed) reader returns."""
    with Path(path).open("rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())
