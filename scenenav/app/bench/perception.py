"""``scenenav bench perception``: per-fix time by stage and method, beside raw cv2.matchTemplate.

Captures are rendered by the simulator's camera (``sitl.camera``, with the world's DSM) along a straight 10 m/s
path at 100 m over the default world (10 Hz). Every method processes the same frames; the raw
baseline runs ``cv2.matchTemplate`` (TM_CCOEFF_NORMED) of the same aligned template on the same
window the tracker searched, in the same run, interleaved with the fixes (before the fix on every
other frame, after it on the others: ``_run_method``), over several rounds of the whole path. One
thread for OpenCV and torch ("one core"). Both are timed twice: wall clock (the fix's own total,
perf_counter around the raw call) and the CPU time of this thread (thread_time around ``process``
and around the raw call), which other jobs on a shared machine inflate far less. The ratios
(``x_raw_wall``, ``x_raw_cpu``) compare the medians over the same fixes (window searches). Also: a
whole assistant map at stride 5 px, and per-fix time while tracking as the map grows.
"""

from __future__ import annotations

import logging
import math
import statistics
import time

import cv2
import numpy as np

from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

METHODS = ("none", "statistical", "assistant-map", "cnn")


def _captures(world, n: int, altitude_m: float = 100.0, speed_m_s: float = 10.0, rate_hz: float = 10.0):
    from sitl.camera import GroundCamera
    from sitl.config import CameraConfig
    cam = GroundCamera(-1, world.orthophoto, world.m_per_px, CameraConfig(), heights_m=world.dsm_m,
                       facade_rgb=world.facade_rgb)
    half_w = world.width_px * world.m_per_px / 2 - 70.0
    heading = math.radians(80.0)   # a slightly skewed track: the image is rotated
    yaw = math.pi / 2 - heading
    q = np.array([math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)])
    frames = []
    try:
        for i in range(n):
            x = -half_w + i * speed_m_s / rate_hz
            if x > half_w:
                break
            frames.append((i / rate_hz, cam.render(np.array([x, -20.0, altitude_m]), q), heading))
    finally:
        cam.close()
    return frames


def _grown_reference(ref: np.ndarray, side: int) -> np.ndarray:
    """A side x side map holding ``ref`` once, in its centre, surrounded by mirrored copies (so
    the original content, which the captures show, appears exactly once: no ambiguity is added)."""
    h, w = ref.shape[:2]
    variants = [np.flip(ref, 0), np.flip(ref, 1), np.flip(ref, (0, 1))]
    reps_y, reps_x = math.ceil(side / h) + 1, math.ceil(side / w) + 1
    rows = []
    for i in range(reps_y):
        rows.append(np.concatenate([variants[(i + j) % 3] for j in range(reps_x)], axis=1))
    big = np.concatenate(rows, axis=0)
    oy, ox = (big.shape[0] - h) // 2, (big.shape[1] - w) // 2
    big[oy:oy + h, ox:ox + w] = ref
    cy, cx = oy + h // 2, ox + w // 2
    return np.ascontiguousarray(big[cy - side // 2:cy - side // 2 + side, cx - side // 2:cx - side // 2 + side])


def _raw_match_ms(reference: np.ndarray, window_px: tuple[int, int, int, int],
                  template: np.ndarray) -> tuple[float, float]:
    """Wall and thread-CPU milliseconds of one cv2.matchTemplate (TM_CCOEFF_NORMED) of ``template``
    on the window ``window_px`` = (u0, v0, width, height) of ``reference`` (a view, as the matcher's)."""
    u0, v0, w, h = window_px
    window = reference[v0:v0 + h, u0:u0 + w]
    c0, t0 = time.thread_time(), time.perf_counter()
    cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    return (time.perf_counter() - t0) * 1000.0, (time.thread_time() - c0) * 1000.0


def _pipeline(world, method: str, classifier, amap, gradient_refine_px: int = 0):
    from perception.config import MatcherConfig, PerceptionConfig
    from perception.decision import FalseMatchMethod
    from perception.pipeline import PerceptionPipeline
    m = FalseMatchMethod(method)
    cfg = PerceptionConfig(matcher=MatcherConfig(gradient_refine_radius_px=gradient_refine_px))
    return PerceptionPipeline(world.reference, world.m_per_px, m, cfg,
                              classify=classifier.predict_proba if classifier is not None and m in (
                                  FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP) else None,
                              assistant_map=None if amap is None else amap.copy())


def _run_method(world, frames, method: str, classifier, amap, rounds: int = 3,
                gradient_refine_px: int = 0) -> dict:
    """Per-fix stage times and CPU of ``method`` beside the raw ``cv2.matchTemplate`` of each fix's
    own template on its own window, measured fairly: a first pass (untimed) records every fix's
    template and window (the pipeline is deterministic, so every round repeats them); then
    ``rounds`` passes, each with a fresh pipeline, time the fix and the raw call of every frame,
    the raw call before the fix on every other frame and after it on the others (alternating
    between rounds), so neither side always runs on the caches the other warmed. Same thread
    settings for both (the caller's). Medians over all rounds; global searches (the first frame,
    re-acquisitions) are excluded from the raw comparison, their fix times are in the stages."""
    record = []
    pipe = _pipeline(world, method, classifier, amap, gradient_refine_px)
    for t, img, heading in frames:
        r = pipe.process(img, heading, 100.0, t)
        window = r.valid and pipe.last_match is not None and pipe.last_match.search.value == "window"
        record.append((pipe.last_match.window_px, pipe.last_aligned.template.copy()) if window else None)
    stages = {k: [] for k in ("align", "ncc", "cnn", "lookup", "total")}
    raw, raw_cpu, cpu, wall = [], [], [], []
    split = {k: [] for k in ("crop", "correlate", "refine", "rest")}   # the window fixes' matcher stages
    for rnd in range(rounds):
        pipe = _pipeline(world, method, classifier, amap, gradient_refine_px)
        reference = pipe.matcher.reference          # the very map (and window memory) the fix reads
        for i, (t, img, heading) in enumerate(frames):
            rec = record[i]
            raw_first = rec is not None and (i + rnd) % 2 == 0
            if raw_first:       # the recorded template, read once first: as warm as a fresh alignment
                float(rec[1].sum())
                wall_ms, cpu_ms = _raw_match_ms(reference, rec[0], rec[1])
            c0 = time.thread_time()
            r = pipe.process(img, heading, 100.0, t)
            c1 = time.thread_time()
            if rec is not None and not raw_first:   # the fix's own template, as before
                wall_ms, cpu_ms = _raw_match_ms(reference, rec[0], pipe.last_aligned.template)
            if not r.valid:
                continue
            for k in stages:
                stages[k].append(getattr(r.timings, f"{k}_ms"))
            if rec is not None:
                if pipe.last_match.window_px != rec[0]:
                    raise RuntimeError(f"frame {i}: round {rnd} searched {pipe.last_match.window_px}, the "
                                       f"recording pass {rec[0]}: the pipeline is not deterministic")
                wall.append(r.timings.total_ms)
                cpu.append((c1 - c0) * 1000.0)
                mt = pipe.last_match.timings
                split["crop"].append(mt.crop_ms)
                split["correlate"].append(mt.ncc_ms)
                split["refine"].append(mt.refine_ms)
                split["rest"].append(r.timings.total_ms - r.timings.align_ms - mt.crop_ms - mt.ncc_ms
                                     - mt.refine_ms - r.timings.cnn_ms)
                raw.append(wall_ms)
                raw_cpu.append(cpu_ms)
    med = {k: round(statistics.median(v), 3) if v else None for k, v in stages.items()}

    def median(v: list[float]) -> float | None:
        return round(statistics.median(v), 3) if v else None
    fix_w, raw_w, fix_c, raw_c = median(wall), median(raw), median(cpu), median(raw_cpu)
    return {"method": method, "fixes": len(stages["total"]) // rounds, "rounds": rounds,
            "fix_time_ms_median": med["total"], "stages_ms_median": med,
            "window_fixes": len(wall) // rounds, "window_fix_ms_median": fix_w,
            "window_split_ms_median": {k: median(v) for k, v in split.items()},
            "match_template_ms_median": raw_w, "fix_cpu_ms_median": fix_c,
            "match_template_cpu_ms_median": raw_c,
            "x_raw_wall": round(fix_w / raw_w, 3) if fix_w and raw_w else None,
            "x_raw_cpu": round(fix_c / raw_c, 3) if fix_c and raw_c else None}


def run_perception_bench(n_frames: int = 60, sizes_px: tuple[int, ...] = (1000, 4000, 8000),
                         stride_px: int = 5, gradient_refine_px: int = 0) -> dict:
    """``gradient_refine_px``: ``MatcherConfig.gradient_refine_radius_px`` of every pipeline (0: off)."""
    from perception.config import MatcherConfig
    if n_frames < 5:
        raise UserError(f"--frames {n_frames}: expected at least 5")
    MatcherConfig(gradient_refine_radius_px=gradient_refine_px)   # a bad radius: one line, before any work
    import torch

    from perception.assistant_map import AssistantMap, build_assistant_map
    from perception.cnn import MatchClassifier
    from worlds.default import load_default_world
    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    world = load_default_world()
    frames = _captures(world, n_frames)
    clf = MatchClassifier.default(num_threads=1)
    gray = cv2.cvtColor(world.reference, cv2.COLOR_RGB2GRAY)
    t0 = time.perf_counter()
    built = build_assistant_map(gray, clf.predict_proba, world.m_per_px, stride_px=stride_px,
                                batch_size=256, cnn_input_px=clf.input_px,
                                world_name=world.manifest.name)
    build_s = time.perf_counter() - t0
    rows = []
    for method in METHODS:
        amap = None
        if method == "assistant-map":
            amap = built
        elif method == "cnn":
            amap = AssistantMap.empty(world.width_px, world.height_px, world.m_per_px,
                                      world_name=world.manifest.name)
        rows.append(_run_method(world, frames, method, clf if method in ("cnn", "assistant-map") else None, amap,
                                gradient_refine_px=gradient_refine_px))
    # flatness with map size: tile the reference to bigger maps, track the same frames
    scaling = []
    for side in sizes_px:
        big_ref = _grown_reference(world.reference, side)
        from types import SimpleNamespace
        big = SimpleNamespace(reference=big_ref, m_per_px=world.m_per_px, width_px=side, height_px=side)
        # place the path at the same place relative to the first tile: shift frames' truth is irrelevant,
        # the tracker acquires globally once and then tracks.
        r = _run_method(big, frames, "none", None, None, rounds=2, gradient_refine_px=gradient_refine_px)
        scaling.append({"map_px": f"{side}x{side}", "fix_time_ms_median": r["fix_time_ms_median"],
                        "ncc_ms_median": r["stages_ms_median"]["ncc"], "fix_cpu_ms_median": r["fix_cpu_ms_median"]})
    paper = {"cnn": 140.0, "assistant-map": 41.0, "statistical": 41.0, "none": 40.0}
    return {"methods": {r["method"]: r for r in rows}, "assistant_map_build_s": round(build_s, 2),
            "assistant_map_stride_px": stride_px, "scaling": scaling,
            "paper_ms": paper, "world_px": f"{world.width_px}x{world.height_px}",
            "gradient_refine_px": gradient_refine_px}


def _ms(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def format_table(result: dict) -> str:
    """The figures of ``run_perception_bench`` as a table (text, newline-terminated)."""
    rows = list(result["methods"].values())
    paper = result["paper_ms"]
    lines = [f"perception per-fix time, one core, default world {result['world_px']}, "
             f"{rows[0]['fixes']} fixes (median ms: wall clock, then this thread's CPU time), "
             f"gradient refinement {result.get('gradient_refine_px', 0)} px",
             f"{'method':>14} {'align':>7} {'ncc':>7} {'cnn':>7} {'lookup':>7} {'total':>7} "
             f"{'window':>7} {'raw mT':>7} {'x raw':>6} {'cpu':>7} {'raw cpu':>7} {'x raw':>6} {'paper':>6}"]
    for r in rows:
        s = r["stages_ms_median"]
        raw, ratio = r["match_template_ms_median"], r["x_raw_wall"]
        cpu, raw_cpu, cpu_ratio = r["fix_cpu_ms_median"], r["match_template_cpu_ms_median"], r["x_raw_cpu"]
        lines.append(f"{r['method']:>14} {_ms(s['align']):>7} {_ms(s['ncc']):>7} {_ms(s['cnn']):>7} "
                     f"{_ms(s['lookup'], 3):>7} {_ms(s['total']):>7} {_ms(r['window_fix_ms_median']):>7} "
                     f"{_ms(raw):>7} {_ms(ratio):>6} "
                     f"{_ms(cpu):>7} {_ms(raw_cpu):>7} {_ms(cpu_ratio):>6} {paper[r['method']]:>6.0f}")
    lines.append(f"whole assistant map {result['world_px']} px at stride {result['assistant_map_stride_px']} px: "
                 f"{result['assistant_map_build_s']:.1f} s (target <= 60 s)")
    lines.append("tracking per-fix time vs map size (wall / cpu): " + ", ".join(
        f"{s['map_px']} {_ms(s['fix_time_ms_median'])} / {_ms(s.get('fix_cpu_ms_median'))} ms"
        for s in result["scaling"]))
    lines.append("total: every valid fix; window: the window-search fixes the raw call is compared with "
                 f"(x raw), {rows[0]['rounds']} interleaved rounds")
    lines.append("window fixes' matcher stages (median ms: crop / correlate / refine / rest of the fix "
                 "without align and cnn): " + ", ".join(
                     f"{r['method']} " + " / ".join(_ms(r["window_split_ms_median"][k], 3)
                                                    for k in ("crop", "correlate", "refine", "rest"))
                     for r in rows))
    lines.append("targets: assistant-map <= 1.5x raw matchTemplate; online CNN <= 5 ms; flat with map size")
    return "\n".join(lines) + "\n"
