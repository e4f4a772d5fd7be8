"""Perception node: scene-matching fixes from camera frames, one per frame.

Inputs
  ``sensors/camera``    CameraFrame     (rgb8 or mono8; its ``fov_deg`` scales the capture, and its
                                         FOV and size must be the configured camera's)
  ``sensors/compass``   CompassSample   (newest before the frame is used for alignment)
  ``sensors/baro``      BaroSample      (newest before the frame is used for scale)
  ``autopilot/estimate`` NavEstimate    (alignment homography: the estimated roll and pitch at or just
                                         before the frame, for FIXED-mount frames; never truth; the
                                         worker waits, at most ESTIMATE_WAIT_S, until that estimate
                                         is sure to have arrived, so lockstep runs are repeatable;
                                         also its position with prior_from_estimate, or for the
                                         search without a track with drop_rejected_track_s and
                                         reacquire_window_s, its position and 1-sigma with
                                         resolve_ambiguity_min_posterior or
                                         reject_ambiguity_below_posterior, its position below
                                         the rated height with below_rated_near_estimate_m, and
                                         its velocity with dr_from_estimate)
Outputs
  ``perception/fix/<node_id>``   VisionFix  (one per frame; ``valid`` false when no match; with
                                            ``confirm_successors`` N > 0 held until N more matches
                                            decide it, then published in frame order; with
                                            ``camera_flow`` the image motion since the previous
                                            fixed-mount frame, perception/frame_flow.py)
  ``lockstep/ack/<node_id>``     LockstepAck (role camera, after the fix) when in lockstep
  liveliness ``nodes/perception/<node_id>`` and, in lockstep, ``lockstep/member/camera/<node_id>``
  ``info/<node_id>``, ``events/<node_id>``

A frame whose FOV or size contradicts the configured camera (``ExpectedCamera``) is refused: counted
(``stats["refused_camera_mismatch"]``), logged once, and answered with an invalid fix (and the ack)
so that neither lockstep nor the autopilot waits for it. NaN headings/altitudes or undecodable
bytes are dropped and counted (``stats``), logged, and the node keeps running. Work happens on a
worker thread, so Zenoh's callback threads never block on matching. Every frame is undistorted with
the calibration in its header (``CameraFrame.distortion_k1_k2_p1_p2``, ``intrinsics_fx_fy_cx_cy_px``);
with ``alignment="homography"`` a FIXED-mount frame is aligned with the ground homography of the
estimated attitude (``stats["homography_without_estimate"]`` counts frames aligned as nadir because
no estimate had arrived yet).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
from collections import Counter, deque
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from perception.config import ExpectedCamera, PerceptionConfig, PerceptionNodeConfig
from perception.frame_flow import CameraFlow, FrameFlow
from perception.match_confirmation import MatchConfirmation
from perception.match_metrics import MatchMetrics
from scenenav.core.bus import Bus, BusConfig
from scenenav.core.camera_geometry import focal_length_px
from scenenav.core.contracts import (
    BaroSample,
    CameraFrame,
    CompassSample,
    Event,
    LockstepAck,
    LockstepRole,
    NavEstimate,
    NodeInfo,
    Severity,
    VisionFix,
)
from scenenav.core.keys import Keys
from scenenav.core.presence import announce_node
from scenenav.core.rotations import aviation_euler_from_quat
from scenenav.core.timed_history import sample_at, sample_settled

if TYPE_CHECKING:
    from perception.pipeline import FixResult, Reason

log = logging.getLogger(__name__)


def make_pipeline(world, settings: PerceptionNodeConfig, *, fov_deg: float = PerceptionConfig.fov_deg,
                  weights: str | None = None):
    """The pure perception pipeline for a world and the scenario's ``perception`` settings
    (``PerceptionNodeConfig``: its method, assistant map, reference and the keys
    ``PerceptionNodeConfig.pipeline_config`` passes on). ``fov_deg``: the camera's, used when a
    capture does not state its own.

    ``weights``: a CNN ``.pt`` (the paper's rule, P(bad) > 0.5) or a combined decision-model
    ``.json`` (perception.decision.CombinedDecisionModel): that file selects the combined rule and
    names the CNN weights it was fitted with. Empty: ``perception/weights/default.pt``, paper rule.
    ``settings.reference``: the reference map matched against: ``default`` (the one the world's
    manifest names), ``orthophoto`` or ``perspective`` (``worlds.world.World.reference_map``).
    ``settings.assistant_map``: a saved ``.npz`` (empty: an empty map, filled online).
    """
    from perception.decision import CombinedDecisionModel, DecisionRule, FalseMatchMethod
    from perception.pipeline import PerceptionPipeline
    m = FalseMatchMethod(settings.method)
    cfg = settings.pipeline_config(fov_deg)
    decision_model = None
    if weights and str(weights).endswith(".json"):
        decision_model = CombinedDecisionModel.load(weights)
        cfg = dataclasses.replace(cfg, decision_rule=DecisionRule.COMBINED, decision_model=str(weights))
        cnn = decision_model.cnn_weights_path()
        weights = str(cnn) if cnn is not None else None
    classify = None
    amap = None
    if m in (FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP):
        from perception.cnn import MatchClassifier
        # One torch thread: one 48 px image per frame gains little from a second one, which would
        # compete for the CPU the simulator and the autopilot need in lockstep (docs/cnn.md: 0.65-0.75
        # vs 0.7-1.3 ms per image with 2 vs 1 threads on a quiet machine).
        clf = (MatchClassifier.from_file(weights, num_threads=1) if weights
               else MatchClassifier.default(num_threads=1))
        classify = clf.predict_proba
    if m == FalseMatchMethod.ASSISTANT_MAP or m == FalseMatchMethod.CNN:
        from perception.assistant_map import AssistantMap
        if settings.assistant_map:
            amap = AssistantMap.load(settings.assistant_map)
        else:
            amap = AssistantMap.empty(world.width_px, world.height_px, world.m_per_px,
                                      world_name=world.manifest.name)
    ref = world.reference_map(None if settings.reference == "default" else settings.reference)
    return PerceptionPipeline(ref, world.m_per_px, m, cfg,
                              classify=classify, assistant_map=amap, decision_model=decision_model)


#: Per-fix diagnostics the VisionFix message does not carry, written to ``perception_diag.csv``
#: in the run folder (decision-model fitting and audits; nothing here is used in flight).
DIAG_COLUMNS = ("t_s", "frame_seq", "valid", "accepted", "rule", "reason", "search", "track_state",
                "quality_ok", "u_px", "v_px", "drone_u_px", "drone_v_px", "innovation_px", "track_fixes", "run",
                "dr_innovation_px", "dr_age_s", "reach_excess_px",
                "p_true", "p_false", "ncc_peak", "ncc_psr", "ncc_second_peak_ratio", "dropped_tracks",
                "ambiguity_resolved")


#: Camera frames waiting for the worker. In lockstep one or two wait; more pile up only after the node
#: was frozen (SIGSTOP, a debugger) or in real time on an overloaded machine. Past this many the oldest
#: is dropped (``stats["dropped_backlog"]``, logged, no fix and no ack for it): the newest frames are
#: the ones worth matching.
FRAME_BACKLOG = 64
#: Wall seconds the worker waits for the autopilot estimate of a frame's capture time (see
#: ``_estimate_settled``); after that it aligns with the newest one it has (``stats["estimate_late"]``).
ESTIMATE_WAIT_S = 0.5

def _flow_fields(flow: CameraFlow | None) -> dict:
    """VisionFix's version-3 fields for a camera flow (their defaults: not measured)."""
    if flow is None:
        return {}
    return {"flow_flu_rad_s": (float(flow.flow_flu_rad_s[0]), float(flow.flow_flu_rad_s[1])),
            "flow_interval_us": round(flow.interval_s * 1e6), "flow_quality": float(flow.quality)}


class PerceptionNode:
    """See the module docstring. ``camera``: the camera this node expects (FOV and size)."""

    def __init__(self, world, bus_cfg: BusConfig, node_id: str, settings: PerceptionNodeConfig, *,
                 out_dir: Path | None = None, camera: ExpectedCamera | None = None,
                 weights: str | None = None):
        self.world = world
        self.settings = settings
        self.homography = settings.alignment == "homography"
        self.node_id = node_id
        self.out_dir = out_dir
        self.camera = camera if camera is not None else ExpectedCamera()
        self.keys = Keys(bus_cfg.namespace)
        # One OpenCV thread, like the one torch thread below: a frame is a 200 px capture and a
        # ~270 px window, too small to split, and a second thread's hand-offs and spin-waits take CPU
        # the simulator and the autopilot need in lockstep. The results are the same bits (checked on
        # the alignment, window and global correlation, dilation).
        import cv2
        cv2.setNumThreads(1)
        self.pipeline = make_pipeline(world, settings, fov_deg=self.camera.fov_deg, weights=weights)
        self._frame_flow = FrameFlow()
        self._confirm: MatchConfirmation[tuple[CameraFrame, FixResult, bool]] = MatchConfirmation(
            settings.confirm_successors, settings.confirm_tol_m, settings.confirm_max_span_s)
        self._diag = None
        if out_dir is not None:
            try:
                self._diag = open(Path(out_dir) / f"perception_diag_{node_id}.csv", "w",
                                  encoding="utf-8")
                self._diag.write(",".join(DIAG_COLUMNS) + "\n")
            except OSError as exc:
                log.warning("no diagnostics file: %s", exc)
        self.stats: Counter[str] = Counter()
        # (timestamp_us, value) of recent compass and baro samples: frames arrive after a camera
        # latency, so alignment uses the samples taken at or just before the capture time.
        self._headings: deque[tuple[int, float]] = deque(maxlen=200)
        self._altitudes: deque[tuple[int, float]] = deque(maxlen=200)
        self._tilts: deque[tuple[int, tuple[float, float]]] = deque(maxlen=400)
        # the estimate at its time: (east, north, window radius or None, re-acquisition radius or
        # None = the whole map, 1-sigma east, 1-sigma north), m
        self._priors: deque[tuple[int, tuple[float, float, float | None, float | None, float, float]]] = \
            deque(maxlen=400)
        self._velocities: deque[tuple[int, tuple[float, float]]] = deque(maxlen=400)
        self._sensor_lock = threading.Lock()
        self._estimate_arrived = threading.Condition(self._sensor_lock)
        self._queue: queue.Queue = queue.Queue(maxsize=FRAME_BACKLOG)
        self._backlog_dropped: deque[CameraFrame] = deque()     # oldest frames pushed out
        self._stop = threading.Event()
        # set before the worker starts: a node joining a flight gets its first frame at once
        # (the swap test's second node lost its worker to an AttributeError here under load)
        self._info = NodeInfo(0, node_id, "perception", self.settings.method)
        self._info_repeated = False
        self.bus = Bus(bus_cfg)
        self._worker = threading.Thread(target=self._work, name="perception", daemon=True)
        self._worker.start()
        self.bus.subscribe(self.keys.compass, CompassSample, self._on_compass)
        self.bus.subscribe(self.keys.baro, BaroSample, self._on_baro)
        if self.homography or self.settings.uses_estimate_position or self.settings.dr_from_estimate:
            self.bus.subscribe(self.keys.nav_estimate, NavEstimate, self._on_estimate)
        self.bus.subscribe(self.keys.camera, CameraFrame, self._on_frame)
        # Announce only once subscribed, so nothing addressed to us is lost.
        self.presence = announce_node(self.bus, self.keys, "perception", node_id)
        if self.settings.lockstep:
            self.bus.declare_token(self.keys.lockstep_member(LockstepRole.CAMERA, node_id))
        self.bus.publish(self.keys.node_info(node_id), self._info)
        log.info("perception node %s up (method %s, lockstep %s)", node_id, self.settings.method, self.settings.lockstep)

    def _on_compass(self, msg: CompassSample, _k: str) -> None:
        with self._sensor_lock:
            self._headings.append((msg.timestamp_us, msg.heading_rad))

    def _on_baro(self, msg: BaroSample, _k: str) -> None:
        with self._sensor_lock:
            self._altitudes.append((msg.timestamp_us, msg.altitude_m))

    def _on_estimate(self, msg: NavEstimate, _k: str) -> None:
        from perception.tracker import prior_search_radius_m
        roll, pitch, _heading = aviation_euler_from_quat(msg.q_wxyz)
        mcfg = self.pipeline.cfg.matcher
        radius = prior_search_radius_m(msg.position_std_m, self.pipeline.m_per_px, self.settings.prior_margin_px,
                                       mcfg.max_search_radius_px)
        reacquire_radius = None
        if self.settings.reacquires:       # only a re-acquisition uses it
            reacquire_radius = prior_search_radius_m(msg.position_std_m, self.pipeline.m_per_px,
                                                     self.settings.prior_margin_px, mcfg.max_search_radius_px,
                                                     self.settings.reacquire_min_radius_m)
        with self._sensor_lock:
            self._tilts.append((msg.timestamp_us, (roll, pitch)))
            self._priors.append((msg.timestamp_us, (msg.position_enu_m[0], msg.position_enu_m[1], radius,
                                                    reacquire_radius, msg.position_std_m[0],
                                                    msg.position_std_m[1])))
            self._velocities.append((msg.timestamp_us, (msg.velocity_enu_m_s[0], msg.velocity_enu_m_s[1])))
            self._estimate_arrived.notify_all()

    def _estimate_settled(self, t_us: int) -> bool:
        """Whether the estimate at or before ``t_us`` has surely arrived (``sample_settled``). Without
        this the frame would take whichever estimate happened to have arrived, and the autopilot's and
        the simulator's links race: two lockstep runs differed in 3 of 900 realistic fixes
        (2026-12-05). Call with ``_sensor_lock`` held."""
        return sample_settled(self._tilts, t_us)

    def _estimate_for(self, msg: CameraFrame) -> tuple[tuple[float, float] | None, tuple | None,
                                                      tuple[float, float] | None]:
        """The estimated (roll, pitch) for a fixed-mount frame's homography, the search prior and the
        horizontal velocity (``dr_from_estimate``), from the autopilot estimate at or before the
        frame's time, once it is settled (at most ``ESTIMATE_WAIT_S``)."""
        want_tilt = self.homography and msg.mount == "fixed"
        if not (want_tilt or self.settings.uses_estimate_position or self.settings.dr_from_estimate):
            return None, None, None
        t = msg.timestamp_us
        with self._estimate_arrived:
            if not self._estimate_arrived.wait_for(lambda: self._estimate_settled(t) or self._stop.is_set(),
                                                   ESTIMATE_WAIT_S):
                self.stats["estimate_late"] += 1
            tilt = sample_at(self._tilts, t) if want_tilt else None
            prior = sample_at(self._priors, t) if self.settings.uses_estimate_position else None
            velocity = sample_at(self._velocities, t) if self.settings.dr_from_estimate else None
        return tilt, prior, velocity

    def _on_frame(self, msg: CameraFrame, _k: str) -> None:
        with self._sensor_lock:
            heading = sample_at(self._headings, msg.timestamp_us)
            altitude = sample_at(self._altitudes, msg.timestamp_us)
        item = (msg, heading, altitude)
        # Never block here: this runs in Zenoh's receive thread, and a blocked receive thread stalls
        # every subscription of the node (after a SIGSTOP the backlog filled the queue and the node
        # never saw a frame again). A full queue loses its oldest frame instead.
        while True:
            try:
                self._queue.put_nowait(item)
                return
            except queue.Full:
                try:
                    old = self._queue.get_nowait()
                except queue.Empty:
                    continue
                with self._sensor_lock:
                    self._backlog_dropped.append(old[0])

    def _drop(self, reason: str, msg: CameraFrame, detail: str = "") -> None:
        """Count a dropped frame under a fixed ``reason`` key; log the first ones with detail."""
        self.stats[f"dropped_{reason}"] += 1
        n = self.stats[f"dropped_{reason}"]
        if n <= 5 or n % 100 == 0:
            text = f"dropped camera frame {msg.seq}: {reason}" + (f" ({detail})" if detail else "")
            log.warning("%s, %d so far", text, n)
            self.bus.publish(self.keys.events(self.node_id), Event(
                msg.timestamp_us, self.node_id, int(Severity.WARNING), text))

    def _answer_invalid(self, msg: CameraFrame, reason: Reason | None = None, diag: bool = False) -> FixResult:
        """The invalid VisionFix a frame that cannot be matched still gets (every frame is answered,
        docs/interfaces.md), so the autopilot does not wait its vision timeout for it."""
        from perception.pipeline import Reason
        res = self.pipeline.refused(msg.timestamp_us * 1e-6, reason or Reason.BAD_INPUT)
        self._emit(msg, res, diag=diag)
        return res

    def _emit(self, msg: CameraFrame, res: FixResult, diag: bool = True) -> None:
        """Publish a frame's fix (and its diagnostics row with ``diag``) through the confirmation
        (``perception.confirm_successors``): what it decides now leaves, in frame order."""
        xy = (float(res.position_enu_m[0]), float(res.position_enu_m[1]))
        self._publish_decided(self._confirm.push((msg, res, diag), res.timestamp_s, xy, res.valid))

    def _publish_decided(self, decided: list[tuple[tuple[CameraFrame, FixResult, bool], bool]]) -> None:
        """Publish fixes the confirmation decided: an accepted fix its successors did not confirm
        leaves rejected (reason ``unconfirmed``)."""
        from perception.pipeline import Reason
        for (m, r, d), confirmed in decided:
            if r.valid and r.accepted and not confirmed:
                r = dataclasses.replace(r, accepted=False, reason=Reason.UNCONFIRMED)
                self.stats["unconfirmed"] += 1
            self.bus.publish(self.keys.vision_fix(self.node_id), self._fix_message(m, r))
            if d:
                self._write_diag(m, r)

    def _refuse(self, msg: CameraFrame, mismatch: str) -> None:
        """A frame from another camera than configured: count, log once, answer with an invalid fix."""
        from perception.pipeline import Reason
        self.stats["refused_camera_mismatch"] += 1
        if self.stats["refused_camera_mismatch"] == 1:
            text = (f"refusing camera frames that contradict the configured camera ({mismatch}); "
                    f"first: frame {msg.seq}")
            log.warning("%s", text)
            self.bus.publish(self.keys.events(self.node_id), Event(
                msg.timestamp_us, self.node_id, int(Severity.WARNING), text))
        self._answer_invalid(msg, Reason.CAMERA_MISMATCH, diag=True)

    def _work(self) -> None:
        from perception.pipeline import BadInput, Reason
        while not self._stop.is_set():
            try:
                item = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            msg, heading, altitude = item
            try:
                tilt, prior, velocity = self._estimate_for(msg)
                if not self._info_repeated:
                    # the first put can leave before the recorder's subscription reached this session
                    self.bus.publish(self.keys.node_info(self.node_id), self._info)
                    self._info_repeated = True
                with self._sensor_lock:
                    dropped = list(self._backlog_dropped)
                    self._backlog_dropped.clear()
                for old in dropped:
                    self._drop("backlog", old, f"more than {FRAME_BACKLOG} frames waiting: the oldest goes")
                mismatch = self.camera.mismatch(msg.fov_deg, msg.width_px, msg.height_px)
                if mismatch is not None:
                    self._refuse(msg, mismatch)
                elif heading is None or altitude is None:
                    self._drop("no_compass_or_baro_yet", msg)
                    self._answer_invalid(msg)
                elif not (math.isfinite(heading) and math.isfinite(altitude)):
                    self._drop("nan_sensor", msg)
                    self._answer_invalid(msg)
                elif altitude <= 0.0:
                    # a vehicle on the ground: its barometric height wanders around 0 (noise, drift,
                    # the rotors' ground effect): nothing to match, and nothing wrong with the input
                    self.stats["altitude_at_or_below_ground"] += 1
                    self._answer_invalid(msg, Reason.TEMPLATE_TOO_SMALL)
                else:
                    if self.homography and msg.mount == "fixed" and tilt is None:
                        self.stats["homography_without_estimate"] += 1
                    prior_xy = None
                    if self.settings.prior_from_estimate and prior is not None and prior[2] is not None:
                        prior_xy = (prior[0], prior[1])
                    reacquire_prior = None if prior is None else (prior[0], prior[1], prior[3])
                    estimate = None if prior is None else (prior[0], prior[1], prior[4], prior[5])
                    try:
                        res = self.pipeline.process(msg.pixels, heading, altitude,
                                                    msg.timestamp_us * 1e-6, prior_xy, fov_deg=msg.fov_deg,
                                                    tilt_rad=tilt, intrinsics_px=msg.intrinsics_fx_fy_cx_cy_px,
                                                    distortion=msg.distortion_k1_k2_p1_p2,
                                                    prior_radius_m=None if prior_xy is None else prior[2],
                                                    velocity_enu_m_s=velocity,
                                                    reacquire_prior=reacquire_prior, estimate=estimate)
                    except BadInput as exc:
                        self._drop("bad_input", msg, str(exc))
                        self._answer_invalid(msg)
                    else:
                        self._emit(msg, self._with_camera_flow(msg, res))
                        self.stats["fixes"] += 1
            except Exception:   # keep serving frames whatever one frame did
                log.exception("frame %d failed", msg.seq)
                self.stats["errors"] += 1
            finally:
                if self.settings.lockstep:
                    self.bus.publish(self.keys.lockstep_ack(self.node_id), LockstepAck(
                        msg.timestamp_us, self.node_id, LockstepRole.CAMERA.value, msg.seq))

    def _with_camera_flow(self, msg: CameraFrame, res: FixResult) -> FixResult:
        """``res`` with the camera's flow from the previous frame (``perception.camera_flow``, a
        fixed-mount frame whose capture was aligned); the flow history restarts otherwise."""
        capture = self.pipeline.last_capture
        if not self.settings.camera_flow or msg.mount != "fixed" or capture is None:
            self._frame_flow.reset()
            return res
        intr = msg.intrinsics_fx_fy_cx_cy_px
        if intr is None or not all(math.isfinite(v) for v in intr):
            f = focal_length_px(capture.gray.shape[1], msg.fov_deg)
            intr = (f, f, 0.0, 0.0)
        flow = self._frame_flow.update(msg.timestamp_us * 1e-6, capture.gray, (intr[0], intr[1]))
        if flow is None:
            return res
        self.stats["camera_flows"] += 1
        return dataclasses.replace(res, camera_flow=flow)

    def _fix_message(self, msg: CameraFrame, r: FixResult) -> VisionFix:
        cov = np.asarray(r.covariance_m2, dtype=float).reshape(2, 2)
        pc = tuple(float(x) for x in np.broadcast_to(np.asarray(r.p_classes, dtype=float), (4,)))
        t = r.timings
        m: MatchMetrics = r.metrics
        return VisionFix(
            timestamp_us=msg.timestamp_us, frame_seq=msg.seq, node_id=self.node_id,
            method=self.settings.method, valid=bool(r.valid), accepted=bool(r.accepted),
            position_xy_enu_m=(float(r.position_enu_m[0]), float(r.position_enu_m[1])),
            covariance_xy_m2=(float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 0]), float(cov[1, 1])),
            p_true=float(r.p_true), p_classes=pc,
            ncc_peak=float(m.peak), ncc_psr=float(m.psr),
            ncc_second_peak_ratio=float(m.second_peak_ratio),
            time_align_ms=float(t.align_ms), time_ncc_ms=float(t.ncc_ms),
            time_cnn_ms=float(t.cnn_ms), time_lookup_ms=float(t.lookup_ms),
            time_total_ms=float(t.total_ms),
            heading_rad=float(r.heading_rad), heading_std_rad=float(r.heading_std_rad),
            **_flow_fields(r.camera_flow))

    def _write_diag(self, msg: CameraFrame, r: FixResult) -> None:
        if self._diag is None:
            return
        m = r.metrics
        vals = (r.timestamp_s, msg.seq, int(r.valid), int(r.accepted), r.decision_rule.value,
                r.reason.value, r.search.value if r.search is not None else "",
                r.track_state.value, int(r.quality_ok), r.position_px[0], r.position_px[1],
                r.drone_px[0], r.drone_px[1], r.innovation_px, r.track_fixes, r.run,
                r.dr_innovation_px, r.dr_age_s, r.reach_excess_px, r.p_true, r.p_false,
                m.peak, m.psr, m.second_peak_ratio, self.pipeline.dropped_tracks, int(r.ambiguity_resolved))
        self._diag.write(",".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in vals) + "\n")

    def close(self) -> None:
        self._stop.set()
        self._worker.join(timeout=5)
        if not self._worker.is_alive():     # the run ends: the fixes still held leave unconfirmed
            self._publish_decided(self._confirm.flush())
        if self._diag is not None:
            self._diag.close()
            self._diag = None
        if self.out_dir is not None and getattr(self.pipeline, "assistant_map", None) is not None:
            try:
                self.pipeline.assistant_map.save(Path(self.out_dir) / f"assistant_map_{self.node_id}.npz")
            except OSError as exc:
                log.warning("could not save the assistant map: %s", exc)
        if self.pipeline.dropped_tracks:
            self.stats["dropped_rejected_tracks"] = self.pipeline.dropped_tracks
        if self.pipeline.ambiguities_resolved:
            self.stats["ambiguities_resolved"] = self.pipeline.ambiguities_resolved
        if self.pipeline.ambiguities_rejected:
            self.stats["ambiguities_rejected"] = self.pipeline.ambiguities_rejected
        if self.pipeline.near_estimate_accepted:
            self.stats["near_estimate_accepted"] = self.pipeline.near_estimate_accepted
        if self.pipeline.ambiguities_resolved_by_consistency:
            self.stats["ambiguities_resolved_by_consistency"] = self.pipeline.ambiguities_resolved_by_consistency
        log.info("perception node %s stats: %s", self.node_id, dict(self.stats))
        self.presence.close()
        self.bus.close()
