"""Learn the compass's heading error from the scene matches themselves (a deviation card).

A calibrated magnetometer on a multicopter still has a heading error of several degrees: the
residual hard iron after the onboard calibration (a one-cycle error in the heading), soft iron (two
cycles) and the motor current's field tilted with the body (docs/realism.md: 6-9 degrees at some
headings on the ``realistic`` profile). The template is rotated north-up by the compass heading, so
that error rotates the template against the map: at 7-9 degrees the NCC peak drops and most window
matches of the ``realistic`` flights fail (docs/realism.md, "What breaks matching on `realistic`").
The autopilot's EKF heading does not help: its only yaw reference is the same compass.

A navigator keeps a *deviation card*: the compass error per heading, measured against known
bearings. Here the known bearing is the map. After a window match that continues a run of at least
``min_run`` quality-ok matches (the tracker is locked on, so the position is right; a false lock
rarely holds a run: measured on the ``realistic`` flights, false locks had runs of 0-1), the capture is aligned again with the heading turned by
``-probe_deg`` and ``+probe_deg``; the NCC peak of each near the matched position
(``rotation_peaks``) and the peak of the match itself give a parabola whose vertex is the rotation
that fits the map best (``parabola_vertex``, clipped to the probe span: a larger error is walked off
over a few frames). ``HeadingDeviation`` keeps one estimate per heading sector (``sector_deg``),
updated by an exponential average, and gives the correction for a heading as the weighted mean of
the two nearest sectors' estimates, over those that have one (none: no correction). The correction is added to the compass heading before alignment.

Pure numpy + OpenCV. No truth is used: the measurement is the rotation between the capture and the
reference at the position the matcher found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from scenenav.core.config import check
from scenenav.core.frames import wrap_2pi, wrap_pi


@dataclass(frozen=True)
class HeadingOffsetConfig:
    """Learning the compass heading error from the matches (``enabled`` off: the raw compass)."""

    enabled: bool = False
    probe_deg: float = 4.0          # the captures are re-aligned at -probe and +probe around the heading
    sector_deg: float = 30.0        # one estimate per heading sector of this width
    gain: float = 0.25              # exponential-average gain once a sector has 1 / gain measurements
    window_radius_px: int = 12      # the rotated templates' peaks are searched this far around the match
    max_offset_deg: float = 20.0    # the learned correction is clipped to this
    min_run: int = 5                # learn only inside a run of at least this many quality-ok matches
    min_template_px: int = 120      # ... and from templates at least this big (near the ground, e.g. in
                                    # the climb, small templates hold false-lock runs)
    # While no sector near the heading has an estimate, a frame the tracker would search in a window
    # is first matched there at these extra heading offsets too; the best quality-ok peak picks the
    # heading the frame is aligned with (a rotation search: the first measurement needs a lock).
    seed_offsets_deg: tuple[float, ...] = (-8.0, -4.0, 4.0, 8.0)
    learn_every_n: int = 3          # measure on every n-th frame that qualifies (a measurement costs
                                    # about 2 ms CPU: two re-alignments and three small correlations) ...
    warmup_measurements: int = 10   # ... once the heading's sector has this many; on every one before
    # The 1-sigma published with each measured heading (VisionFix.heading_std_rad): the scatter of
    # the measurements against the true heading on `realistic` flights (docs/realism.md).
    measurement_std_deg: float = 1.0

    def __post_init__(self) -> None:
        check(0.5 <= self.probe_deg <= 15.0, "heading_offset.probe_deg", self.probe_deg, "0.5 .. 15 degrees")
        check(5.0 <= self.sector_deg <= 180.0 and (360.0 / self.sector_deg).is_integer(),
              "heading_offset.sector_deg", self.sector_deg, "5 .. 180 degrees, dividing 360")
        check(0.0 < self.gain <= 1.0, "heading_offset.gain", self.gain, "a number in (0, 1]")
        check(1 <= self.window_radius_px <= 32, "heading_offset.window_radius_px", self.window_radius_px,
              "1 .. 32 px")
        check(0.0 < self.max_offset_deg <= 45.0, "heading_offset.max_offset_deg", self.max_offset_deg,
              "0 .. 45 degrees")
        check(self.min_run >= 1, "heading_offset.min_run", self.min_run, "an integer >= 1")
        check(all(abs(o) <= self.max_offset_deg for o in self.seed_offsets_deg),
              "heading_offset.seed_offsets_deg", self.seed_offsets_deg, "offsets within max_offset_deg")
        check(self.warmup_measurements >= 0, "heading_offset.warmup_measurements",
              self.warmup_measurements, "an integer >= 0")
        check(self.learn_every_n >= 1, "heading_offset.learn_every_n", self.learn_every_n,
              "an integer >= 1")
        check(0.1 <= self.measurement_std_deg <= 30.0, "heading_offset.measurement_std_deg",
              self.measurement_std_deg, "0.1 .. 30 degrees")
        check(self.min_template_px >= 16, "heading_offset.min_template_px", self.min_template_px,
              "an integer >= 16")


def parabola_vertex(minus: float, centre: float, plus: float, step: float) -> float | None:
    """Abscissa of the vertex of the parabola through (-step, minus), (0, centre), (step, plus),
    clipped to [-step, step]; None when the three points do not bend down (no maximum)."""
    curvature = minus - 2.0 * centre + plus
    if not math.isfinite(curvature) or curvature >= 0.0:
        if plus > centre and plus > minus:
            return step
        if minus > centre and minus > plus:
            return -step
        return None
    return float(min(step, max(-step, 0.5 * step * (minus - plus) / curvature)))


def rotation_peaks(reference: np.ndarray, templates: list[np.ndarray],
                   centres_uv: list[tuple[float, float]], radius_px: int) -> list[float]:
    """The zero-mean NCC peak of each template over the reference within ``radius_px`` of placing
    the template's centre at its ``centres_uv`` entry (continuous map pixels). The templates are
    cropped to their common centred square first, so the peaks compare like with like. NaN where
    the window leaves the map."""
    side = min(min(t.shape) for t in templates)
    h, w = reference.shape
    n = side + 2 * radius_px
    out = []
    for t, (cu, cv) in zip(templates, centres_uv, strict=True):
        u0 = int(math.floor(cu - 0.5 * side)) - radius_px
        v0 = int(math.floor(cv - 0.5 * side)) - radius_px
        if u0 < 0 or v0 < 0 or u0 + n > w or v0 + n > h:
            out.append(math.nan)
            continue
        r0, c0 = (t.shape[0] - side) // 2, (t.shape[1] - side) // 2
        crop = np.ascontiguousarray(t[r0:r0 + side, c0:c0 + side])
        out.append(float(cv2.matchTemplate(reference[v0:v0 + n, u0:u0 + n], crop, cv2.TM_CCOEFF_NORMED).max()))
    return out


class HeadingDeviation:
    """The learned compass error per heading sector (module docstring)."""

    def __init__(self, cfg: HeadingOffsetConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else HeadingOffsetConfig()
        self.n_sectors = int(round(360.0 / self.cfg.sector_deg))
        self.offset_rad = np.zeros(self.n_sectors)
        self.count = np.zeros(self.n_sectors, dtype=int)
        self.measurements = 0
        self._qualified = 0

    def reset(self) -> None:
        self.offset_rad[:] = 0.0
        self.count[:] = 0
        self.measurements = 0
        self._qualified = 0

    def due(self, compass_heading_rad: float) -> bool:
        """Count a frame that qualifies for a measurement; True on every ``learn_every_n``-th, and on
        every one while the heading's sector has fewer than ``warmup_measurements``."""
        self._qualified += 1
        if self.count[self._sector(compass_heading_rad)] < self.cfg.warmup_measurements:
            return True
        return (self._qualified - 1) % self.cfg.learn_every_n == 0

    def _sector(self, heading_rad: float) -> int:
        return int(wrap_2pi(heading_rad) / math.radians(self.cfg.sector_deg)) % self.n_sectors

    def _weights(self, compass_heading_rad: float) -> np.ndarray:
        """Triangular weights (1 at a sector's centre, 0 one sector width away) of the sectors that
        have an estimate; all zero when none near the heading has one."""
        width = math.radians(self.cfg.sector_deg)
        centres = (np.arange(self.n_sectors) + 0.5) * width
        d = np.abs((centres - compass_heading_rad + math.pi) % (2.0 * math.pi) - math.pi)
        return np.where(self.count > 0, np.clip(1.0 - d / width, 0.0, None), 0.0)

    def known(self, compass_heading_rad: float) -> bool:
        """A sector next to this heading has an estimate."""
        return bool(self._weights(compass_heading_rad).sum() > 0.0)

    def correction_rad(self, compass_heading_rad: float) -> float:
        """What to add to the compass heading: the weighted mean of the estimates of the sectors
        next to it that have one (a sector without an estimate does not pull it towards 0); 0 when
        neither has one."""
        w = self._weights(compass_heading_rad)
        total = float(w.sum())
        return float(w @ self.offset_rad) / total if total > 0.0 else 0.0

    def update(self, compass_heading_rad: float, offset_rad: float) -> None:
        """One measured heading error (the total: the correction used plus the parabola's vertex)
        at this compass heading."""
        k = self._sector(compass_heading_rad)
        gain = max(self.cfg.gain, 1.0 / (self.count[k] + 1))
        limit = math.radians(self.cfg.max_offset_deg)
        value = self.offset_rad[k] + gain * wrap_pi(offset_rad - self.offset_rad[k])
        self.offset_rad[k] = min(limit, max(-limit, value))
        self.count[k] += 1
        self.measurements += 1
