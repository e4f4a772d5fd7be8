"""``scenenav bench render``: per-frame cost of the 3-D city camera and its agreement with the reference.

Cost: the simulator's camera (``sitl.camera.GroundCamera``, 200 x 200 px, 60 deg, gimbal, no effects;
and once more with every camera effect of ``sitl.camera_model`` on, plus sensor noise and JPEG) renders frames along a straight flight line at 100 m (10 m/s, 10 Hz, heading 80 deg so the image is
rotated), over the 3-D city and over the same world flat (``relief: false``), and over synthetic cities
of 900 x 1000, 2400 x 2400 and 8000 x 8000 px (the cost must not grow with the map). The figure is the
CPU time of the rendering thread per frame (``time.thread_time``: one core, numba single-threaded,
other processes' load excluded as far as the OS can), median and 90th percentile, after a warm-up
that loads the compiled kernels (numba's on-disk cache; compilation is never in the figures). The
machine's load average is printed beside them.

World: the default world when it has a DSM, otherwise its orthophoto with a synthetic city DSM
(``worlds.synthetic_relief``); the output says which.

Agreement: the camera against the independent TinyRenderer mesh renderer (``sitl.mesh_camera``)
drawing the same DSM as boxes in label colours, on a 20 x 12 x 25 m box and on a 120 x 120 m patch of
the bench world's city, from nadir, off-nadir and tilted FIXED-mount poses. A pixel agrees when the
reference has its label at that pixel or one of its 8 neighbours (``agreement_share``: the worst
scene). The flat-world identity (share of pixels byte-identical to TinyRenderer's image) is measured
too, over a grid of poses.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
import time
from typing import TextIO

import numpy as np

from scenenav.app.json_output import emit_json

log = logging.getLogger(__name__)

ALTITUDE_M = 100.0
SPEED_M_S = 10.0
RATE_HZ = 10.0
HEADING_DEG = 80.0
WARMUP_FRAMES = 5
DEFAULT_FRAMES = 150
MAP_SIZES = ((900, 1000), (2400, 2400), (8000, 8000))
PATCH_PX = 240
DEFAULT_IDENTITY_POSES = 40


def _quat_heading(heading_rad: float) -> np.ndarray:
    yaw = math.pi / 2 - heading_rad
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def bench_world():
    """(orthophoto, dsm_m, facade_rgb, m_per_px, description) of the bench world."""
    from worlds.default import load_default_world
    from worlds.synthetic_relief import synthetic_dsm
    world = load_default_world()
    if world.dsm_m is not None:
        return world.orthophoto, world.dsm_m, world.facade_rgb, world.m_per_px, "default world (its DSM)"
    dsm, facade = synthetic_dsm(world.height_px, world.width_px, world.m_per_px, seed=1)
    return (world.orthophoto, dsm, facade, world.m_per_px,
            "default world orthophoto with a synthetic city DSM (the default world has no DSM)")


def synthetic_city(width_px: int, height_px: int, m_per_px: float, seed: int = 0):
    """A random-texture map with a synthetic city DSM (content does not change the cost much)."""
    import cv2

    from worlds.synthetic_relief import synthetic_dsm
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, size=(max(8, height_px // 8), max(8, width_px // 8), 3), dtype=np.uint8)
    top = cv2.resize(small, (width_px, height_px), interpolation=cv2.INTER_LINEAR)
    dsm, facade = synthetic_dsm(height_px, width_px, m_per_px, seed=seed)
    return top, dsm, facade


def _line_poses(width_m: float, n: int):
    heading = math.radians(HEADING_DEG)
    q = _quat_heading(heading)
    half = max(0.0, width_m / 2 - 70.0)
    poses = []
    for i in range(n + WARMUP_FRAMES):
        x = -half + (i * SPEED_M_S / RATE_HZ) % max(1.0, 2 * half)
        poses.append((np.array([x, -20.0, ALTITUDE_M]), q))
    return poses


def frame_costs_ms(top, dsm, facade, m_per_px: float, n: int, relief: bool = True,
                   effects: bool = False) -> dict:
    """Median / p90 CPU and wall ms per frame of GroundCamera along the flight line. ``effects``: with
    every camera effect of ``sitl.camera_model`` on (``REALISTIC_CAMERA``, with a 20 ms exposure so the
    blur kernel is not skipped) and the JPEG round trip of ``SimulatorCore.camera_frame``; the sensor
    noise of ``sitl.sensors.CameraEffects`` is not in it)."""
    import dataclasses

    from sitl.camera import GroundCamera
    from sitl.camera_model import REALISTIC_CAMERA, jpeg_roundtrip
    from sitl.config import CameraConfig, CameraMount
    from sitl.sensors import CameraEffects
    cfg = CameraConfig(relief=relief)
    rng = None
    post = None
    if effects:
        keys = {**REALISTIC_CAMERA, "mount": CameraMount(REALISTIC_CAMERA["mount"]), "exposure_time_s": 0.02}
        cfg = dataclasses.replace(cfg, **keys)   # type: ignore[arg-type]
        rng = np.random.default_rng(0)
        post = CameraEffects(cfg, np.random.default_rng(1))
    cam = GroundCamera(-1, top, m_per_px, cfg, heights_m=dsm, facade_rgb=facade, optics_rng=rng)
    vel = np.array([SPEED_M_S * math.sin(math.radians(HEADING_DEG)),
                    SPEED_M_S * math.cos(math.radians(HEADING_DEG)), 0.0])
    cpu, wall = [], []
    for i, (pos, q) in enumerate(_line_poses(top.shape[1] * m_per_px, n)):
        t_cpu, t_wall = time.thread_time(), time.perf_counter()
        if post is None:
            cam.render(pos, q)
        else:
            image = post.apply(cam.render_capture(i / RATE_HZ, pos, q, vel, (0.0, 0.0, 0.0)))
            jpeg_roundtrip(image, cfg.jpeg_quality)
        if i >= WARMUP_FRAMES:
            cpu.append(time.thread_time() - t_cpu)
            wall.append(time.perf_counter() - t_wall)
    cam.close()
    c, w = np.array(cpu) * 1e3, np.array(wall) * 1e3
    return {"cpu_ms_median": round(float(np.median(c)), 3), "cpu_ms_p90": round(float(np.percentile(c, 90)), 3),
            "wall_ms_median": round(float(np.median(w)), 3), "frames": int(c.size)}


def _agreement_scenes(dsm_city: np.ndarray):
    """(name, heights, pose list) of the agreement scenes: the box and a city patch."""
    from scenenav.core.rotations import quat_from_euler_zyx
    from sitl.config import CameraMount
    box = np.zeros((200, 200), np.float32)
    box[76:100, 80:120] = 25.0
    r0 = max(0, dsm_city.shape[0] // 2 - PATCH_PX // 2)
    c0 = max(0, dsm_city.shape[1] // 2 - PATCH_PX // 2)
    patch = np.ascontiguousarray(dsm_city[r0:r0 + PATCH_PX, c0:c0 + PATCH_PX])

    def q(yaw, pitch=0.0, roll=0.0):
        return np.asarray(quat_from_euler_zyx(yaw, pitch, roll), dtype=float)
    poses = [((0.0, 6.0, 100.0), q(math.pi / 2), CameraMount.GIMBAL),
             ((-30.0, 6.0, 100.0), q(math.pi / 2), CameraMount.GIMBAL),
             ((-15.0, -10.0, 70.0), q(1.2, -0.4, -0.3), CameraMount.FIXED)]
    patch_poses = [((3.0, -4.0, 100.0), q(0.7), CameraMount.GIMBAL),
                   ((-25.0, 10.0, 100.0), q(2.0), CameraMount.GIMBAL),
                   ((-10.0, 15.0, 80.0), q(2.0, 0.3, 0.25), CameraMount.FIXED)]
    return [("box", box, poses), ("city patch", patch, patch_poses)]


def agreement(dsm_city: np.ndarray, m_per_px: float) -> dict:
    """Label agreement within 1 px with the mesh reference, per scene and pose."""
    from sitl.camera import GroundCamera
    from sitl.config import CameraConfig
    from sitl.mesh_camera import MeshCamera, agreement_share, height_runs, hit_labels, run_index_map
    rows = []
    for name, heights, poses in _agreement_scenes(dsm_city):
        side = heights.shape[0]
        top = np.zeros((side, side, 3), np.uint8)
        checker = (np.add.outer(np.arange(side) // 4, np.arange(heights.shape[1]) // 4) % 2).astype(bool)
        top[checker] = (0, 40, 0)
        top[~checker] = (0, 0, 40)
        runs, _ = height_runs(heights, 0, heights.shape[1], 0, side)
        index = run_index_map(heights.shape, runs)
        for pos, q, mount in poses:
            cfg = CameraConfig(mount=mount, ground_window_px=256)
            with MeshCamera(top, m_per_px, cfg, heights_m=heights, box_colours="labels") as ref, \
                    GroundCamera(-1, top, m_per_px, cfg, heights_m=heights) as cam:
                want = ref.render(np.array(pos), q)
                got = cam.render(np.array(pos), q)
                labels = hit_labels(got, *cam.renderer.last_hits(cfg.width_px, cfg.height_px), index)
            rows.append({"scene": name, "mount": mount.value, "position_enu_m": list(pos),
                         "within_1px_share": round(agreement_share(labels, want), 5),
                         "exact_share": round(float(np.all(labels == want, axis=2).mean()), 5)})
    return {"scenes": rows, "agreement_share": min(r["within_1px_share"] for r in rows)}


def flat_identity(top: np.ndarray, m_per_px: float, n_poses: int = 40, seed: int = 5) -> dict:
    """Share of pixels byte-identical to the TinyRenderer camera on the flat world, both mounts."""
    from scenenav.core.rotations import quat_from_euler_zyx
    from sitl.camera import GroundCamera
    from sitl.config import CameraConfig, CameraMount
    from sitl.mesh_camera import MeshCamera
    rng = np.random.default_rng(seed)
    same = total = 0
    worst = 1.0
    half_x, half_y = top.shape[1] * m_per_px / 2, top.shape[0] * m_per_px / 2
    for mount in (CameraMount.GIMBAL, CameraMount.FIXED):
        cfg = CameraConfig(mount=mount)
        with MeshCamera(top, m_per_px, cfg) as ref, GroundCamera(-1, top, m_per_px, cfg) as cam:
            for _ in range(max(1, n_poses // 2)):
                pos = np.array([rng.uniform(-half_x, half_x), rng.uniform(-half_y, half_y),
                                rng.choice([3.0, 30.0, 100.0, 300.0, 1000.0])])
                q = np.asarray(quat_from_euler_zyx(rng.uniform(0, 2 * math.pi), rng.choice([0.0, 0.3, -0.8]),
                                                   rng.choice([0.0, 0.2, 1.2])), dtype=float)
                eq = np.all(ref.render(pos, q) == cam.render(pos, q), axis=2)
                same += int(eq.sum())
                total += eq.size
                worst = min(worst, float(eq.mean()))
    return {"identical_share": same / total, "worst_frame_identical_share": worst, "poses": n_poses}


def run_render_bench(frames: int = DEFAULT_FRAMES, sizes=MAP_SIZES, identity_poses: int = DEFAULT_IDENTITY_POSES,
                     json_out: bool = False, out: TextIO | None = None) -> dict:
    """Run the benchmark; write a table (or the JSON) to ``out`` and return the results."""
    from tqdm import tqdm
    top, dsm, facade, m, world_desc = bench_world()
    steps = 4 + len(sizes) + 2
    bar = tqdm(total=steps, desc="bench render", file=sys.stderr, disable=json_out or not sys.stderr.isatty())
    # Warm-up: load (or compile once) every kernel before any timing.
    frame_costs_ms(top, dsm, facade, m, 3)
    bar.update(1)
    city = frame_costs_ms(top, dsm, facade, m, frames)
    bar.update(1)
    flat = frame_costs_ms(top, dsm, facade, m, frames, relief=False)
    bar.update(1)
    effects = frame_costs_ms(top, dsm, facade, m, frames, effects=True)
    by_size = []
    for w, h in sizes:
        t, d, f = synthetic_city(w, h, m)
        cost = frame_costs_ms(t, d, f, m, frames)
        by_size.append({"world_px": f"{w}x{h}", **cost})
        del t, d, f
        bar.update(1)
    agree = agreement(dsm, m)
    bar.update(1)
    ident = flat_identity(top, m, n_poses=max(2, identity_poses))
    bar.update(1)
    bar.close()
    report = {
        "bench": "render",
        "world": world_desc,
        "image_px": [200, 200],
        "altitude_m": ALTITUDE_M,
        "clock": "thread CPU time per frame (one core)",
        "load_average_1min": round(os.getloadavg()[0], 2),
        "render_ms_median": city["cpu_ms_median"],
        "render_ms_p90": city["cpu_ms_p90"],
        "city_100m": city,
        "flat_100m": flat,
        "city_100m_all_camera_effects": effects,
        "camera_effects_ms_per_frame": round(effects["cpu_ms_median"] - city["cpu_ms_median"], 3),
        "by_map_size": by_size,
        "agreement_share": agree["agreement_share"],
        "agreement": agree["scenes"],
        "flat_identical_share": ident["identical_share"],
        "flat_identity": ident,
        "target": {"render_ms_median_max": 3.0, "agreement_share_min": 0.99},
    }
    if json_out:
        emit_json(report, out)
    else:
        (out or sys.stdout).write(format_table(report))
    return report


def format_table(r: dict) -> str:
    """The figures of ``run_render_bench`` as text."""
    lines = [f"world: {r['world']}; 200x200 px, 60 deg, {r['altitude_m']:.0f} m, {r['clock']}; "
             f"load average {r['load_average_1min']}",
             f"{'case':>24} {'median ms':>10} {'p90 ms':>8} {'wall ms':>8}"]
    for name, c in (("3-D city", r["city_100m"]), ("flat (relief: false)", r["flat_100m"]),
                    ("3-D city, all effects", r["city_100m_all_camera_effects"])):
        lines.append(f"{name:>24} {c['cpu_ms_median']:>10.2f} {c['cpu_ms_p90']:>8.2f} {c['wall_ms_median']:>8.2f}")
    for s in r["by_map_size"]:
        lines.append(f"{'city ' + s['world_px']:>24} {s['cpu_ms_median']:>10.2f} {s['cpu_ms_p90']:>8.2f} "
                     f"{s['wall_ms_median']:>8.2f}")
    lines.append(f"camera effects (jitter, blur, lens, auto-exposure, JPEG): "
                 f"+{r['camera_effects_ms_per_frame']:.2f} ms per frame (median difference)")
    lines.append("agreement with the TinyRenderer mesh reference (label within 1 px):")
    for a in r["agreement"]:
        lines.append(f"  {a['scene']:>10} {a['mount']:>6} at {tuple(round(v, 1) for v in a['position_enu_m'])}: "
                     f"{a['within_1px_share']:.4f} (exact {a['exact_share']:.4f})")
    lines.append(f"agreement_share (worst scene) {r['agreement_share']:.4f}; flat world identical to TinyRenderer: "
                 f"{r['flat_identical_share']:.6f} of pixels over {r['flat_identity']['poses']} poses")
    lines.append("targets: median <= 3 ms per 200x200 frame on one core, flat in map size; agreement >= 0.99")
    return "\n".join(lines) + "\n"


def _size_list(text: str) -> tuple[tuple[int, int], ...]:
    """``900x1000,2400x2400`` -> ((900, 1000), (2400, 2400))."""
    sizes = []
    for part in text.split(","):
        try:
            w, h = (int(v) for v in part.strip().lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{part!r}: expected WIDTHxHEIGHT in pixels, e.g. 900x1000") from None
        if not (64 <= w <= 20000 and 64 <= h <= 20000):
            raise argparse.ArgumentTypeError(f"{part!r}: expected sides of 64 to 20000 pixels")
        sizes.append((w, h))
    return tuple(sizes)


def _cmd_bench_render(args: argparse.Namespace) -> int:
    run_render_bench(frames=args.frames, sizes=args.sizes, identity_poses=args.identity_poses, json_out=args.json)
    return 0


def register_bench(bench_subparsers) -> None:
    """Add ``render`` to the ``scenenav bench`` sub-commands."""
    from scenenav.app.arg_types import positive_int
    p = bench_subparsers.add_parser(
        "render", help="3-D city camera: per-frame cost vs map size, agreement with the mesh reference",
        description="Per-frame CPU cost (median, p90) of the simulator camera over the 3-D city at 100 m "
                    "along a flight line, flat, and on 900x1000 / 2400x2400 / 8000x8000 maps; label "
                    "agreement within 1 px with the independent TinyRenderer mesh renderer; share of "
                    "pixels identical to TinyRenderer on the flat world. See docs/rendering.md.")
    p.add_argument("--json", action="store_true", help="print only the results as JSON on stdout")
    p.add_argument("--frames", type=positive_int, default=DEFAULT_FRAMES,
                   help=f"timed frames per case (default {DEFAULT_FRAMES})")
    p.add_argument("--sizes", type=_size_list, default=MAP_SIZES, metavar="WxH,...",
                   help="synthetic city sizes for the cost vs map size, px (default "
                        + ",".join(f"{w}x{h}" for w, h in MAP_SIZES) + ")")
    p.add_argument("--identity-poses", type=positive_int, default=DEFAULT_IDENTITY_POSES, metavar="N",
                   help=f"poses of the flat-world identity check, half per mount (default {DEFAULT_IDENTITY_POSES})")
    p.set_defaults(func=_cmd_bench_render)
