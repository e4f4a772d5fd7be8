"""The perception pipeline of the paper's Figure 2: align -> NCC match (tracked) -> decide.

Decision per ``FalseMatchMethod`` (details in docs/perception.md):

* ``none``: every computed match is accepted.
* ``statistical``: the detrended-variance detector (perception.statistical) over the last
  ``statistical_window`` fixes; rejected when the variance exceeds ``statistical_threshold_m2``.
* ``assistant-map``: p_true is read from the assistant map at the drone pixel. Where the map has no
  value, the capture is classified when a classifier is given (and the patch is written), otherwise
  ``unknown_policy`` decides (default REJECT: no evidence of a good area, and losing a fix is cheaper
  than accepting a false one, paper 7.1).
* ``cnn``: every capture is classified; the patch is written to the assistant map as well.

Rejection (paper 5.4): P(bad) > p_bad_threshold (0.5). The drone pixel used for the map lookup and the
patch is the match position when the matcher rates the match quality-ok, otherwise the tracker's
constant-velocity prediction when there is one (a low-quality match lands anywhere on the map).
The patch side is twice the last movement in pixels (paper 5.4), at least 1 px and at most
``assistant_patch_max_px``.

The classifier callable takes (N, cnn_input_px, cnn_input_px) float32 grey in [0, 1] (here N = 1: the
camera image as captured, grey, resized) and returns (N,) P(bad) or (N, 4) softmax (column 0 = bad).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from enum import Enum
from typing import Callable

import cv2
import numpy as np

from perception.alignment import (
    AlignedCapture,
    BadInput,
    TemplateTooLarge,
    TemplateTooSmall,
    align_capture,
    finite_number,
    to_gray_float32,
)
from perception.assistant_map import AssistantMap
from perception.config import CropMode, PerceptionConfig, UnknownPolicy
from perception.decision import (
    N_PAPER_CLASSES,
    VARIANCE_WINDOWS,
    CombinedDecisionModel,
    Decision,
    DecisionRule,
    FalseMatchMethod,
    TrackEvidence,
    combined_features,
    decide_from_p_bad,
    split_classifier_output,
)
from perception.fix_covariance import local_mode_posterior, pointing_covariance_m2
from perception.frame_flow import CameraFlow
from perception.heading_offset import HeadingDeviation, parabola_vertex, rotation_peaks
from perception.match_consistency import MatchConsistency
from perception.match_metrics import MatchMetrics, StageTimes
from perception.ncc_search import MatchResult, SceneMatcher, SearchMode
from perception.statistical import StatisticalDetector
from perception.tracker import MatchTracker, TrackState
from scenenav.core.camera_geometry import NO_DISTORTION, Distortion
from scenenav.core.errors import UserError
from scenenav.core.frames import wrap_2pi

__all__ = ["BadInput", "FixResult", "PerceptionPipeline", "Reason"]

log = logging.getLogger(__name__)

Classifier = Callable[[np.ndarray], np.ndarray]
_MS = 1000.0
_NAN = float("nan")


class Reason(str, Enum):
    """Why a fix was accepted or rejected (for logs and evaluation)."""

    ACCEPTED = "accepted"
    NO_DETECTION = "no-detection"            # method none: accepted without a check
    CNN_BAD_AREA = "cnn-bad-area"
    MAP_BAD_AREA = "map-bad-area"
    LIKELY_FALSE = "likely-false"            # combined rule: P(false fix) above the model threshold
    MAP_UNKNOWN = "map-unknown"              # unknown_policy REJECT and no classifier
    STATISTICAL_VARIANCE = "statistical-variance"
    LOW_QUALITY = "low-quality"              # quality_gate on and the matcher rated it low
    TEMPLATE_TOO_SMALL = "template-too-small"
    TEMPLATE_TOO_LARGE = "template-too-large"
    FLAT_CAPTURE = "flat-capture"            # uniform capture: NCC undefined, no match computed
    CAMERA_MISMATCH = "camera-mismatch"      # the frame's FOV or size is not the configured camera's
    BAD_INPUT = "bad-input"                  # the frame or its heading / height cannot be used
    BELOW_RATED_HEIGHT = "below-rated-height"  # cnn / assistant-map: captured too low for the area rating
    TRACK_CONTINUATION = "track-continuation"  # below the rated height, continuing an accepted track
    NEAR_ESTIMATE = "near-estimate"          # below the rated height, a window track near the estimate
    AMBIGUOUS_FAR = "ambiguous-far"          # an ambiguous match whose own peak the estimate all but rules out
    UNCONFIRMED = "unconfirmed"              # accepted, but its successors did not confirm it (the node's
                                             # perception.confirm_successors, perception/match_confirmation.py)


@dataclass(frozen=True)
class FixResult:
    """Output of ``PerceptionPipeline.process`` for one capture (maps onto contracts.VisionFix).

    ``valid``: a match was computed (position NaN otherwise). ``accepted``: the false-match verdict.
    ``p_true``: probability of a true match (NaN when not evaluated). ``p_classes``: the classifier's
    4 class probabilities (bad, 4-, 3-, 2-arm) or NaNs. ``metrics``: the NCC match's quality
    (NaN when invalid). ``timings``: wall-clock time per stage.
    """

    timestamp_s: float
    valid: bool
    accepted: bool
    decision: Decision
    reason: Reason
    method: FalseMatchMethod
    position_enu_m: tuple[float, float]
    position_px: tuple[float, float]
    covariance_m2: np.ndarray
    p_true: float
    p_classes: tuple[float, float, float, float]
    metrics: MatchMetrics
    quality_ok: bool
    search: SearchMode | None
    track_state: TrackState
    statistical_variance_m2: float
    template_side_px: int
    timings: StageTimes = field(default_factory=StageTimes)
    innovation_px: float = _NAN
    track_fixes: int = 0
    run: int = 0
    dr_innovation_px: float = _NAN
    dr_age_s: float = _NAN
    reach_excess_px: float = _NAN
    drone_px: tuple[float, float] = (_NAN, _NAN)
    p_false: float = _NAN
    decision_rule: DecisionRule = DecisionRule.PAPER
    ambiguity_resolved: bool = False    # published with the local covariance (resolve_ambiguity_min_posterior)
    #: the heading the map measured for this capture (clockwise from north, rad): the rotation that
    #: fits the reference best at the matched position (``_learn_heading``); NaN when not measured
    heading_rad: float = _NAN
    heading_std_rad: float = _NAN       # its 1-sigma (``HeadingOffsetConfig.measurement_std_deg``); NaN with it
    #: the camera's flow from the previous capture (``perception.frame_flow``; the node adds it with
    #: ``perception.camera_flow``); None: not measured
    camera_flow: CameraFlow | None = None

    @property
    def covariance_row_major(self) -> tuple[float, float, float, float]:
        """The 2x2 covariance as the row-major 4-tuple of contracts.VisionFix."""
        c = self.covariance_m2
        return (float(c[0, 0]), float(c[0, 1]), float(c[1, 0]), float(c[1, 1]))


_NAN_CLASSES = (_NAN,) * N_PAPER_CLASSES
#: Rejections by the area rating or the combined rule: what ``drop_rejected_track_s`` counts.
_RULE_REJECTIONS = frozenset({Reason.LIKELY_FALSE, Reason.CNN_BAD_AREA, Reason.MAP_BAD_AREA,
                              Reason.STATISTICAL_VARIANCE})


class PerceptionPipeline:
    """Align, match and decide for one reference map (see the module docstring)."""

    def __init__(self, reference_rgb: np.ndarray, m_per_px: float,
                 method: FalseMatchMethod | str | None = None, cfg: PerceptionConfig | None = None,
                 classify: Classifier | None = None, assistant_map: AssistantMap | None = None,
                 world_name: str = "", model_id: str = "",
                 decision_model: CombinedDecisionModel | None = None) -> None:
        self.cfg = cfg if cfg is not None else PerceptionConfig()
        self._told_below_rated = False
        #: the newest rated verdict on the current window track was an acceptance (track continuation)
        self._trusted_track = False
        #: when the current streak of rated rejections of quality-ok matches began (None: no streak)
        self._rejected_since_s: float | None = None
        #: a rejected track was dropped and no fix has been accepted since (``cfg.drop_rejected_track_s``)
        self.reacquiring = False
        #: tracks dropped so far (``cfg.drop_rejected_track_s``)
        self.dropped_tracks = 0
        self.ambiguities_resolved = 0     # accepted ambiguous matches published with the local covariance
        self.ambiguities_rejected = 0     # ambiguous matches rejected as far from the estimate
        self.near_estimate_accepted = 0   # fixes below the rated height accepted near the estimate
        #: the motion consistency of the latest valid matches (``cfg.resolve_consistent_matches``)
        self.consistency = MatchConsistency(self.cfg.consistent_match_tol_m)
        self.ambiguities_resolved_by_consistency = 0
        #: the time of the last accepted fix (``cfg.reacquire_window_s``)
        self._last_accept_s: float | None = None
        try:
            self.method = FalseMatchMethod(method) if method is not None else self.cfg.method
        except ValueError:
            allowed = ", ".join(m.value for m in FalseMatchMethod)
            raise UserError(f"perception method {method!r}: expected one of {allowed}") from None
        if self.method is FalseMatchMethod.CNN and classify is None:
            raise UserError("perception method 'cnn' needs a classifier (CNN model); none was given")
        try:
            gray = to_gray_float32(reference_rgb)
        except BadInput as exc:
            raise UserError(f"reference map: {exc}") from None
        self.m_per_px = float(m_per_px)
        self.matcher = SceneMatcher(gray, self.m_per_px, self.cfg.matcher)
        self.tracker = MatchTracker(self.matcher, self.cfg.matcher)
        self.track_evidence = TrackEvidence()
        #: the learned compass heading error (None: the compass heading is used as it comes)
        self.heading_deviation = (HeadingDeviation(self.cfg.heading_offset)
                                  if self.cfg.heading_offset.enabled else None)
        self.last_aligned: AlignedCapture | None = None
        #: this call's aligned capture (None when alignment failed); ``last_aligned`` keeps the last
        #: one matched
        self.last_capture: AlignedCapture | None = None
        self.last_match: MatchResult | None = None
        self.classify = classify
        h, w = gray.shape
        if assistant_map is None:
            assistant_map = AssistantMap(w, h, self.m_per_px, world_name=world_name,
                                         method=self.method.value, model_id=model_id)
        elif (assistant_map.width_px, assistant_map.height_px) != (w, h):
            raise UserError(f"assistant map is {assistant_map.width_px}x{assistant_map.height_px} px:"
                            f" expected {w}x{h} px (the size of the reference map)")
        elif not math.isclose(assistant_map.m_per_px, self.m_per_px, rel_tol=1e-6):
            raise UserError(f"assistant map resolution {assistant_map.m_per_px} m/px: expected "
                            f"{self.m_per_px} m/px (the reference map's)")
        self.assistant_map = assistant_map
        self.decision_model: CombinedDecisionModel | None = None
        if self.cfg.decision_rule is DecisionRule.COMBINED and self.method in (
                FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP):
            self.decision_model = (decision_model if decision_model is not None
                                   else CombinedDecisionModel.load(self.cfg.decision_model or None))
        # The statistical indicator over two windows: features of the combined rule.
        self._variance = [StatisticalDetector(w) for w in VARIANCE_WINDOWS]
        self._detector: StatisticalDetector | None = None
        if self.method is FalseMatchMethod.STATISTICAL:
            self._detector = StatisticalDetector(self.cfg.statistical_window,
                                                 self.cfg.statistical_threshold_m2)
        if (self.method is FalseMatchMethod.ASSISTANT_MAP and classify is None
                and assistant_map.coverage() == 0.0):
            log.warning("assistant-map method with an empty map and no classifier: every fix will "
                        "follow unknown_policy=%s", self.cfg.unknown_policy.value)

    def reset(self) -> None:
        """Forget the track and the statistical window (keeps the assistant map)."""
        self.tracker.reset()
        self.track_evidence.reset()
        self._trusted_track = False
        self._rejected_since_s = None
        self.reacquiring = False
        self._last_accept_s = None
        self.consistency.reset()
        for det in self._variance:
            det.reset()
        if self._detector is not None:
            self._detector.reset()

    # ------------------------------------------------------------------------------ main
    def process(self, image_rgb: np.ndarray, heading_rad: float, altitude_m: float,
                timestamp_s: float, prior_enu_m: tuple[float, float] | None = None, *,
                fov_deg: float | None = None, tilt_rad: tuple[float, float] | None = None,
                intrinsics_px: tuple[float, float, float, float] | None = None,
                distortion: Distortion = NO_DISTORTION,
                prior_radius_m: float | None = None,
                velocity_enu_m_s: tuple[float, float] | None = None,
                reacquire_prior: tuple[float, float, float | None] | None = None,
                estimate: tuple[float, float, float, float] | None = None) -> FixResult:
        """One capture -> FixResult. Raises BadInput for unusable inputs (the node drops those).

        ``prior_enu_m`` (optional, e.g. the autopilot's estimate) seeds the search window when the
        tracker has no prediction of its own. ``fov_deg``: the horizontal field of view the capture
        was taken with (the node passes ``CameraFrame.fov_deg``); None: ``cfg.fov_deg``.
        ``tilt_rad``: (roll, pitch) of the body a FIXED camera is on (the autopilot's estimate): align
        with the ground homography (``perception.alignment``); None: rotation and scale (nadir).
        ``intrinsics_px``, ``distortion``: the frame's calibration (the capture is undistorted first).
        ``prior_radius_m``: the search radius around ``prior_enu_m`` (None: ``max_search_radius_px``).
        ``velocity_enu_m_s``: the vehicle's horizontal velocity at the capture (the autopilot's
        estimate, ``perception.dr_from_estimate``): the track evidence dead-reckons its anchor with it
        (``TrackEvidence.observe``); None: at the last established run's constant velocity.
        ``reacquire_prior``: (east m, north m, radius m or None) where to search when the tracker has
        no track, after a rejected track was dropped (``cfg.drop_rejected_track_s``) or within
        ``cfg.reacquire_window_s`` of the last accepted fix (the node gives the autopilot's estimate).
        None, or a None radius: the whole map.
        ``estimate``: (east m, north m, 1-sigma east m, 1-sigma north m) of the autopilot's estimate at
        the capture: an accepted ambiguous match near it is published with its local covariance
        (``cfg.resolve_ambiguity_min_posterior``); None: never.
        """
        t_start = time.perf_counter()
        t_s = finite_number("timestamp_s", timestamp_s)
        cfg = self.cfg
        timings = StageTimes()
        self.last_capture = None
        deviation = self.heading_deviation
        if deviation is not None:
            heading_rad = finite_number("heading_rad", heading_rad)
            compass_rad = heading_rad
            heading_rad = compass_rad + deviation.correction_rad(compass_rad)
            if not deviation.known(compass_rad):
                heading_rad = self._seed_heading(deviation, image_rgb, heading_rad, altitude_m, t_s,
                                                 cfg.fov_deg if fov_deg is None else fov_deg,
                                                 tilt_rad, intrinsics_px, distortion)
        try:
            aligned = align_capture(image_rgb, heading_rad, altitude_m,
                                    cfg.fov_deg if fov_deg is None else fov_deg, self.m_per_px,
                                    cfg.crop_mode, (self.matcher.width_px, self.matcher.height_px),
                                    tilt_rad=tilt_rad, intrinsics_px=intrinsics_px, distortion=distortion,
                                    min_template_px=cfg.matcher.min_template_px)
        except TemplateTooLarge as exc:
            log.debug("capture unusable: %s", exc)
            timings.total_ms = (time.perf_counter() - t_start) * _MS
            return self._invalid(t_s, Reason.TEMPLATE_TOO_LARGE, 0, timings)
        except TemplateTooSmall as exc:
            # checked before resampling: no blur and warp for a template that would be dropped
            log.debug("capture at %.1f m gives a %d px template: too small", exc.altitude_m, exc.side_px)
            timings.align_ms = timings.total_ms = (time.perf_counter() - t_start) * _MS
            return self._invalid(t_s, Reason.TEMPLATE_TOO_SMALL, exc.side_px, timings)
        t_align = time.perf_counter()
        timings.align_ms = (t_align - t_start) * _MS
        self.last_capture = aligned      # the undistorted capture (``gray``) for the camera flow
        side = aligned.side_px

        if (reacquire_prior is not None and reacquire_prior[2] is not None
                and self.tracker.state is not TrackState.TRACKING and self._reacquires(t_s)):
            prior_enu_m, prior_radius_m = (reacquire_prior[0], reacquire_prior[1]), reacquire_prior[2]
        rated = self._rated_at(altitude_m)
        near_estimate = None if rated else self._near_estimate_prior(estimate, altitude_m)
        if near_estimate is not None and self.tracker.state is not TrackState.TRACKING:
            prior_enu_m, prior_radius_m = near_estimate, cfg.below_rated_near_estimate_m
        prior_uv = None
        if prior_enu_m is not None and all(math.isfinite(c) for c in prior_enu_m):
            prior_uv = self.matcher.world_to_pixel(prior_enu_m[0], prior_enu_m[1])
        # the inscribed square's mask is all True by construction (perception.alignment): no scan
        full = cfg.crop_mode is CropMode.INSCRIBED_SQUARE or aligned.mask_is_full
        mask = None if full else aligned.mask
        # A prediction from a known velocity (tracking with two good fixes) is what the innovation
        # is measured against; a prior or a one-fix prediction says little about where to be.
        predicted = (self.tracker.state is TrackState.TRACKING
                     and self.tracker.velocity_px_s is not None)
        track_fixes = self.tracker.track_fixes if predicted else 0
        continuing = self.tracker.state is TrackState.TRACKING   # a window match continues this track
        prior_radius_px = None if prior_radius_m is None else prior_radius_m / self.m_per_px
        match = self.tracker.match(aligned.template, t_s, mask=mask, prior_uv=prior_uv,
                                   prior_radius_px=prior_radius_px, offset_px=aligned.centre_offset_px)
        pred = self.tracker.last_prediction
        innovation_px = _NAN
        if predicted and pred is not None:
            innovation_px = math.hypot(match.position_px[0] - pred.uv[0],
                                       match.position_px[1] - pred.uv[1])
        t_match = time.perf_counter()
        self.last_aligned, self.last_match = aligned, match   # for benchmarks and inspection
        timings.ncc_ms = (t_match - t_align) * _MS
        if match.flat_template:
            timings.total_ms = (time.perf_counter() - t_start) * _MS
            return self._invalid(t_s, Reason.FLAT_CAPTURE, side, timings)

        velocity_px_s = None
        if velocity_enu_m_s is not None and all(math.isfinite(c) for c in velocity_enu_m_s):
            velocity_px_s = (velocity_enu_m_s[0] / self.m_per_px, -velocity_enu_m_s[1] / self.m_per_px)
        new_track = match.search is not SearchMode.WINDOW or not continuing
        run, dr_innovation_px, dr_age_s, reach_excess_px = self.track_evidence.observe(
            t_s, match.position_px, match.quality_ok, new_track, velocity_px_s)
        measured_heading_rad = _NAN
        if (deviation is not None and match.quality_ok and run >= deviation.cfg.min_run
                and side >= deviation.cfg.min_template_px and match.search is SearchMode.WINDOW
                and deviation.due(compass_rad)):
            measured_heading_rad = self._learn_heading(deviation, compass_rad, aligned, match,
                                                       cfg.fov_deg if fov_deg is None else fov_deg,
                                                       tilt_rad, intrinsics_px)
        innovation_m = innovation_px * self.m_per_px
        consistent = (self.consistency.observe(t_s, match.position_enu_m)
                      if cfg.resolve_consistent_matches > 0 or near_estimate is not None else 0)
        if new_track:
            self._trusted_track = False         # a global search or re-acquisition: a new track
        if rated:
            decision, reason, p_true, p_classes, variance, p_false, drone = self._decide(
                aligned, match, t_s, timings, innovation_m, run,
                dr_innovation_px * self.m_per_px, dr_age_s, reach_excess_px * self.m_per_px)
            self._trusted_track = decision is Decision.ACCEPT and match.quality_ok
        elif self._continues_track(match, predicted, innovation_m):
            decision, reason, p_true, p_classes, variance, p_false, drone = (
                Decision.ACCEPT, Reason.TRACK_CONTINUATION, _NAN, _NAN_CLASSES, _NAN, _NAN, (_NAN, _NAN))
        elif near_estimate is not None and self._near_estimate_fix(match, near_estimate, consistent):
            decision, reason, p_true, p_classes, variance, p_false, drone = (
                Decision.ACCEPT, Reason.NEAR_ESTIMATE, _NAN, _NAN_CLASSES, _NAN, _NAN, (_NAN, _NAN))
            self.near_estimate_accepted += 1
        else:   # no classification either: a low capture's rating would be written into the map
            if match.quality_ok:
                # a sharp match away from the prediction: not the track that was trusted (a
                # low-quality one is only not used; the tracker coasts and the trust stays)
                self._trusted_track = False
            if not self._told_below_rated:
                self._told_below_rated = True
                log.info("capture at %.1f m: fixes from below %.1f m are rejected (below-rated-height): "
                         "the area rating is made for %.0f m captures (PerceptionConfig.rated_altitude_m, "
                         "min_rated_footprint_share)", altitude_m,
                         self.cfg.rated_altitude_m * math.sqrt(self.cfg.min_rated_footprint_share),
                         self.cfg.rated_altitude_m)
            decision, reason, p_true, p_classes, variance, p_false, drone = (
                Decision.REJECT, Reason.BELOW_RATED_HEIGHT, _NAN, _NAN_CLASSES, _NAN, _NAN, (_NAN, _NAN))
        if cfg.quality_gate and not match.quality_ok and decision is Decision.ACCEPT:
            decision, reason = Decision.REJECT, Reason.LOW_QUALITY
        elif (new_track and match.search is SearchMode.WINDOW and not match.quality_ok
              and reason is not Reason.NEAR_ESTIMATE):
            # a window around a prior (the estimate), not the track's own prediction: the match lies
            # near the estimate by construction, so the rule's position features vouch for anything;
            # only a sharp match may start a track there (docs/perception.md "Dropping a rejected track")
            decision, reason = Decision.REJECT, Reason.LOW_QUALITY
        pointing = None
        if cfg.pointing_attitude_std_deg > 0.0 or cfg.pointing_heading_std_deg > 0.0:
            du, dv = aligned.centre_offset_px
            pointing = pointing_covariance_m2(
                altitude_m, (du * self.m_per_px, -dv * self.m_per_px),
                math.radians(cfg.pointing_attitude_std_deg), math.radians(cfg.pointing_heading_std_deg))
        local_mode = None
        if decision is Decision.ACCEPT and estimate is not None:
            local_mode = self._local_mode(match, pointing, estimate)
            if local_mode is not None and local_mode[0] < cfg.reject_ambiguity_below_posterior:
                decision, reason = Decision.REJECT, Reason.AMBIGUOUS_FAR
                self._trusted_track = False
                self.ambiguities_rejected += 1
        self._follow_verdict(t_s, match, decision, reason)
        covariance_m2 = match.covariance_m2 if pointing is None else match.covariance_m2 + pointing
        resolved = False
        if (decision is Decision.ACCEPT and local_mode is not None and cfg.resolve_ambiguity_min_posterior > 0.0
                and local_mode[0] >= cfg.resolve_ambiguity_min_posterior):
            covariance_m2 = local_mode[1]
            resolved = True
            self.ambiguities_resolved += 1
        # a near-estimate fix is accepted on its consistent predecessors: the same evidence
        by_consistency = reason is Reason.NEAR_ESTIMATE or (
            cfg.resolve_consistent_matches > 0 and consistent >= cfg.resolve_consistent_matches)
        if (decision is Decision.ACCEPT and not resolved and by_consistency and match.ambiguity_weight > 0.0
                and match.local_covariance_m2 is not None):
            covariance_m2 = (match.local_covariance_m2 if pointing is None
                             else match.local_covariance_m2 + pointing)
            resolved = True
            self.ambiguities_resolved_by_consistency += 1
        if cfg.covariance_scale != 1.0:
            covariance_m2 = covariance_m2 * cfg.covariance_scale
        timings.total_ms = (time.perf_counter() - t_start) * _MS
        return FixResult(
            timestamp_s=t_s, valid=True, accepted=decision is Decision.ACCEPT, decision=decision,
            reason=reason, method=self.method, position_enu_m=match.position_enu_m,
            position_px=match.position_px, covariance_m2=covariance_m2, p_true=p_true,
            p_classes=p_classes,
            metrics=match.metrics,
            quality_ok=match.quality_ok, search=match.search, track_state=self.tracker.state,
            statistical_variance_m2=variance, template_side_px=side, timings=timings,
            innovation_px=innovation_px, track_fixes=track_fixes, run=run,
            dr_innovation_px=dr_innovation_px, dr_age_s=dr_age_s,
            reach_excess_px=reach_excess_px, drone_px=drone, p_false=p_false,
            decision_rule=self.rule, ambiguity_resolved=resolved, heading_rad=measured_heading_rad,
            heading_std_rad=(math.radians(cfg.heading_offset.measurement_std_deg)
                             if math.isfinite(measured_heading_rad) else _NAN))

    def _local_mode(self, match: MatchResult, pointing: np.ndarray | None,
                    estimate: tuple[float, float, float, float]) -> tuple[float, np.ndarray] | None:
        """(The share of the posterior an ambiguous match's own peak holds against ``estimate`` (east
        m, north m, 1-sigma east m, 1-sigma north m; ``fix_covariance.local_mode_posterior``), that
        peak's covariance with the pointing term); None when neither
        ``resolve_ambiguity_min_posterior`` nor ``reject_ambiguity_below_posterior`` is on, or the
        match is not ambiguous."""
        cfg = self.cfg
        if (cfg.resolve_ambiguity_min_posterior <= 0.0 and cfg.reject_ambiguity_below_posterior <= 0.0) \
                or match.local_covariance_m2 is None or match.ambiguity_weight <= 0.0:
            return None
        local = match.local_covariance_m2 if pointing is None else match.local_covariance_m2 + pointing
        prior_cov = np.diag([estimate[2] * estimate[2], estimate[3] * estimate[3]])
        share = local_mode_posterior(match.position_enu_m, local, match.ambiguity_weight,
                                     match.search_area_m2, (estimate[0], estimate[1]), prior_cov)
        return share, local

    def _follow_verdict(self, t_s: float, match: MatchResult, decision: Decision, reason: Reason) -> None:
        """Drop the track when the rule has rejected its quality-ok matches for
        ``cfg.drop_rejected_track_s`` with no acceptance between (a false lock the tracker would
        otherwise follow for good): the tracker forgets it, the track evidence ends its run and
        returns to its anchor at the last acceptance, and ``reacquiring`` asks for a search around
        the re-acquisition prior. Any acceptance ends the streak and the re-acquisition."""
        if decision is Decision.ACCEPT:
            self._rejected_since_s = None
            self.reacquiring = False
            self._last_accept_s = t_s
            self.track_evidence.mark_accepted()
            return
        limit = self.cfg.drop_rejected_track_s
        if limit <= 0.0 or not match.quality_ok or reason not in _RULE_REJECTIONS:
            return
        if self._rejected_since_s is None:
            self._rejected_since_s = t_s
        elif t_s - self._rejected_since_s >= limit and self.tracker.state is TrackState.TRACKING:
            self.dropped_tracks += 1
            log.log(logging.INFO if self.dropped_tracks == 1 else logging.DEBUG,
                    "dropping a track the decision rule rejected for %.1f s (drop %d): searching "
                    "around the re-acquisition prior", t_s - self._rejected_since_s, self.dropped_tracks)
            self.tracker.reset()
            self.track_evidence.drop_run()
            self._trusted_track = False
            self._rejected_since_s = None
            self.reacquiring = True

    def _reacquires(self, t_s: float) -> bool:
        """Whether a search without a track goes around the re-acquisition prior now: after a dropped
        track until the next acceptance, and within ``cfg.reacquire_window_s`` of the last one."""
        window = self.cfg.reacquire_window_s
        return self.reacquiring or (window > 0.0 and self._last_accept_s is not None
                                    and t_s - self._last_accept_s <= window)

    def _seed_heading(self, deviation: HeadingDeviation, image, heading_rad: float, altitude_m: float,
                      t_s: float, fov_deg: float, tilt_rad, intrinsics_px, distortion) -> float:
        """The heading among ``heading_rad`` and its ``seed_offsets_deg`` whose capture matches best
        (quality-ok, highest peak) in the window the tracker would search; ``heading_rad`` when the
        tracker has no window (a global search is due) or no candidate is quality-ok. The tracker
        is not touched."""
        pred = self.tracker.predict(t_s)
        if pred is None:
            return heading_rad
        best_peak, best = -math.inf, heading_rad
        for off in (0.0, *deviation.cfg.seed_offsets_deg):
            try:
                a = align_capture(image, heading_rad + math.radians(off), altitude_m, fov_deg,
                                  self.m_per_px, self.cfg.crop_mode,
                                  (self.matcher.width_px, self.matcher.height_px), tilt_rad=tilt_rad,
                                  intrinsics_px=intrinsics_px, distortion=distortion,
                                  min_template_px=self.cfg.matcher.min_template_px)
            except (TemplateTooLarge, TemplateTooSmall):
                return heading_rad
            du, dv = a.centre_offset_px
            r = self.matcher.match(a.template, (pred.uv[0] + du, pred.uv[1] + dv), pred.radius_px,
                                   None if a.mask_is_full else a.mask)
            if r.quality_ok and r.peak > best_peak:
                best_peak, best = r.peak, heading_rad + math.radians(off)
        return best

    def _learn_heading(self, deviation: HeadingDeviation, compass_rad: float, aligned: AlignedCapture,
                       match: MatchResult, fov_deg: float, tilt_rad, intrinsics_px) -> float:
        """One measurement of the compass heading error (perception.heading_offset): the capture
        (already undistorted) re-aligned at -probe and +probe around the heading used, each rotated
        template's NCC peak near the locked-on position, the parabola's vertex. Returns the heading
        measured (the one used turned by the vertex, in [0, 2 pi)); NaN when the peaks have no
        maximum or it lies at the edge of the probe span (the true heading may lie beyond it)."""
        step = math.radians(deviation.cfg.probe_deg)
        u, v = match.position_px
        templates, centres = [], []
        for d in (-step, 0.0, step):
            a = aligned if d == 0.0 else align_capture(
                aligned.gray, aligned.heading_rad + d, aligned.altitude_m, fov_deg, self.m_per_px,
                self.cfg.crop_mode, None, tilt_rad=tilt_rad, intrinsics_px=intrinsics_px)
            templates.append(a.template)
            centres.append((u + a.centre_offset_px[0], v + a.centre_offset_px[1]))
        peaks = rotation_peaks(self.matcher.reference, templates, centres,
                               deviation.cfg.window_radius_px)
        vertex = parabola_vertex(peaks[0], peaks[1], peaks[2], step)
        if vertex is None:
            return _NAN
        deviation.update(compass_rad, aligned.heading_rad - compass_rad + vertex)
        if abs(vertex) >= step:
            return _NAN
        return wrap_2pi(aligned.heading_rad + vertex)

    @property
    def rule(self) -> DecisionRule:
        """The rule that decides (combined only for cnn / assistant-map with a model)."""
        return DecisionRule.COMBINED if self.decision_model is not None else DecisionRule.PAPER

    # ------------------------------------------------------------------------------ decisions
    def _continues_track(self, match: MatchResult, predicted: bool, innovation_m: float) -> bool:
        """A capture below the rated height continues a trusted track (``cfg.track_below_rated``):
        the newest rated verdict on this window track was an acceptance, and this match is a
        quality-ok window match within ``continuation_max_innovation_m`` of the prediction."""
        return (self.cfg.track_below_rated and self._trusted_track and match.quality_ok and predicted
                and match.search is SearchMode.WINDOW
                and innovation_m <= self.cfg.continuation_max_innovation_m)

    def _near_estimate_prior(self, estimate: tuple[float, float, float, float] | None,
                             altitude_m: float) -> tuple[float, float] | None:
        """The estimate's position when a capture below the rated height is searched for and judged
        near it (``cfg.below_rated_near_estimate_m``, a finite estimate given, the capture from at
        least ``cfg.below_rated_min_altitude_m``); None otherwise."""
        cfg = self.cfg
        if cfg.below_rated_near_estimate_m <= 0.0 or estimate is None or altitude_m < cfg.below_rated_min_altitude_m:
            return None
        east, north = float(estimate[0]), float(estimate[1])
        return (east, north) if math.isfinite(east) and math.isfinite(north) else None

    def _near_estimate_fix(self, match: MatchResult, estimate_enu_m: tuple[float, float],
                           consistent: int) -> bool:
        """A capture below the rated height with no trusted track: accept a window match within
        ``cfg.below_rated_near_estimate_m`` of the estimate that is the ``cfg.below_rated_min_run``-th
        (or later) in a row to continue the matches before it at a constant velocity
        (``MatchConsistency``; the matcher's quality flag is not asked: at these heights it calls
        most true matches low-quality). A window track that wandered farther from the estimate is
        dropped: the next capture is searched for around the estimate."""
        cfg = self.cfg
        if match.search is not SearchMode.WINDOW:
            return False
        off_m = math.hypot(match.position_enu_m[0] - estimate_enu_m[0],
                           match.position_enu_m[1] - estimate_enu_m[1])
        if off_m > cfg.below_rated_near_estimate_m:
            if self.tracker.state is TrackState.TRACKING:
                self.tracker.reset()
                self.track_evidence.drop_run()
            return False
        return consistent >= cfg.below_rated_min_run

    def _rated_at(self, altitude_m: float) -> bool:
        """Whether the area rating applies to a capture from ``altitude_m``: always for the methods
        without one (none, statistical); for cnn and assistant-map when the capture covers at least
        ``min_rated_footprint_share`` of the rated footprint's area (``PerceptionConfig``)."""
        if self.method not in (FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP):
            return True
        share = self.cfg.min_rated_footprint_share
        return share <= 0.0 or (altitude_m / self.cfg.rated_altitude_m) ** 2 >= share

    def _decide(self, aligned: AlignedCapture, match: MatchResult, t_s: float,
                timings: StageTimes, innovation_m: float, run: int,
                dr_innovation_m: float, dr_age_s: float, reach_excess_m: float) -> tuple[Decision, Reason, float, tuple, float, float, tuple[float, float]]:
        method = self.method
        no_px = (_NAN, _NAN)
        if method is FalseMatchMethod.NONE:
            return Decision.ACCEPT, Reason.NO_DETECTION, _NAN, _NAN_CLASSES, _NAN, _NAN, no_px
        if method is FalseMatchMethod.STATISTICAL:
            t0 = time.perf_counter()
            flag, var = self._detector.update(match.position_enu_m[0], match.position_enu_m[1], t_s)
            timings.lookup_ms = (time.perf_counter() - t0) * _MS
            if flag:
                return (Decision.REJECT, Reason.STATISTICAL_VARIANCE, _NAN, _NAN_CLASSES, var, _NAN,
                        no_px)
            return Decision.ACCEPT, Reason.ACCEPTED, _NAN, _NAN_CLASSES, var, _NAN, no_px

        u, v = self._drone_pixel(match)
        var = [_NAN] * len(self._variance)
        if self.decision_model is not None:      # every valid fix enters the indicators
            var = [det.update(match.position_enu_m[0], match.position_enu_m[1], t_s)[1]
                   for det in self._variance]
        p_classes = _NAN_CLASSES
        bad_reason = Reason.MAP_BAD_AREA
        p_bad = _NAN
        if method is FalseMatchMethod.ASSISTANT_MAP:
            t0 = time.perf_counter()
            p_true = self.assistant_map.lookup(u, v)
            timings.lookup_ms = (time.perf_counter() - t0) * _MS
            if math.isfinite(p_true):
                p_bad = 1.0 - p_true
            elif self.classify is None:
                if self.cfg.unknown_policy is UnknownPolicy.ACCEPT:
                    return Decision.ACCEPT, Reason.ACCEPTED, _NAN, _NAN_CLASSES, _NAN, _NAN, (u, v)
                return Decision.REJECT, Reason.MAP_UNKNOWN, _NAN, _NAN_CLASSES, _NAN, _NAN, (u, v)
        if not math.isfinite(p_bad):
            # cnn, or assistant-map with an unknown pixel and a classifier: classify and write.
            p_bad, p_classes = self._classify(aligned, timings)
            t0 = time.perf_counter()
            self.assistant_map.write_patch(u, v, self._patch_side_px(), 1.0 - p_bad)
            timings.lookup_ms += (time.perf_counter() - t0) * _MS
            bad_reason = Reason.CNN_BAD_AREA
        p_false = _NAN
        if self.decision_model is None:
            decision = decide_from_p_bad(p_bad, self.cfg.p_bad_threshold)
        else:
            feats = combined_features(p_bad, match.peak, match.psr, match.second_peak_ratio,
                                      innovation_m, run, dr_innovation_m, dr_age_s, *var,
                                      reach_excess_m)
            decision, p_false = self.decision_model.decide(feats)
            bad_reason = Reason.LIKELY_FALSE
        reason = Reason.ACCEPTED if decision is Decision.ACCEPT else bad_reason
        return decision, reason, 1.0 - p_bad, p_classes, _NAN, p_false, (u, v)

    def _classify(self, aligned: AlignedCapture,
                  timings: StageTimes) -> tuple[float, tuple[float, float, float, float]]:
        t0 = time.perf_counter()
        n = self.cfg.cnn_input_px
        gray = aligned.gray
        if gray.shape != (n, n):
            interp = cv2.INTER_AREA if min(gray.shape) > n else cv2.INTER_LINEAR
            gray = cv2.resize(gray, (n, n), interpolation=interp)
        p_bad, classes = split_classifier_output(self.classify(gray[None, :, :]), 1)
        timings.cnn_ms = (time.perf_counter() - t0) * _MS
        if classes is not None and classes.shape[1] == N_PAPER_CLASSES:
            p_classes = tuple(float(c) for c in classes[0])
        else:
            p_classes = _NAN_CLASSES
        return float(p_bad[0]), p_classes

    def _drone_pixel(self, match: MatchResult) -> tuple[float, float]:
        pred = self.tracker.last_prediction
        if not match.quality_ok and pred is not None:
            return pred.uv
        return match.position_px

    def _patch_side_px(self) -> float:
        movement = self.tracker.last_movement_px()
        return float(min(self.cfg.assistant_patch_max_px, max(1.0, 2.0 * movement)))

    def refused(self, t_s: float, reason: Reason) -> FixResult:
        """An invalid result for a capture refused before any processing (e.g. Reason.CAMERA_MISMATCH)."""
        return self._invalid(t_s, reason, 0, StageTimes())

    def _invalid(self, t_s: float, reason: Reason, side: int, timings: StageTimes) -> FixResult:
        nan_cov = np.full((2, 2), np.nan)
        return FixResult(
            timestamp_s=t_s, valid=False, accepted=False, decision=Decision.REJECT, reason=reason,
            method=self.method, position_enu_m=(_NAN, _NAN), position_px=(_NAN, _NAN),
            covariance_m2=nan_cov, p_true=_NAN, p_classes=_NAN_CLASSES,
            metrics=MatchMetrics.unknown(), quality_ok=False, search=None,
            track_state=self.tracker.state, statistical_variance_m2=_NAN, template_side_px=side,
            timings=timings)
