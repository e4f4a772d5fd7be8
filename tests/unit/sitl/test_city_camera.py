"""The 3-D city camera (worlds.view_renderer via sitl.camera) against geometry and the TinyRenderer reference.

* flat world: byte-identical to the TinyRenderer mesh camera (sitl.mesh_camera.MeshCamera) over a grid
  of poses (gimbal and fixed mounts, tilts, levels of detail > 1, re-centred windows, the map edge,
  outside-map grey, the grey frame and the sky seen by a tilted camera); heights all zero and
  ``relief: false`` give that same image;
* one box (20 x 12 m, 25 m high): its roof lands exactly where pinhole geometry puts it, nadir,
  off-nadir and through a tilted FIXED mount; the facade facing the camera shows, leaning away from
  nadir; the street behind it is occluded;
* agreement with the mesh camera drawing the DSM as boxes in label colours: >= 99 % of pixels have
  the reference's label at the same pixel or one of its 8 neighbours, on the box and on a city patch.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scenenav.core.rotations import quat_from_euler_zyx
from sitl.camera import GroundCamera, camera_axes
from sitl.config import CameraConfig, CameraMount
from sitl.mesh_camera import MeshCamera, agreement_share, height_runs, hit_labels, run_index_map
from worlds.raycast import Surface, WallFace
from worlds.synthetic_relief import synthetic_dsm

M = 0.5
SIDE = 200                       # map pixels (100 m)
W = H = 200                      # image pixels
TAN = math.tan(math.radians(30.0))
# The box: columns 80..119, rows 76..99 -> x in [-10, 10] m, y in [0, 12] m; 25 m high.
BOX = (80, 120, 76, 100)
BOX_H = 25.0


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    rng = np.random.default_rng(7)
    return rng.integers(0, 256, (260, 300, 3), dtype=np.uint8)


def _quat(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Body -> ENU quaternion; ``yaw`` counter-clockwise from east (pi/2: nose north, image up north)."""
    return np.asarray(quat_from_euler_zyx(yaw, pitch, roll), dtype=float)


def _flat_poses():
    rng = np.random.default_rng(11)
    poses = [((0.0, 0.0, 100.0), _quat(0.0)), ((70.0, -60.0, 40.0), _quat(1.1)),      # near the map edge
             ((0.0, 0.0, 400.0), _quat(0.4)), ((250.0, 0.0, 60.0), _quat(2.0)),       # L > 1; outside the map
             ((5.0, 3.0, 0.1), _quat(0.2))]                                           # below the lowest height
    for _ in range(10):
        pos = (float(rng.uniform(-90, 90)), float(rng.uniform(-80, 80)), float(rng.choice([2.0, 30.0, 120.0, 700.0])))
        poses.append((pos, _quat(float(rng.uniform(0, 2 * math.pi)), float(rng.choice([0.0, 0.3, 1.2, -0.7])),
                                 float(rng.choice([0.0, 0.2, 1.3])))))
    return poses


@pytest.mark.parametrize("mount", [CameraMount.GIMBAL, CameraMount.FIXED])
def test_flat_world_is_exactly_the_tinyrenderer_image(texture, mount):
    cfg = CameraConfig(mount=mount, ground_window_px=256)
    zeros = np.zeros(texture.shape[:2], np.float32)
    seen_lods, seen_sky, seen_frame = set(), False, False
    with MeshCamera(texture, M, cfg) as reference, GroundCamera(-1, texture, M, cfg) as flat, \
            GroundCamera(-1, texture, M, cfg, heights_m=zeros) as zero_heights, \
            GroundCamera(-1, texture, M, CameraConfig(mount=mount, ground_window_px=256, relief=False),
                         heights_m=zeros + 12.0) as relief_off:
        for pos, q in _flat_poses():
            want = reference.render(np.array(pos), q)
            for cam in (flat, zero_heights, relief_off):
                got = cam.render(np.array(pos), q)
                same = np.all(got == want, axis=2)
                assert same.all(), (pos, q, float(same.mean()))
            assert flat.window == reference.window
            seen_lods.add(flat.window.lod)
            seen_sky |= bool(np.all(want == 255, axis=2).any())
            seen_frame |= bool(np.all(want == cfg.outside_grey_level, axis=2).any())
        assert flat.window_builds >= 3
    assert max(seen_lods) > 1 and seen_frame
    if mount is CameraMount.FIXED:
        assert seen_sky


def _box_world():
    heights = np.zeros((SIDE, SIDE), np.float32)
    c0, c1, r0, r1 = BOX
    heights[r0:r1, c0:c1] = BOX_H
    top = np.zeros((SIDE, SIDE, 3), np.uint8)
    checker = (np.add.outer(np.arange(SIDE) // 4, np.arange(SIDE) // 4) % 2).astype(bool)
    top[checker] = (0, 40, 0)
    top[~checker] = (0, 0, 40)
    return heights, top


def _project(eye, right, up, back, point):
    """Continuous image coordinates (col, row) of a world point through the pinhole."""
    d = np.asarray(point, float) - np.asarray(eye, float)
    xc, yc, zc = d @ np.asarray(right), d @ np.asarray(up), d @ np.asarray(back)
    return W / 2 * (1 + xc / (-zc) / TAN), H / 2 * (1 - yc / (-zc) / TAN)


def _inside_polygon(cols, rows, poly):
    """Pixel centres inside a convex polygon (image coordinates), and their distance margin to its edges."""
    cx, cy = cols + 0.5, rows + 0.5
    margin = np.full(cx.shape, np.inf)
    sign = None
    for (ax, ay), (bx, by) in zip(poly, poly[1:] + poly[:1], strict=True):
        cross = ((bx - ax) * (cy - ay) - (by - ay) * (cx - ax)) / math.hypot(bx - ax, by - ay)
        if sign is None:
            sign = np.sign(np.median(cross)) or 1.0
        margin = np.minimum(margin, cross * sign)
    return margin


POSES = {
    "nadir": ((0.0, 6.0, 100.0), _quat(math.pi / 2), CameraMount.GIMBAL),
    "off-nadir": ((-30.0, 6.0, 100.0), _quat(math.pi / 2), CameraMount.GIMBAL),
    "fixed-tilted": ((-15.0, -10.0, 70.0), _quat(1.2, pitch=-0.4, roll=-0.3), CameraMount.FIXED),
}


@pytest.mark.parametrize("name", list(POSES))
def test_box_roof_lands_where_pinhole_geometry_puts_it(name):
    heights, top = _box_world()
    pos, q, mount = POSES[name]
    cfg = CameraConfig(mount=mount, ground_window_px=256)
    right, up, back = camera_axes(q, mount)
    with GroundCamera(-1, top, M, cfg, heights_m=heights) as cam:
        cam.render(np.array(pos), q)
        surface, face, col, row = cam.renderer.last_hits(W, H)
    c0, c1, r0, r1 = BOX
    corners = [((c - SIDE / 2) * M, (SIDE / 2 - r) * M, BOX_H) for c, r in ((c0, r0), (c1, r0), (c1, r1), (c0, r1))]
    poly = [_project(pos, right, up, back, p) for p in corners]
    rr, cc = np.mgrid[0:H, 0:W]
    margin = _inside_polygon(cc, rr, poly)
    roof = surface == Surface.TOP
    # Every pixel centre more than 0.01 px inside the projected roof outline is roof, and every pixel
    # centre more than 0.01 px outside it is not: the roof corners are where geometry says, to 1 px.
    assert roof[margin > 0.01].all()
    assert not roof[margin < -0.01].any()
    assert roof.sum() > 200
    # The roof pixel nearest to each projected corner is the pixel centre nearest to it inside the
    # outline: the corners are where geometry says, to well within 1 px.
    ys, xs = np.nonzero(roof)
    gys, gxs = np.nonzero(margin > 0.0)
    for corner_col, corner_row in poly:
        assert 0 < corner_col < W and 0 < corner_row < H
        near = np.hypot(xs + 0.5 - corner_col, ys + 0.5 - corner_row).min()
        assert near == pytest.approx(np.hypot(gxs + 0.5 - corner_col, gys + 0.5 - corner_row).min(), abs=1e-9)
        assert near <= 1.5


def test_off_nadir_box_shows_its_west_facade_and_hides_the_street_behind():
    heights, top = _box_world()
    pos, q, mount = POSES["off-nadir"]      # 30 m west of the map centre, level with the box's middle
    cfg = CameraConfig(ground_window_px=256)
    right, up, back = camera_axes(q, mount)
    with GroundCamera(-1, top, M, cfg, heights_m=heights) as cam:
        image = cam.render(np.array(pos), q)
        surface, face, col, row = (a.copy() for a in cam.renderer.last_hits(W, H))
    with GroundCamera(-1, top, M, CameraConfig(ground_window_px=256, relief=False), heights_m=heights) as flat:
        flat_image = flat.render(np.array(pos), q)
    walls = surface == Surface.WALL
    assert walls.sum() > 100
    assert set(np.unique(face[walls]).tolist()) == {WallFace.WEST}
    # The facade leans away from nadir: its pixels lie between the base edge (x = -10 m, z = 0) and the
    # roof edge (z = 25 m) as projected, i.e. the roof is displaced away from the image centre.
    base_col, _ = _project(pos, right, up, back, (-10.0, 6.0, 0.0))
    roof_col, _ = _project(pos, right, up, back, (-10.0, 6.0, BOX_H))
    assert roof_col > base_col > W / 2
    ys, xs = np.nonzero(walls)
    assert xs.min() + 0.5 >= base_col - 1.0 and xs.max() + 0.5 <= roof_col + 1.0
    # Walls are shaded (windows, light): not the roof texture.
    assert not np.array_equal(image[walls], flat_image[walls])
    # The street 2 m east of the box, seen through the box: occluded by the roof.
    sc, sr = _project(pos, right, up, back, (12.0, 6.0, 0.0))
    assert surface[int(sr), int(sc)] == Surface.TOP
    # Nothing else differs from the flat image outside the box's footprint on screen.
    changed = np.any(image != flat_image, axis=2)
    assert not changed[(surface == Surface.GROUND)].any()


def _agreement(heights, top, pose):
    pos, q, mount = pose
    cfg = CameraConfig(mount=mount, ground_window_px=256)
    runs, _ = height_runs(heights, 0, heights.shape[1], 0, heights.shape[0])
    index = run_index_map(heights.shape, runs)
    with MeshCamera(top, M, cfg, heights_m=heights, box_colours="labels") as reference, \
            GroundCamera(-1, top, M, cfg, heights_m=heights) as cam:
        want = reference.render(np.array(pos), q)
        got = cam.render(np.array(pos), q)
        labels = hit_labels(got, *cam.renderer.last_hits(W, H), index)
    return agreement_share(labels, want), float(np.all(labels == want, axis=2).mean())


@pytest.mark.parametrize("name", list(POSES))
def test_box_agrees_with_the_mesh_reference(name):
    heights, top = _box_world()
    within_1px, exact = _agreement(heights, top, POSES[name])
    assert within_1px >= 0.99 and exact >= 0.98


def test_city_patch_agrees_with_the_mesh_reference():
    dsm, _ = synthetic_dsm(SIDE, SIDE, M, seed=3)
    _, top = _box_world()
    for pose in (((3.0, -4.0, 100.0), _quat(0.7), CameraMount.GIMBAL),
                 ((-10.0, 15.0, 80.0), _quat(2.0, pitch=0.3, roll=0.25), CameraMount.FIXED)):
        within_1px, _ = _agreement(dsm, top, pose)
        assert within_1px >= 0.99, pose


def test_render_worker_draws_the_relief():
    from sitl.render_worker import CameraPipeline
    heights, top = _box_world()
    pos, q, _ = POSES["off-nadir"]
    cfg = CameraConfig(ground_window_px=256)
    with GroundCamera(-1, top, M, cfg, heights_m=heights) as cam:
        want = cam.render(np.array(pos), q)
    pipeline = CameraPipeline(top, M, cfg, heights_m=heights)      # forked worker (render_in_worker)
    try:
        pipeline.request(1, np.array(pos), q)
        got = pipeline.result(1)
    finally:
        pipeline.close()
    np.testing.assert_array_equal(got, want)
    with GroundCamera(-1, top, M, cfg) as flat:
        assert not np.array_equal(flat.render(np.array(pos), q), want)


@pytest.mark.parametrize("mount", [CameraMount.GIMBAL, CameraMount.FIXED])
def test_camera_hits_are_first_hits_of_the_pixel_rays(mount):
    """The camera's cast pass (image tiles bounding their rays' start height) finds exactly the hits
    ``worlds.raycast.first_hits`` finds for the same pixel-centre rays."""
    from worlds.raycast import HeightField, first_hits
    dsm, facade = synthetic_dsm(SIDE, SIDE, M, seed=4)
    _, top = _box_world()
    pos, q = (8.0, -6.0, 90.0), _quat(0.9, pitch=0.25, roll=-0.2)
    cfg = CameraConfig(mount=mount, ground_window_px=256)
    right, up, back = (np.array(a) for a in camera_axes(q, mount))
    with GroundCamera(-1, top, M, cfg, heights_m=dsm, facade_rgb=facade) as cam:
        cam.render(np.array(pos), q)
        surface, face, col, row = (a.copy() for a in cam.renderer.last_hits(W, H))
    rr, cc = np.mgrid[0:H, 0:W]
    a = ((2.0 * cc + 1.0) / W - 1.0) * TAN
    b = (1.0 - (2.0 * rr + 1.0) / H) * TAN
    d = -back + a.reshape(-1, 1) * right + b.reshape(-1, 1) * up
    hits = first_hits(HeightField(dsm, M), np.tile(pos, (W * H, 1)), d)
    assert (surface == Surface.WALL).any() and (surface == Surface.TOP).any()
    np.testing.assert_array_equal(surface.ravel(), hits.surface)
    np.testing.assert_array_equal(face.ravel(), hits.wall_face)
    np.testing.assert_array_equal(col.ravel(), hits.col_px)
    np.testing.assert_array_equal(row.ravel(), hits.row_px)
