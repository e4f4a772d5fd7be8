"""The decision-rule data path of the app layer: flight folders -> samples -> fitted model."""

from __future__ import annotations

import math

import numpy as np

from perception.decision import COMBINED_FEATURES, CombinedDecisionModel
from scenenav.app.decision_data import evaluate_flights, fit_decision, flight_dirs_under, flight_samples

K = len(COMBINED_FEATURES)


def _fake_flight(path, seed: int, n: int = 120):
    """A flight folder as the perception node and recorder write it: a straight track whose
    second half is a false lock (low peak, global search, 300 m off)."""
    from perception.assistant_map import AssistantMap
    rng = np.random.default_rng(seed)
    path.mkdir(parents=True)
    t = np.arange(n) * 0.1
    tx, ty = -50.0 + 10.0 * t, np.zeros(n)
    bad = np.arange(n) >= n // 2
    x = np.where(bad, tx + 300.0, tx + rng.normal(0, 0.2, n))
    y = ty + rng.normal(0, 0.2, n)
    mpp = 0.5
    u, v = x / mpp + 200.0, 100.0 - y / mpp
    peak = np.where(bad, rng.uniform(0.15, 0.35, n), rng.uniform(0.6, 0.9, n))
    lines = ["t_s,frame_seq,valid,accepted,x_m,y_m,p_bad"]
    lines += [f"{a:.3f},{i},1,1,{b:.3f},{c:.3f},{0.9 if k else 0.1}"
              for i, (a, b, c, k) in enumerate(zip(t, x, y, bad, strict=False))]
    (path / "fixes.csv").write_text("\n".join(lines) + "\n")
    (path / "truth.csv").write_text("t_s,x_m,y_m\n" + "\n".join(
        f"{a:.3f},{b:.3f},{c:.3f}" for a, b, c in zip(t, tx, ty, strict=False)) + "\n")
    cols = ("t_s,frame_seq,u_px,v_px,quality_ok,search,drone_u_px,drone_v_px,innovation_px,"
            "ncc_peak,ncc_psr,ncc_second_peak_ratio")
    rows = [f"{a:.3f},{i},{uu:.3f},{vv:.3f},{0 if k else 1},{'global' if k else 'window'},"
            f"{uu:.3f},{vv:.3f},{'nan' if k or i < 2 else 0.4},{pk:.3f},{3.0 if k else 9.0},"
            f"{0.95 if k else 0.3}"
            for i, (a, uu, vv, k, pk) in enumerate(zip(t, u, v, bad, peak, strict=False))]
    (path / "perception_diag_perception.csv").write_text(cols + "\n" + "\n".join(rows) + "\n")
    amap = AssistantMap(400, 200, mpp)
    amap.probability[:] = 0.5
    amap.save(path / "assistant_map_perception.npz")


def test_fit_decision_on_flight_folders(tmp_path):
    for k in range(3):
        _fake_flight(tmp_path / "flights" / f"w{k}", k)
        (tmp_path / "flights" / f"w{k}" / "summary.json").write_text("{}")
    dirs = flight_dirs_under(tmp_path)
    assert [d.name for d in dirs] == ["w0", "w1", "w2"]
    s = flight_samples(dirs[0])
    assert s.y.sum() == 60 and s.features["cnn"].shape == (120, K)
    assert s.features["assistant-map"].shape == (120, K)
    f = dict(zip(COMBINED_FEATURES, s.features["cnn"][100], strict=False))
    assert f["no_track"] == 1.0 and f["dr_innov"] > math.log(100.0)   # far from the anchor
    out = tmp_path / "model.json"
    model = fit_decision(dirs, out, "", data_manifest={"command": "test"})
    loaded = CombinedDecisionModel.load(out)
    assert loaded.model_id == model.model_id and loaded.meta["data"] == {"command": "test"}
    assert loaded.meta["training_worlds"] == ["w0", "w1", "w2"]
    res = evaluate_flights(loaded, dirs[:1])["w0"]["assistant-map"]["combined"]
    assert res["recall"] == 1.0 and res["precision"] == 1.0
    # deterministic
    assert fit_decision(dirs, tmp_path / "again.json", "").model_id == model.model_id
