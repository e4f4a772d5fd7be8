"""Visible-arm count of a junction crop (perception.dataset_arms) on hand-drawn road masks."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from perception.dataset_arms import ArmCountConfig, ArmVerdict, arm_check, visible_arms

MPP = 0.5
CROP = 100          # px: a 50 m crop
C = 100.5           # centre of the 200 px test map (continuous pixel coordinates)


def _map() -> np.ndarray:
    return np.zeros((200, 200), np.uint8)


def _road(m: np.ndarray, a: tuple[int, int], b: tuple[int, int], width_px: int = 14) -> None:
    cv2.line(m, a, b, 1, width_px)


def _arms(m: np.ndarray) -> int:
    return visible_arms(m, C, C, CROP, MPP)


def test_cross_tee_corner_counts():
    cross, tee, corner = _map(), _map(), _map()
    _road(cross, (0, 100), (199, 100))
    _road(cross, (100, 0), (100, 199))
    _road(tee, (0, 100), (199, 100))
    _road(tee, (100, 100), (100, 199))
    _road(corner, (100, 100), (199, 100))
    _road(corner, (100, 100), (100, 199))
    assert (_arms(cross), _arms(tee), _arms(corner)) == (4, 3, 2)


def test_wide_avenues_still_four_arms():
    m = _map()
    _road(m, (0, 100), (199, 100), 44)        # 22 m
    _road(m, (100, 0), (100, 199), 44)
    assert _arms(m) == 4


def test_stub_and_unconnected_road_do_not_count():
    m = _map()
    _road(m, (0, 100), (199, 100))
    _road(m, (100, 100), (100, 199))
    _road(m, (100, 100), (100, 80))            # a 10 m stub: ends inside the crop
    _road(m, (140, 0), (199, 60), 8)           # crosses the crop corner, never meets the junction
    assert _arms(m) == 3


def test_thin_path_below_min_width_does_not_count():
    m = _map()
    _road(m, (0, 100), (199, 100))
    _road(m, (100, 100), (100, 199))
    _road(m, (100, 100), (100, 0), 2)          # a 1 m wide path
    assert _arms(m) == 3
    assert visible_arms(m, C, C, CROP, MPP, ArmCountConfig(min_arm_width_m=0.5)) == 4


def test_verdicts():
    tee, paved = _map(), _map()
    _road(tee, (0, 100), (199, 100))
    _road(tee, (100, 100), (100, 199))
    square = _map()
    square[40:100, 40:160] = 1                 # a paved square on the tee's open side
    assert arm_check(3, tee, _map(), C, C, CROP, MPP) == (ArmVerdict.AGREE, 3)
    assert arm_check(4, tee, _map(), C, C, CROP, MPP) == (ArmVerdict.DISAGREE, 3)
    assert arm_check(3, tee, square, C, C, CROP, MPP)[0] is ArmVerdict.PAVED
    assert arm_check(3, _map(), _map(), C, C, CROP, MPP)[0] is ArmVerdict.UNREADABLE
    paved[:, :] = 1
    assert arm_check(4, paved, _map(), C, C, CROP, MPP)[0] is ArmVerdict.UNREADABLE


@pytest.mark.parametrize("arms", [2, 3, 4])
def test_rotation_invariant(arms: int):
    for deg in (0, 17, 45, 90):
        m = _map()
        for k in range(arms):
            a = np.radians(deg + 90 * k)
            _road(m, (100, 100), (int(100 + 140 * np.cos(a)), int(100 + 140 * np.sin(a))))
        assert _arms(m) == arms


def test_visible_arm_filter_drops_a_tee_labelled_four_and_counts_it():
    """--arms visible: a junction the graph calls four-armed but whose crop shows a tee is dropped."""
    from perception.capture import CaptureScene
    from perception.dataset_config import ArmLabels, CropGeometry, DatasetConfig
    from perception.dataset_samples import WorldData, select_base_samples
    from worlds.landcover import Junction, JunctionKind, LandCover
    lc = np.full((800, 800), int(LandCover.BUILDING_TEXTURED), np.uint8)
    road = np.zeros((800, 800), np.uint8)
    for cu in (200, 600):                               # two tees, 400 px apart
        _road_at(road, cu, 200)
    lc[road > 0] = int(LandCover.ROAD)
    junctions = (Junction(200.5, 200.5, 3, JunctionKind.TEE), Junction(600.5, 200.5, 4, JunctionKind.CROSS))
    gray = np.zeros((800, 800), np.float32)
    wd = WorldData(seed=1, scene=CaptureScene.flat(gray, gray, 0.53), junctions=junctions, landcover=lc)
    for arms, kept in ((ArmLabels.GRAPH, {3, 4}), (ArmLabels.VISIBLE, {3})):
        cfg = DatasetConfig(crop=CropGeometry.INTERSECTION, intersection_jitter_px=0.0, arms=arms,
                            base_crops=8, max_crops_per_junction=1)
        stats: dict = {}
        picked = select_base_samples([wd], cfg, cfg.crop_px(), np.random.default_rng(0), stats)
        junction_crops = [s for s in picked if s.arms > 0]
        assert {s.arms for s in junction_crops} == kept
        assert all(s.visible_arms == 3 for s in junction_crops)
        assert stats["candidates_by_graph_class"]["FOUR_ARM"] == {"disagree": 1}
        assert stats["candidates_by_graph_class"]["THREE_ARM"] == {"agree": 1}
        assert stats["agree_share"] == 0.5


def _road_at(m: np.ndarray, cu: int, cv: int) -> None:
    _road(m, (cu - 150, cv), (cu + 150, cv), 20)
    _road(m, (cu, cv), (cu, cv + 150), 20)


def test_flight_view_is_the_central_square_of_the_100_m_camera():
    import math

    from perception.dataset_config import CropGeometry, DatasetConfig, IntersectionView
    from scenenav.core.errors import UserError
    crop = DatasetConfig(crop=CropGeometry.INTERSECTION)
    flight = DatasetConfig(crop=CropGeometry.INTERSECTION, intersection_view=IntersectionView.FLIGHT)
    assert crop.crop_fov_deg() == 60.0 == DatasetConfig().crop_fov_deg()
    side_m = flight.crop_px() * flight.m_per_px
    altitude = side_m / (2.0 * math.tan(math.radians(flight.crop_fov_deg()) / 2.0))
    assert altitude == pytest.approx(100.0)
    from perception.dataset import build_dataset
    with pytest.raises(UserError, match="--crop intersection only"):
        build_dataset("/nonexistent-never-created", DatasetConfig(intersection_view=IntersectionView.FLIGHT))


def test_crops_of_one_junction_share_a_split_group():
    """Jittered repeats of a junction near a tile border stay in one group (no train/val leak)."""
    from perception.cnn_spec import MatchClass
    from perception.dataset_samples import BaseSample, CropSource, _pick_junctions, assign_ids
    j = BaseSample(world_seed=1, source=CropSource.JUNCTION, u_px=188.0, v_px=188.0,
                   label=MatchClass.THREE_ARM, arms=3)
    crops = _pick_junctions([j], 40, 40, 10.0, np.random.default_rng(0))
    assert len({(int(c.u_px // 94), int(c.v_px // 94)) for c in crops}) > 1    # the jitter crosses tiles
    assign_ids(crops, 94)
    assert {c.group for c in crops} == {"w1_t2_2"}
