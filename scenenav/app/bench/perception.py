"""``scenenav bench perception``: per-fix time by stage and method, beside raw cv2.matchTemplate.

Captures are rendered by the simulator's camera (``sitl.camera``, with the world's DSM) along a straight 10 m/s
path at 100 m over the default world (10 Hz). Every method processes the same frames; the raw
baseline runs ``cv2.matchTemplate`` (TM_CCOEFF_NORMED) of the same aligned template on the same
window the tracker searched, in the same run. One thread for OpenCV and torch ("one core").
Both are timed twice: wall clock (the fix's own stage timings, perf_counter around the raw call)
and the CPU time of this thread (thread_time around ``process`` and around the raw call), which
other jobs on a shared machine inflate far less. Also: a whole assistant map at stride 5 px, and
per-fix time while tracking as the map grows.
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


def _raw_match_ms(pipe) -> tuple[float, float]:
    """Wall and thread-CPU milliseconds of one cv2.matchTemplate of the fix's template on its window."""
    m, a = pipe.last_match, pipe.last_aligned
    u0, v0, w, h = m.window_px
    window = pipe.matcher.reference[v0:v0 + h, u0:u0 + w] if hasattr(pipe.matcher, "reference") else None
    if window is None:
        raise RuntimeError("matcher has no reference array")
    c0, t0 = time.thread_time(), time.perf_counter()
    cv2.matchTemplate(window, a.template, cv2.TM_CCOEFF_NORMED)
    return (time.perf_counter() - t0) * 1000.0, (time.thread_time() - c0) * 1000.0


def _run_method(world, frames, method: str, classifier, amap) -> dict:
    from perception.config import PerceptionConfig
    from perception.decision import FalseMatchMethod
    from perception.pipeline import PerceptionPipeline
    m = FalseMatchMethod(method)
    pipe = PerceptionPipeline(world.reference, world.m_per_px, m, PerceptionConfig(),
                              classify=classifier.predict_proba if classifier is not None and m in (
                                  FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP) else None,
                              assistant_map=amap)
    stages = {k: [] for k in ("align", "ncc", "cnn", "lookup", "total")}
    raw, raw_cpu, cpu = [], [], []
    for t, img, heading in frames:
        c0 = time.thread_time()
        r = pipe.process(img, heading, 100.0, t)
        c1 = time.thread_time()
        if not r.valid:
            continue
        for k in stages:
            stages[k].append(getattr(r.timings, f"{k}_ms"))
        cpu.append((c1 - c0) * 1000.0)
        wall_ms, cpu_ms = _raw_match_ms(pipe)
        raw.append(wall_ms)
        raw_cpu.append(cpu_ms)
    med = {k: round(statistics.median(v), 3) if v else None for k, v in stages.items()}

    def median(v: list[float]) -> float | None:
        return round(statistics.median(v), 3) if v else None
    return {"method": method, "fixes": len(stages["total"]), "fix_time_ms_median": med["total"],
            "stages_ms_median": med, "match_template_ms_median": median(raw),
            "fix_cpu_ms_median": median(cpu), "match_template_cpu_ms_median": median(raw_cpu)}


def run_perception_bench(n_frames: int = 60, sizes_px: tuple[int, ...] = (1000, 4000, 8000),
                         stride_px: int = 5) -> dict:
    import torch

    from perception.assistant_map import AssistantMap, build_assistant_map
    from perception.cnn import MatchClassifier
    from worlds.default import load_default_world
    if n_frames < 5:
        raise UserError(f"--frames {n_frames}: expected at least 5")
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
        rows.append(_run_method(world, frames, method, clf if method in ("cnn", "assistant-map") else None, amap))
    # flatness with map size: tile the reference to bigger maps, track the same frames
    scaling = []
    for side in sizes_px:
        big_ref = _grown_reference(world.reference, side)
        from types import SimpleNamespace
        big = SimpleNamespace(reference=big_ref, m_per_px=world.m_per_px, width_px=side, height_px=side)
        # place the path at the same place relative to the first tile: shift frames' truth is irrelevant,
        # the tracker acquires globally once and then tracks.
        r = _run_method(big, frames, "none", None, None)
        scaling.append({"map_px": f"{side}x{side}", "fix_time_ms_median": r["fix_time_ms_median"],
                        "ncc_ms_median": r["stages_ms_median"]["ncc"], "fix_cpu_ms_median": r["fix_cpu_ms_median"]})
    paper = {"cnn": 140.0, "assistant-map": 41.0, "statistical": 41.0, "none": 40.0}
    return {"methods": {r["method"]: r for r in rows}, "assistant_map_build_s": round(build_s, 2),
            "assistant_map_stride_px": stride_px, "scaling": scaling,
            "paper_ms": paper, "world_px": f"{world.width_px}x{world.height_px}"}


def _ms(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def format_table(result: dict) -> str:
    """The figures of ``run_perception_bench`` as a table (text, newline-terminated)."""
    rows = list(result["methods"].values())
    paper = result["paper_ms"]
    lines = [f"perception per-fix time, one core, default world {result['world_px']}, "
             f"{rows[0]['fixes']} fixes (median ms: wall clock, then this thread's CPU time)",
             f"{'method':>14} {'align':>7} {'ncc':>7} {'cnn':>7} {'lookup':>7} {'total':>7} "
             f"{'raw mT':>7} {'x raw':>6} {'cpu':>7} {'raw cpu':>7} {'x raw':>6} {'paper':>6}"]
    for r in rows:
        s = r["stages_ms_median"]
        raw = r["match_template_ms_median"]
        ratio = r["fix_time_ms_median"] / raw if raw and r["fix_time_ms_median"] is not None else None
        cpu, raw_cpu = r.get("fix_cpu_ms_median"), r.get("match_template_cpu_ms_median")
        cpu_ratio = cpu / raw_cpu if cpu is not None and raw_cpu else None
        lines.append(f"{r['method']:>14} {_ms(s['align']):>7} {_ms(s['ncc']):>7} {_ms(s['cnn']):>7} "
                     f"{_ms(s['lookup'], 3):>7} {_ms(s['total']):>7} {_ms(raw):>7} {_ms(ratio):>6} "
                     f"{_ms(cpu):>7} {_ms(raw_cpu):>7} {_ms(cpu_ratio):>6} {paper[r['method']]:>6.0f}")
    lines.append(f"whole assistant map {result['world_px']} px at stride {result['assistant_map_stride_px']} px: "
                 f"{result['assistant_map_build_s']:.1f} s (target <= 60 s)")
    lines.append("tracking per-fix time vs map size (wall / cpu): " + ", ".join(
        f"{s['map_px']} {_ms(s['fix_time_ms_median'])} / {_ms(s.get('fix_cpu_ms_median'))} ms"
        for s in result["scaling"]))
    lines.append("targets: assistant-map <= 1.5x raw matchTemplate; online CNN <= 20 ms; flat with map size")
    return "\n".join(lines) + "\n"
