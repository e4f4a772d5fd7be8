"""worlds.raycast: first hits of rays on a height field, checked against hand geometry and brute force."""

import subprocess
import sys

import numpy as np
import pytest

from worlds.raycast import FACE_LIGHT, HeightField, Surface, WallFace, first_hits, shade

M = 0.5   # m per map pixel


def _box_field():
    """100 x 100 px map (50 m), one 20 x 12 m box 25 m high: columns 40..79, rows 30..53."""
    h = np.zeros((100, 100), np.float32)
    h[30:54, 40:80] = 25.0
    return HeightField(h, M), h


def test_vertical_rays_hit_roof_or_ground():
    field, h = _box_field()
    # Map pixel (c, r) centre -> ENU: x = (c + 0.5 - 50) * M, y = (50 - r - 0.5) * M.
    o = np.array([[(60.5 - 50) * M, (50 - 40.5) * M, 100.0], [(10.5 - 50) * M, (50 - 10.5) * M, 100.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -2.0]])
    hits = first_hits(field, o, d)
    assert list(hits.surface) == [Surface.TOP, Surface.GROUND]
    np.testing.assert_allclose(hits.height_m, [25.0, 0.0])
    np.testing.assert_allclose(hits.u_px, [60.5, 10.5])
    np.testing.assert_allclose(hits.v_px, [40.5, 10.5])
    np.testing.assert_allclose(hits.range_s, [75.0, 50.0])
    assert list(hits.col_px) == [60, 10] and list(hits.row_px) == [40, 10]


@pytest.mark.parametrize("direction, face, u_wall", [((1.0, 0.0), WallFace.WEST, 40.0),
                                                     ((-1.0, 0.0), WallFace.EAST, 80.0)])
def test_oblique_ray_hits_the_facing_wall(direction, face, u_wall):
    field, _ = _box_field()
    # From 15 m high, 10 m before the wall, descending 1 m per 2 m toward it: hits the wall at 10 m.
    x_wall = (u_wall - 50) * M
    x0 = x_wall - direction[0] * 10.0
    o = np.array([[x0, (50 - 42.5) * M, 15.0]])
    d = np.array([[direction[0], 0.0, -0.5]])
    hits = first_hits(field, o, d)
    assert hits.surface[0] == Surface.WALL and hits.wall_face[0] == face
    np.testing.assert_allclose(hits.u_px[0], u_wall)
    np.testing.assert_allclose(hits.height_m[0], 10.0)
    assert hits.row_px[0] == 42


def test_street_behind_the_box_is_occluded_and_upward_rays_miss():
    field, _ = _box_field()
    # A ray that would reach the ground east of the box passes through it: it hits the box first.
    o = np.array([[(30 - 50) * M, 0.0, 40.0], [0.0, 0.0, 40.0], [0.0, 0.0, 40.0]])
    d = np.array([[1.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    hits = first_hits(field, o, d)
    assert hits.surface[0] == Surface.TOP          # lands on the roof (z 25 at x + 15 m)
    np.testing.assert_allclose(hits.u_px[0], 30 + 15 / M)
    assert hits.miss.tolist() == [False, True, True]
    assert np.isnan(hits.u_px[1])


def test_north_and_south_faces():
    field, _ = _box_field()
    # Going south (v increases) hits the north face at v = 30; going north hits the south face at v = 54.
    o = np.array([[(60.5 - 50) * M, (50 - 20) * M, 20.0], [(60.5 - 50) * M, (50 - 64) * M, 20.0]])
    d = np.array([[0.0, -1.0, -0.2], [0.0, 1.0, -0.2]])
    hits = first_hits(field, o, d)
    assert list(hits.wall_face) == [WallFace.NORTH, WallFace.SOUTH]
    np.testing.assert_allclose(hits.v_px, [30.0, 54.0])
    np.testing.assert_allclose(hits.height_m, [20.0 - 0.2 * 5.0, 20.0 - 0.2 * 5.0])


def test_matches_brute_force_marching_on_a_random_city():
    rng = np.random.default_rng(3)
    rows, cols = 120, 150
    h = np.zeros((rows, cols), np.float32)
    for _ in range(40):
        r, c = rng.integers(0, rows - 5), rng.integers(0, cols - 5)
        h[r:r + rng.integers(2, 25), c:c + rng.integers(2, 25)] = rng.uniform(6, 40)
    field = HeightField(h, M)
    n = 300
    o = np.column_stack([rng.uniform(-45, 45, n), rng.uniform(-35, 35, n), rng.uniform(45, 100, n)])
    d = np.column_stack([rng.normal(0, 0.6, n), rng.normal(0, 0.6, n), -np.ones(n)])
    hits = first_hits(field, o, d)
    steps = 40000
    for i in range(n):
        s = np.linspace(0.0, o[i, 2] / -d[i, 2], steps)
        p = o[i] + s[:, None] * d[i]
        c = np.floor(p[:, 0] / M + cols / 2).astype(int)
        r = np.floor(rows / 2 - p[:, 1] / M).astype(int)
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        hh = np.zeros(steps)
        hh[inside] = h[r[inside], c[inside]]
        k = int(np.argmax(p[:, 2] <= hh))
        assert abs(s[k] - hits.range_s[i]) <= 2 * s[1], i


# A ray that came down to a coarse cell's maximum exactly on a pixel edge (u = 764 - 187.5 * 0.944 =
# 587, rounded just above, going west) stepped back to that edge's crossing, an ulp earlier, and
# looped forever between the two levels: `scenenav world import` hung on an imported DSM in whole
# centimetres (found by a black-box test, 2026-12-06). Run in a child: a numba loop cannot be
# interrupted, and a regression must fail the test, not hang the suite.
_EDGE_RAY = """
import numpy as np
from worlds.raycast import HeightField, first_hits
dsm = np.zeros((1528, 1528), np.float32)
dsm[1137, 586] = 28.0
dsm[0, 0] = 50.25            # sets the height the walk starts at
field = HeightField(dsm, 0.3)
x, y = (576.5 - 764) * 0.3, (764 - 1158.5) * 0.3
print(first_hits(field, np.array([[0.0, 0.0, 500.0]]), np.array([[x, y, -500.0]])).height_m[0])
"""


def test_a_ray_meeting_a_cell_maximum_on_a_pixel_edge_ends():
    out = subprocess.run([sys.executable, "-c", _EDGE_RAY], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert 27.0 < float(out.stdout) < 28.0     # the 28 m pixel's wall, 0.75 m below its top


def test_shade_walls_windows_and_ground():
    field, h = _box_field()
    top = np.zeros((100, 100, 3), np.uint8)
    top[:] = (10, 20, 30)
    top[30:54, 40:80] = (200, 100, 50)
    facade = np.zeros_like(top)
    facade[30:54, 40:80] = (100, 100, 100)
    x_wall = (40 - 50) * M
    o = np.array([[0.0, 0.0, 100.0], [x_wall - 10.0, 0.0, 15.0], [x_wall - 10.0, 0.0, 100.0], [0, 0, 5.0]])
    d = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, -0.5], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    hits = first_hits(field, o, d)
    rgb = shade(hits, top, facade, m_per_px=M, outside_grey_level=77)
    assert tuple(rgb[0]) == (200, 100, 50)            # roof
    assert tuple(rgb[2]) == (10, 20, 30)              # street
    assert tuple(rgb[3]) == (77, 77, 77)              # miss
    light = FACE_LIGHT[WallFace.WEST]
    assert rgb[1, 0] in (int(100 * light + 0.5), int(100 * light * 0.45 + 0.5))
    # Without facade colours the wall is the darkened roof colour.
    rgb2 = shade(hits, top, None, m_per_px=M)
    assert rgb2[1, 0] < 200 and rgb2[1, 0] != rgb[1, 0]
