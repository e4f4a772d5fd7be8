"""The stride of a whole-world assistant map is a ground distance: each world gets it in its own
whole pixels (a finer world more pixels, the same metres), the default world keeps its pixel
strides and cache keys, and a bad stride is one line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.assistant_map import AssistantMap
from perception.map_cache import build_world_map, cache_key, cached_assistant_map
from perception.shipped import DEFAULT_WEIGHTS_PATH
from scenenav.core.errors import UserError
from scenenav.core.formats.assistant_map_file import BUILD_STRIDE_M
from worlds.generator import CityConfig, generate_world

SIDE_PX = 256                           # CityConfig's smallest world side
DEFAULT_M_PER_PX = CityConfig().m_per_px  # the default world's resolution (worlds/default.py)
FINE_M_PER_PX = 0.25


class _CountingClassifier:
    """Stands in for the shipped CNN: rates every crop P(bad) = 0.25 and counts the crops."""

    input_px = 16
    meta = None

    def __init__(self) -> None:
        self.rated = 0

    def predict_proba(self, batch: np.ndarray) -> np.ndarray:
        self.rated += len(batch)
        return np.full(len(batch), 0.25, dtype=np.float32)


@pytest.fixture(scope="module")
def worlds(tmp_path_factory):
    """Two 256 x 256 px generated cities: one at the default world's m/px, one finer."""
    folders = {}
    for m_per_px in (DEFAULT_M_PER_PX, FINE_M_PER_PX):
        folder = tmp_path_factory.mktemp("worlds") / f"city-{m_per_px}"
        generate_world(CityConfig(seed=5, width_px=SIDE_PX, height_px=SIDE_PX, m_per_px=m_per_px)).save(folder)
        folders[m_per_px] = folder
    return folders


@pytest.fixture
def cnn(monkeypatch, tmp_path) -> _CountingClassifier:
    """The builder's default classifier replaced by a counting stub; an empty map cache."""
    from perception.cnn import MatchClassifier
    clf = _CountingClassifier()
    monkeypatch.setattr(MatchClassifier, "default", classmethod(lambda cls, *a, **k: clf))
    monkeypatch.setenv("SCENENAV_CACHE_DIR", str(tmp_path / "cache"))
    return clf


def test_a_finer_world_gets_a_larger_pixel_stride_and_the_same_ground_spacing(worlds, cnn, tmp_path):
    built = {m_per_px: build_world_map(str(folder), str(tmp_path / f"{m_per_px}.npz"), stride_m=5.3,
                                       altitude_m=30.0, progress=False, png=False, relief=False)[0]
             for m_per_px, folder in worlds.items()}
    assert built[DEFAULT_M_PER_PX].stride_px == 10
    assert built[FINE_M_PER_PX].stride_px == 21                 # 5.3 / 0.25 = 21.2
    for m_per_px, amap in built.items():                        # 5.3 m to the nearest whole pixel
        assert abs(amap.stride_px * m_per_px - 5.3) <= m_per_px / 2
    # the same ground: the fine world (64 m square) rates about as many cells per square metre as
    # the default one (136 m square), not (0.53 / 0.25)^2 = 4.5x as many
    cells_per_m2 = {m: math.ceil(SIDE_PX / a.stride_px) ** 2 / (SIDE_PX * m) ** 2 for m, a in built.items()}
    assert cells_per_m2[FINE_M_PER_PX] / cells_per_m2[DEFAULT_M_PER_PX] < 1.5


def test_the_cached_map_of_a_finer_world_and_its_notice(worlds, cnn):
    said: list[str] = []
    path = cached_assistant_map(worlds[FINE_M_PER_PX], stride_m=5.3, relief=False, announce=said.append)
    assert AssistantMap.load(path).stride_px == 21
    key = cache_key(worlds[FINE_M_PER_PX], DEFAULT_WEIGHTS_PATH, 21, 100.0, 60.0, relief=False)
    assert path.name == f"{worlds[FINE_M_PER_PX].name}-{key}.npz"          # keyed by the pixels used
    assert len(said) == 1 and "about 169 CNN ratings 5.3 m (21 px) apart" in said[0], said


def test_the_default_worlds_pixel_strides_and_cache_key_are_unchanged(worlds, cnn, tmp_path, capsys):
    """Guidance's cached map: 5.3 m = 10 px (the cache file of before the stride was in metres); the
    build command's default: 2.65 m = 5 px."""
    from scenenav.app.launcher import resolve_guidance_map
    from scenenav.app.scenario import load_scenario
    folder = worlds[DEFAULT_M_PER_PX]
    cfg = load_scenario(None, (f"world={folder}", "flight.mode=autopilot", "guidance.enabled=true",
                               "guidance.goals_enu_m=[[10, 10]]"))
    path = resolve_guidance_map(cfg, progress=True).guidance.assistant_map
    assert "CNN ratings 5.3 m (10 px) apart" in capsys.readouterr().err     # the build notice
    assert AssistantMap.load(path).stride_px == 10
    old_key = cache_key(folder, DEFAULT_WEIGHTS_PATH, 10, cfg.flight.altitude_m, cfg.sim.camera.fov_deg,
                        relief=False, reference=cfg.perception.reference)
    assert path.endswith(f"{folder.name}-{old_key}.npz")
    amap, _ = build_world_map(str(folder), str(tmp_path / "m.npz"), progress=False, png=False, relief=False)
    assert amap.stride_px == 5 and amap.stride_px * DEFAULT_M_PER_PX == pytest.approx(BUILD_STRIDE_M)


@pytest.mark.parametrize("stride_m", [0.0, -5.3, float("nan"), float("inf"), 1e9])
def test_a_bad_stride_is_one_line(worlds, cnn, tmp_path, stride_m):
    with pytest.raises(UserError) as cached:
        cached_assistant_map(worlds[FINE_M_PER_PX], stride_m=stride_m)
    with pytest.raises(UserError) as built:
        build_world_map(str(worlds[FINE_M_PER_PX]), str(tmp_path / "m.npz"), stride_m=stride_m)
    for exc, key in ((cached, "stride_m"), (built, "--stride-m")):
        text = str(exc.value)
        assert "\n" not in text and text.startswith(f"{key} = ") and "metres" in text, text
    assert cnn.rated == 0


def test_a_stride_in_pixels_from_an_older_scenario_still_loads_and_means_pixels(worlds, cnn, capsys):
    """Run folders from before the stride was in metres hold guidance.assistant_map_stride_px: they
    load, and the fine world gets the pixels they name (not 5.3 m); both keys at once are refused."""
    from scenenav.app.launcher import resolve_guidance_map
    from scenenav.app.scenario import load_scenario
    folder = worlds[FINE_M_PER_PX]
    base = (f"world={folder}", "flight.mode=autopilot", "guidance.enabled=true", "guidance.goals_enu_m=[[10, 10]]")
    cfg = load_scenario(None, (*base, "guidance.assistant_map_stride_px=8"))
    path = resolve_guidance_map(cfg, progress=True).guidance.assistant_map
    assert AssistantMap.load(path).stride_px == 8
    assert "(8 px) apart" in capsys.readouterr().err
    with pytest.raises(UserError, match="assistant_map_stride_px"):
        load_scenario(None, (*base, "guidance.assistant_map_stride_px=8", "guidance.assistant_map_stride_m=4"))
