"""Configuration of the perception algorithms and node (frozen dataclasses, units in the key names).

``PerceptionNodeConfig`` is the scenario's ``perception`` section; ``ExpectedCamera`` is the camera the
node is configured for (derived by the app layer from ``sim.camera``).

Loaded with ``scenenav.core.config.load_config(PerceptionConfig, mapping)``; range checks raise
``ConfigError`` through ``scenenav.core.config.check``. See docs/perception.md for what each key does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

from perception.decision import P_BAD_THRESHOLD, DecisionRule, FalseMatchMethod
from perception.heading_offset import HeadingOffsetConfig
from scenenav.core.config import check


def check_near_estimate(radius_m: float, min_run: int, min_altitude_m: float, prefix: str) -> None:
    """The below-rated search near the estimate: a radius in [0, 200] m (0 = off), a run >= 1 and a
    lowest height >= 0 m."""
    check(0.0 <= radius_m <= 200.0, f"{prefix}below_rated_near_estimate_m", radius_m,
          "a number of metres in [0, 200] (0 = off)")
    check(type(min_run) is int and 1 <= min_run <= 100, f"{prefix}below_rated_min_run", min_run,
          "an integer number of matches in [1, 100]")
    check(0.0 <= min_altitude_m <= 1000.0, f"{prefix}below_rated_min_altitude_m", min_altitude_m,
          "a height in [0, 1000] m")

class NccMethod(str, Enum):
    """Correlation score passed to cv2.matchTemplate.

    ``ccorr_normed`` is exactly the paper's equation (1). ``ccoeff_normed`` is its zero-mean variant
    (template and window each minus their mean): invariant to a brightness offset between the day the
    reference was taken and the flight, and its correlation surface has a zero baseline, so the peak
    stands out (higher PSR). It is the default because it matches far more reliably on our data
    (see docs/perception.md, "Choice of NCC").
    """

    CCORR_NORMED = "ccorr_normed"
    CCOEFF_NORMED = "ccoeff_normed"


class CropMode(str, Enum):
    """What part of the rotated capture becomes the template."""

    INSCRIBED_SQUARE = "inscribed-square"   # largest axis-aligned square inside the rotated image
    MASKED_BOUNDS = "masked-bounds"          # full bounding box + validity mask (masked NCC, slower)


class UnknownPolicy(str, Enum):
    """Assistant-map method: what to do where the map has no value and no classifier is available."""

    REJECT = "reject"
    ACCEPT = "accept"


@dataclass(frozen=True)
class MatcherConfig:
    """NCC matcher, tracker window and quality thresholds."""

    ncc_method: NccMethod = NccMethod.CCOEFF_NORMED
    # Tracking window: template + 2 * radius, radius = margin * (1 + misses) + factor * movement.
    min_window_margin_px: int = 24
    movement_factor: float = 1.0
    max_speed_m_s: float = 25.0          # window radius when the velocity is not known yet
    max_search_radius_px: int = 400      # a larger radius triggers a global search instead
    lost_after_n: int = 3                # consecutive low-quality matches before a global search
    # Quality gate ("low quality" = any of these fails, or the peak sits on the window border).
    # Calibrated on generated worlds against their other-day reference maps (true fixes: peak
    # p10 0.61, PSR p10 4.3, second-peak ratio p90 0.79; false fixes: peak p90 0.40, second-peak
    # ratio p50 0.94), see docs/perception.md.
    min_peak: float = 0.4
    min_psr: float = 3.0
    max_second_peak_ratio: float = 0.95
    # Covariance: fully confident at/above peak_confident and psr_confident and at/below
    # second_peak_ratio_confident; fully ambiguous at min_peak / min_psr / max_second_peak_ratio.
    peak_confident: float = 0.55
    psr_confident: float = 5.0
    second_peak_ratio_confident: float = 0.75
    exclusion_radius_px: int = 6         # around the peak, for PSR and the second peak
    cov_floor_px: float = 0.3            # 1-sigma floor on the position (interpolation, resampling)
    cov_local_scale: float = 1.0         # multiplies the peak-curvature term of the covariance
    # Global search.
    coarse_above_px: int = 2048          # maps with a larger side use coarse-to-fine global search
    coarse_target_px: int = 1024         # coarsest pyramid level has a side <= this
    min_coarse_template_px: int = 16     # a coarse level is used only if the template stays this big
    coarse_candidates: int = 5           # coarse peaks verified at full resolution
    # Template limits.
    min_template_px: int = 16
    # Position refinement on gradient magnitude (docs/perception.md "Gradient refinement"): after the
    # intensity search, the position is taken from the NCC of the Sobel gradient magnitude of template
    # and reference within this many px of the intensity peak; the quality metrics and covariance stay
    # the intensity search's. Edges move less than shading between the reference's day and the
    # flight's (sun, exposure), so true fixes are tighter. 0 = off (the intensity peak, as before).
    gradient_refine_radius_px: int = 0

    def __post_init__(self) -> None:
        check(self.min_window_margin_px >= 2, "matcher.min_window_margin_px", self.min_window_margin_px,
              "an integer >= 2")
        check(self.movement_factor >= 0.0, "matcher.movement_factor", self.movement_factor,
              "a number >= 0")
        check(self.max_speed_m_s > 0.0, "matcher.max_speed_m_s", self.max_speed_m_s, "a positive number")
        check(self.max_search_radius_px >= self.min_window_margin_px, "matcher.max_search_radius_px",
              self.max_search_radius_px, "an integer >= min_window_margin_px")
        check(self.lost_after_n >= 1, "matcher.lost_after_n", self.lost_after_n, "an integer >= 1")
        check(-1.0 <= self.min_peak <= 1.0, "matcher.min_peak", self.min_peak, "a number in [-1, 1]")
        check(self.min_peak < self.peak_confident <= 1.0, "matcher.peak_confident",
              self.peak_confident, "a number in (min_peak, 1]")
        check(self.min_psr >= 0.0, "matcher.min_psr", self.min_psr, "a number >= 0")
        check(self.psr_confident > self.min_psr, "matcher.psr_confident", self.psr_confident,
              "a number > min_psr")
        check(0.0 < self.max_second_peak_ratio <= 1.0, "matcher.max_second_peak_ratio",
              self.max_second_peak_ratio, "a number in (0, 1]")
        check(0.0 <= self.second_peak_ratio_confident < self.max_second_peak_ratio,
              "matcher.second_peak_ratio_confident", self.second_peak_ratio_confident,
              "a number in [0, max_second_peak_ratio)")
        check(self.exclusion_radius_px >= 1, "matcher.exclusion_radius_px", self.exclusion_radius_px,
              "an integer >= 1")
        check(self.cov_floor_px > 0.0, "matcher.cov_floor_px", self.cov_floor_px, "a positive number")
        check(self.cov_local_scale >= 0.0, "matcher.cov_local_scale", self.cov_local_scale,
              "a number >= 0")
        check(self.coarse_target_px >= 64, "matcher.coarse_target_px", self.coarse_target_px,
              "an integer >= 64")
        check(self.coarse_above_px >= self.coarse_target_px, "matcher.coarse_above_px",
              self.coarse_above_px, "an integer >= coarse_target_px")
        check(self.min_coarse_template_px >= 8, "matcher.min_coarse_template_px",
              self.min_coarse_template_px, "an integer >= 8")
        check(self.coarse_candidates >= 1, "matcher.coarse_candidates", self.coarse_candidates,
              "an integer >= 1")
        check(self.min_template_px >= 8, "matcher.min_template_px", self.min_template_px,
              "an integer >= 8")
        check(0 <= self.gradient_refine_radius_px <= 200, "matcher.gradient_refine_radius_px",
              self.gradient_refine_radius_px, "an integer of map px in [0, 200] (0 = off)")


@dataclass(frozen=True)
class PerceptionConfig:
    """The whole perception pipeline (alignment, matcher, decision)."""

    method: FalseMatchMethod = FalseMatchMethod.NONE
    fov_deg: float = 60.0                      # horizontal FOV of a capture that does not state its own
    crop_mode: CropMode = CropMode.INSCRIBED_SQUARE
    cnn_input_px: int = 200                    # the classifier sees (N, cnn_input_px, cnn_input_px)
    p_bad_threshold: float = P_BAD_THRESHOLD   # paper 5.4: reject when P(bad) > 0.5
    # cnn / assistant-map verdict: paper = P(bad) > p_bad_threshold; combined = the logistic
    # P(false fix) of decision_model (area P(bad) + NCC quality + innovation), docs/perception.md.
    decision_rule: DecisionRule = DecisionRule.PAPER
    decision_model: str = ""                   # combined-rule JSON ("": the shipped model)
    statistical_window: int = 30               # paper 6.3
    statistical_threshold_m2: float = 1.4      # paper 6.3 / Figure 8
    unknown_policy: UnknownPolicy = UnknownPolicy.REJECT
    assistant_patch_max_px: int = 32           # cap on the written patch side (2 x last movement)
    quality_gate: bool = False                 # also reject what the matcher flags low quality
    true_match_tolerance_m: float = 5.0        # evaluation: a fix this close to the truth is true
    # The area rating of the cnn and assistant-map methods (the CNN's training captures, the
    # assistant map's cells) is made for the camera footprint at rated_altitude_m (paper 6.1: 100 m;
    # DatasetConfig.altitude_m, build_assistant_map's altitude_m). A capture from lower down covers
    # (altitude / rated_altitude_m)^2 of that footprint's area; below min_rated_footprint_share the
    # rating does not describe it and its fix is rejected (reason below-rated-height). 0 = off (the
    # library default; the perception node turns it on: PerceptionNodeConfig.min_rated_footprint_share).
    rated_altitude_m: float = 100.0
    min_rated_footprint_share: float = 0.0
    # Below that height, a match may still continue a track whose last rated fix was accepted
    # (docs/perception.md "Track continuation below the rated height"): window search, quality-ok,
    # within continuation_max_innovation_m of the tracker's constant-velocity prediction. Off: rejected.
    track_below_rated: bool = False
    continuation_max_innovation_m: float = 2.0
    # Below that height but from below_rated_min_altitude_m up, with no trusted track (the climb),
    # the search goes to a window of this radius around the estimate the caller gives
    # (``process(estimate=...)``, the autopilot's), and a window match there is accepted (reason
    # near-estimate) when it lies within the radius of the estimate and is the below_rated_min_run-th
    # in a row to continue its predecessors at a constant velocity (MatchConsistency, within
    # consistent_match_tol_m): a false one is at most that far off (docs/perception.md "Fixes near
    # the estimate below the rated height"). 0 = off: rejected (below-rated-height).
    below_rated_near_estimate_m: float = 0.0
    below_rated_min_run: int = 5
    below_rated_min_altitude_m: float = 45.0
    matcher: MatcherConfig = field(default_factory=MatcherConfig)
    # learn the compass heading error from the matches (perception.heading_offset); off: raw compass
    heading_offset: HeadingOffsetConfig = field(default_factory=HeadingOffsetConfig)
    # the pointing the alignment assumes, 1 sigma: the attitude (roll, pitch) and the heading it was
    # given. Added to every fix's covariance (fix_covariance.pointing_covariance_m2); 0 = exact inputs
    pointing_attitude_std_deg: float = 0.0
    pointing_heading_std_deg: float = 0.0
    # Every published covariance (the matcher's, with the pointing term) times this: a calibration
    # of the matcher's model against measured fix errors (docs/perception.md "Covariance"); 1 = as modelled
    covariance_scale: float = 1.0
    # A window track whose quality-ok matches the decision rule has rejected for this long, with no
    # acceptance between, is dropped; the next search is around the position the caller gives for a
    # re-acquisition (``process(reacquire_prior=...)``, the autopilot's estimate) or, without one, the
    # whole map (docs/perception.md "Dropping a rejected track"). 0 = off: the tracker keeps it.
    drop_rejected_track_s: float = 0.0
    # For this long after the last accepted fix, a search without a track (the tracker lost it after
    # low-quality matches, or dropped it) goes around the re-acquisition prior instead of the whole map:
    # the estimate the accepted fixes kept is better than any global match (docs/perception.md
    # "Dropping a rejected track"). 0 = off (only a dropped track is searched for around the prior).
    reacquire_window_s: float = 0.0
    # An accepted match whose covariance carries the ambiguity term ("here, or anywhere in the area
    # searched": a global search, a low-quality match) is published with its local covariance
    # ("here") when, against the estimate the caller gives (``process(estimate=...)``, the autopilot's),
    # the local mode holds at least this share of the posterior (fix_covariance.local_mode_posterior;
    # docs/perception.md "Resolving an ambiguous match with the estimate"). 0 = off: the mixture's
    # moment, as wide as the area searched, which the EKF barely uses.
    resolve_ambiguity_min_posterior: float = 0.0
    # ... and one whose own peak holds less than this share is rejected (reason ambiguous-far): the
    # mixture's posterior is then the prior, the fix says nothing, and fused with the mixture's wide
    # covariance ten times a second, a run of such false fixes pulls the estimate away. 0 = off.
    reject_ambiguity_below_posterior: float = 0.0
    # An accepted ambiguous match that continues the previous matches at a constant velocity, this
    # many times in a row (each within consistent_match_tol_m of the line through the two before it,
    # the frames at most CONSISTENT_MATCH_MAX_GAP_S apart), is published with its own peak's
    # covariance: independent searches of consecutive frames agreeing on one moving place
    # (docs/perception.md "Resolving an ambiguous match by its consistent predecessors"). 0 = off.
    resolve_consistent_matches: int = 0
    consistent_match_tol_m: float = 2.0

    def __post_init__(self) -> None:
        check(0.0 < self.fov_deg < 170.0, "perception.fov_deg", self.fov_deg, "a number in (0, 170)")
        check(16 <= self.cnn_input_px <= 1024, "perception.cnn_input_px", self.cnn_input_px,
              "an integer in [16, 1024]")
        check(0.0 < self.p_bad_threshold < 1.0, "perception.p_bad_threshold", self.p_bad_threshold,
              "a number in (0, 1)")
        check(self.statistical_window >= 3, "perception.statistical_window", self.statistical_window,
              "an integer >= 3")
        check(self.statistical_threshold_m2 > 0.0 and math.isfinite(self.statistical_threshold_m2),
              "perception.statistical_threshold_m2", self.statistical_threshold_m2, "a positive number")
        check(self.assistant_patch_max_px >= 1, "perception.assistant_patch_max_px",
              self.assistant_patch_max_px, "an integer >= 1")
        check(self.true_match_tolerance_m > 0.0, "perception.true_match_tolerance_m",
              self.true_match_tolerance_m, "a positive number")
        check(self.rated_altitude_m > 0.0 and math.isfinite(self.rated_altitude_m),
              "perception.rated_altitude_m", self.rated_altitude_m, "a positive number of metres")
        check(0.0 <= self.min_rated_footprint_share <= 1.0, "perception.min_rated_footprint_share",
              self.min_rated_footprint_share, "a number in [0, 1] (0 = off)")
        for name in ("pointing_attitude_std_deg", "pointing_heading_std_deg"):
            value = getattr(self, name)
            check(0.0 <= value <= 30.0, f"perception.{name}", value, "a number of degrees in [0, 30]")
        check(0.0 < self.continuation_max_innovation_m < 100.0, "perception.continuation_max_innovation_m",
              self.continuation_max_innovation_m, "a positive number of metres below 100")
        check(0.0 < self.covariance_scale <= 100.0, "perception.covariance_scale", self.covariance_scale,
              "a number in (0, 100]")
        check_near_estimate(self.below_rated_near_estimate_m, self.below_rated_min_run,
                            self.below_rated_min_altitude_m, "perception.")
        check(0.0 <= self.drop_rejected_track_s <= 600.0 and math.isfinite(self.drop_rejected_track_s),
              "perception.drop_rejected_track_s", self.drop_rejected_track_s,
              "a number of seconds in [0, 600] (0 = off)")
        check(0.0 <= self.reacquire_window_s <= 3600.0, "perception.reacquire_window_s",
              self.reacquire_window_s, "a number of seconds in [0, 3600] (0 = off)")
        check(0.0 <= self.resolve_ambiguity_min_posterior < 1.0, "perception.resolve_ambiguity_min_posterior",
              self.resolve_ambiguity_min_posterior, "a share in [0, 1) (0 = off)")
        check(0.0 <= self.reject_ambiguity_below_posterior < 1.0, "perception.reject_ambiguity_below_posterior",
              self.reject_ambiguity_below_posterior, "a share in [0, 1) (0 = off)")
        check(type(self.resolve_consistent_matches) is int and 0 <= self.resolve_consistent_matches <= 100,
              "perception.resolve_consistent_matches", self.resolve_consistent_matches,
              "an integer number of matches in [0, 100] (0 = off)")
        check(0.0 < self.consistent_match_tol_m <= 100.0, "perception.consistent_match_tol_m",
              self.consistent_match_tol_m, "a distance in (0, 100] m")


#: ``PerceptionNodeConfig.alignment`` values: how a FIXED-mount capture is aligned with the map.
ALIGNMENTS = ("rotation-scale", "homography")


@dataclass(frozen=True)
class PerceptionNodeConfig:
    """The ``perception`` section of a scenario: which perception node(s) a run starts and how."""

    enabled: bool = True
    method: str = "none"               # cnn | assistant-map | statistical | none
    assistant_map: str = ""            # .npz for method assistant-map (empty: built online)
    weights: str = ""                  # CNN weights .pt (empty: perception/weights/default.pt)
    reference: str = "default"         # map matched against: default (the world manifest's kind),
                                       # orthophoto (reference.png) or perspective (reference_perspective.png)
    lockstep: bool = True              # the simulator waits for this node's answer to each frame
    decision_rule: str = "paper"       # cnn, assistant-map: paper (P(bad) > 0.5) or combined (docs/perception.md)
    decision_model: str = ""           # combined rule: a model .json, or a shipped one by name: ideal or realistic (empty: ideal)
    swap_at_s: float = 0.0             # > 0: at this simulated time a second node takes over (swap)
    swap_method: str = "statistical"   # method of that second node (perception-2)
    swap_every_s: float = 0.0          # > 0 (with swap_at_s > 0): swap again every this many simulated s,
                                       # back and forth between the two nodes and their methods
    max_restarts: int = 2              # the launcher starts our perception node again when it fails in
                                       # flight, at most this many times a run (docs/faults.md); 0 = never
    alignment: str = "rotation-scale"  # FIXED-mount frames: rotation-scale (as if nadir) or homography
                                       # (from the autopilot's estimated roll and pitch; docs/perception.md)
    # the footprint the area rating was made for is PerceptionConfig.rated_altitude_m's (100 m);
    # docs/perception.md, "Rated height"
    min_rated_footprint_share: float = 0.0  # cnn, assistant-map: reject fixes of captures covering less of the rated footprint's area (0.5: below 70.7 m; 0 = off)
    heading_learning: bool = False     # learn the compass heading error from the matches and correct
                                       # it before alignment (perception.heading_offset; docs/realism.md)
    prior_from_estimate: bool = False  # without a track, search a window around the autopilot's estimate
                                       # (autopilot/estimate) of radius prior_margin_px + 3 sigma, not the map
    prior_margin_px: int = 24
    # the pointing the alignment is given, 1 sigma, added to each fix's covariance (PerceptionConfig;
    # docs/perception.md "Covariance"); 0: exact inputs. Profiles set them (scenenav/app/realism.py)
    pointing_attitude_std_deg: float = 0.0   # the estimated roll / pitch (fixed mount) or the gimbal's
    pointing_heading_std_deg: float = 0.0    # the heading the capture is turned with
    track_below_rated: bool = False    # below the rated height, accept matches that continue a track
                                       # whose last rated fix was accepted (docs/perception.md)
    below_rated_near_estimate_m: float = 0.0  # below the rated height with no trusted track (the climb),
                                       # search this far around the autopilot's estimate and accept a
                                       # match there that is the below_rated_min_run-th in a row on one
                                       # constant-velocity line (PerceptionConfig's; docs/perception.md); 0 = off
    below_rated_min_run: int = 5
    below_rated_min_altitude_m: float = 45.0  # ... from this height up (below: the relief's parallax)
    covariance_scale: float = 1.0      # every published fix covariance times this (a calibration;
                                       # docs/perception.md "Covariance"); 1 = as modelled
    gradient_refine_radius_px: int = 0  # refine each match's position on gradient magnitude within this
                                       # many map px (MatcherConfig; docs/perception.md); 0 = off
    dr_from_estimate: bool = False     # dead-reckon the track evidence's anchor with the autopilot's
                                       # estimated velocity, not at constant velocity (docs/perception.md)
    drop_rejected_track_s: float = 0.0  # drop a track the decision rule has rejected this long and search
                                       # again around the autopilot's estimate (docs/perception.md); 0 = off
    reacquire_window_s: float = 0.0    # for this long after the last accepted fix, search around the
                                       # estimate, not the whole map, when the track is lost (0 = off)
    reacquire_min_radius_m: float = 30.0  # that search's radius: prior_margin_px + 3 sigma of the
                                       # estimate, at least this (the estimate's sigma is optimistic)
    resolve_ambiguity_min_posterior: float = 0.0  # publish an accepted ambiguous match with its local
                                       # covariance when it holds this share of the posterior against
                                       # the autopilot's estimate (PerceptionConfig's; 0 = off)
    reject_ambiguity_below_posterior: float = 0.0  # reject one whose own peak holds less than this
                                       # share (reason ambiguous-far; PerceptionConfig's; 0 = off)
    resolve_consistent_matches: int = 0   # publish an accepted ambiguous match with its local covariance
                                       # when it continues this many matches at a constant velocity
                                       # (PerceptionConfig's; 0 = off)
    consistent_match_tol_m: float = 2.0   # how far from the constant-velocity line a match may lie
    confirm_successors: int = 0        # hold each fix until this many more valid matches arrived and
                                       # accept it only if they lie on one constant-velocity track with it
                                       # (perception/match_confirmation.py, docs/perception.md); 0 = off
    confirm_tol_m: float = 2.0         # how far from that track a match may lie
    confirm_max_span_s: float = 0.8    # successors later than this after the fix: unconfirmed (keep it
                                       # below the autopilot's vision_max_age_s, or held fixes go stale)
    camera_flow: bool = False          # measure the camera's optical flow between consecutive fixed-mount
                                       # frames and publish it with each fix (VisionFix version 3,
                                       # perception/frame_flow.py; fused by the autopilot with SN_CAM_FLOW 1)

    def __post_init__(self) -> None:
        methods = ("cnn", "assistant-map", "statistical", "none")
        check(self.method in methods, "method", self.method, "one of cnn, assistant-map, statistical, none")
        check(type(self.confirm_successors) is int and 0 <= self.confirm_successors <= 50,
              "confirm_successors", self.confirm_successors, "an integer number of matches in [0, 50] (0 = off)")
        check(0.0 < self.confirm_tol_m <= 100.0, "confirm_tol_m", self.confirm_tol_m, "a distance in (0, 100] m")
        check(0.0 < self.confirm_max_span_s <= 10.0, "confirm_max_span_s", self.confirm_max_span_s,
              "a number of seconds in (0, 10]")
        check(self.decision_rule in ("paper", "combined"), "decision_rule", self.decision_rule,
              "paper or combined")
        check(self.reference in ("default", "orthophoto", "perspective"), "reference", self.reference,
              "default (the world manifest's kind), orthophoto or perspective")
        check(not (self.decision_rule == "combined" and self.weights.endswith(".pt")), "weights",
              self.weights, "empty with decision_rule combined (the decision model names the CNN it "
              "was fitted with; choose another model with decision_model)")
        check(type(self.max_restarts) is int and 0 <= self.max_restarts <= 100, "max_restarts",
              self.max_restarts, "an integer number of restarts in [0, 100] (0 = never restart)")
        check(self.swap_at_s >= 0, "swap_at_s", self.swap_at_s, ">= 0 s (0 = no swap)")
        check(self.swap_method in methods, "swap_method", self.swap_method,
              "one of cnn, assistant-map, statistical, none")
        check(0.0 <= self.min_rated_footprint_share <= 1.0, "min_rated_footprint_share",
              self.min_rated_footprint_share, "a number in [0, 1] (0 = off)")
        check(self.prior_margin_px >= 0, "prior_margin_px", self.prior_margin_px, "an integer >= 0 (map px)")
        for name in ("pointing_attitude_std_deg", "pointing_heading_std_deg"):
            value = getattr(self, name)
            check(0.0 <= value <= 30.0, name, value, "a number of degrees in [0, 30]")
        check(self.alignment in ALIGNMENTS, "alignment", self.alignment, "one of " + ", ".join(ALIGNMENTS))
        check(self.swap_every_s == 0 or (self.swap_every_s >= 10.0 and self.swap_at_s > 0),
              "swap_every_s", self.swap_every_s,
              "0 (one swap at most) or >= 10 simulated s, with swap_at_s > 0 (the first swap)")
        check(0.0 < self.covariance_scale <= 100.0, "covariance_scale", self.covariance_scale,
              "a number in (0, 100] (1 = the covariance as modelled)")
        check_near_estimate(self.below_rated_near_estimate_m, self.below_rated_min_run,
                            self.below_rated_min_altitude_m, "")
        check(0 <= self.gradient_refine_radius_px <= 200, "gradient_refine_radius_px",
              self.gradient_refine_radius_px, "an integer of map px in [0, 200] (0 = off)")
        check(0.0 <= self.drop_rejected_track_s <= 600.0, "drop_rejected_track_s", self.drop_rejected_track_s,
              "a number of seconds in [0, 600] (0 = off)")
        check(0.0 <= self.resolve_ambiguity_min_posterior < 1.0, "resolve_ambiguity_min_posterior",
              self.resolve_ambiguity_min_posterior, "a share in [0, 1) (0 = off)")
        check(0.0 <= self.reject_ambiguity_below_posterior < 1.0, "reject_ambiguity_below_posterior",
              self.reject_ambiguity_below_posterior, "a share in [0, 1) (0 = off)")
        check(type(self.resolve_consistent_matches) is int and 0 <= self.resolve_consistent_matches <= 100,
              "resolve_consistent_matches", self.resolve_consistent_matches,
              "an integer number of matches in [0, 100] (0 = off)")
        check(0.0 < self.consistent_match_tol_m <= 100.0, "consistent_match_tol_m",
              self.consistent_match_tol_m, "a distance in (0, 100] m")
        check(0.0 <= self.reacquire_window_s <= 3600.0, "reacquire_window_s", self.reacquire_window_s,
              "a number of seconds in [0, 3600] (0 = off)")
        check(0.0 <= self.reacquire_min_radius_m <= 1000.0, "reacquire_min_radius_m",
              self.reacquire_min_radius_m, "a number of metres in [0, 1000]")

    def pipeline_config(self, fov_deg: float) -> PerceptionConfig:
        """The pipeline's ``PerceptionConfig`` for these node settings and the camera's FOV (the one
        place the scenario's ``perception`` keys become the algorithm's; the decision rule follows
        from the weights file, ``perception.node.make_pipeline``)."""
        return PerceptionConfig(
            fov_deg=fov_deg, min_rated_footprint_share=self.min_rated_footprint_share,
            heading_offset=HeadingOffsetConfig(enabled=self.heading_learning),
            pointing_attitude_std_deg=self.pointing_attitude_std_deg,
            pointing_heading_std_deg=self.pointing_heading_std_deg,
            track_below_rated=self.track_below_rated, covariance_scale=self.covariance_scale,
            below_rated_near_estimate_m=self.below_rated_near_estimate_m,
            below_rated_min_run=self.below_rated_min_run,
            below_rated_min_altitude_m=self.below_rated_min_altitude_m,
            drop_rejected_track_s=self.drop_rejected_track_s, reacquire_window_s=self.reacquire_window_s,
            resolve_ambiguity_min_posterior=self.resolve_ambiguity_min_posterior,
            reject_ambiguity_below_posterior=self.reject_ambiguity_below_posterior,
            resolve_consistent_matches=self.resolve_consistent_matches,
            consistent_match_tol_m=self.consistent_match_tol_m,
            matcher=MatcherConfig(gradient_refine_radius_px=self.gradient_refine_radius_px))

    @property
    def uses_estimate_position(self) -> bool:
        """The node reads the autopilot estimate's position (and 1-sigma): a search prior, a
        re-acquisition, the ambiguity resolution or rejection."""
        return (self.prior_from_estimate or self.reacquires or self.resolve_ambiguity_min_posterior > 0.0
                or self.reject_ambiguity_below_posterior > 0.0 or self.below_rated_near_estimate_m > 0.0)

    @property
    def reacquires(self) -> bool:
        """A lost or dropped track is searched for around the estimate."""
        return self.drop_rejected_track_s > 0.0 or self.reacquire_window_s > 0.0


#: A frame's FOV may differ from the expected one by this much (JSON round trip, config rounding).
FOV_TOLERANCE_DEG = 1e-6


@dataclass(frozen=True)
class ExpectedCamera:
    """The camera the perception node expects (the app layer derives it from the scenario's
    ``sim.camera`` section). A ``CameraFrame`` that contradicts it is refused."""

    fov_deg: float = 60.0          # horizontal field of view
    width_px: int = 200
    height_px: int = 200

    def __post_init__(self) -> None:
        check(0.0 < self.fov_deg < 170.0, "fov_deg", self.fov_deg, "a number in (0, 170)")
        check(self.width_px >= 8 and self.height_px >= 8, "width_px/height_px",
              (self.width_px, self.height_px), "integers >= 8")

    def mismatch(self, fov_deg: float, width_px: int, height_px: int) -> str | None:
        """What in a frame's camera (FOV, size) contradicts this one; None when it matches."""
        problems = []
        if (width_px, height_px) != (self.width_px, self.height_px):
            problems.append(f"{width_px}x{height_px} px, expected {self.width_px}x{self.height_px} px")
        if not (math.isfinite(fov_deg) and math.isclose(fov_deg, self.fov_deg, rel_tol=0.0,
                                                        abs_tol=FOV_TOLERANCE_DEG)):
            problems.append(f"fov {fov_deg!r} deg, expected {self.fov_deg} deg")
        return "; ".join(problems) or None
