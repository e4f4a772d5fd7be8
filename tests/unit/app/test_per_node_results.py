"""Per-node perception results in the summary (issue 16, item 5) and the plain-words summary."""

from __future__ import annotations

import types

import numpy as np

from scenenav.app.evaluation import (
    format_summary,
    headline_method,
    perception_node_metrics,
    plain_summary,
)


def _fx(rows):
    """A fix table as fix_table returns it: (t, node, method, valid, accepted, error_m)."""
    t, node, method, valid, acc, err = zip(*rows, strict=True)
    err = np.array(err, dtype=float)
    valid = np.array(valid, dtype=float)
    return {"t_s": np.array(t, dtype=float), "node_id": np.array(node, dtype=object),
            "method": np.array(method, dtype=object), "valid": valid,
            "accepted": np.array(acc, dtype=float), "error_m": np.where(valid > 0.5, err, np.nan),
            "is_false": (valid > 0.5) & (err > 5.0), "time_total_ms": np.ones(len(t))}


SWAP = _fx([(1.0, "perception", "cnn", 1, 1, 3.0), (2.0, "perception", "cnn", 1, 1, 4.0),
            (3.0, "perception", "cnn", 1, 0, 50.0), (4.0, "perception", "cnn", 0, 0, np.nan),
            (5.0, "mine", "lightglue", 1, 1, 1.0), (6.0, "mine", "lightglue", 1, 1, 30.0),
            (7.0, "mine", "lightglue", 1, 1, 1.0)])


def test_each_node_has_its_own_row_in_the_order_it_flew():
    rows = perception_node_metrics(SWAP)
    assert [r["node_id"] for r in rows] == ["perception", "mine"]
    a, b = rows
    assert (a["fixes_total"], a["fixes_valid"], a["fixes_accepted"], a["false_fixes"]) == (4, 3, 2, 1)
    assert a["false_fixes_accepted"] == 0
    assert abs(a["fix_rms_error_accepted_m"] - np.sqrt((9 + 16) / 2)) < 1e-9
    assert (a["first_fix_s"], a["last_fix_s"], a["time_live_s"]) == (1.0, 4.0, 3.0)
    assert (b["fixes_accepted"], b["false_fixes"], b["false_fixes_accepted"]) == (3, 1, 1)
    assert abs(b["fix_rms_error_accepted_m"] - np.sqrt((1 + 900 + 1) / 3)) < 1e-9
    assert a["method"] == "cnn" and b["method"] == "lightglue"


def test_the_method_a_node_announced_wins_over_its_fixes():
    rows = perception_node_metrics(SWAP, {"mine": {"method": "my-matcher v2"}})
    assert rows[1]["method"] == "my-matcher v2" and rows[0]["method"] == "cnn"


def test_the_headline_method_names_every_node_in_order():
    cfg = types.SimpleNamespace(perception=types.SimpleNamespace(enabled=False, method="cnn"))
    assert headline_method(cfg, perception_node_metrics(SWAP)) == "cnn -> lightglue"
    # an external node alone (the built-in perception off): its own method, not null
    only = perception_node_metrics({k: v[4:] for k, v in SWAP.items()})
    assert headline_method(cfg, only) == "lightglue"
    assert headline_method(cfg, []) is None


def test_the_printed_summary_says_the_fix_figures_are_pooled_and_gives_each_node():
    summary = {"perception_nodes": perception_node_metrics(SWAP), "fixes_total": 7}
    text = format_summary(summary)
    assert "pooled over 2 perception nodes" in text
    assert "perception node mine (lightglue): 3 fixes, 3 accepted, 1 false" in text


def test_plain_summary_says_what_happened(tmp_path):
    (tmp_path / "trajectory.png").write_bytes(b"")
    summary = {"distance_flown_m": 1850.0, "sim_time_s": 260.0, "wall_time_s": 95.0, "gps_used": False,
               "fixes_total": 240, "fixes_accepted": 200, "false_fixes": 3, "false_fixes_rejected": 3,
               "false_fix_threshold_m": 5.0, "fix_rms_error_accepted_m": 1.5, "rms_error_m": 1.84,
               "max_error_m": 6.7, "route_length_m": 1900.0, "route_min_clearance_m": 10.0,
               "end_position_enu_m": [1.0, -2.0], "landed": True, "goal_enu_m": [0.0, 0.0],
               "end_distance_to_goal_m": 2.24, "mission_completed": True,
               "perception_nodes": [{"node_id": "perception", "method": "cnn"}]}
    text = plain_summary(summary, tmp_path)
    assert "1.85 km" in text and "without GPS" in text
    assert "240 fixes; 200 were accepted and 3 were false" in text
    assert "1.8 m RMS and 6.7 m at worst" in text
    assert "landed at (1, -2) m east/north, 2.2 m from the goal (0, 0)" in text
    assert "mission was completed" in text
    assert str(tmp_path / "trajectory.png") in text


def test_the_airborne_estimate_error_leaves_out_the_time_on_the_ground(tmp_path):
    """rms_error_airborne_m: only estimates taken > 1 m above the start; the whole-run figure keeps
    the time at rest (error 0 here), which dilutes it."""
    from scenenav.app.evaluation import estimate_metrics
    t = np.arange(0.0, 30.0, 0.5)
    z = np.where((t >= 10.0) & (t < 20.0), 50.0, 0.0)          # in the air from 10 to 20 s
    truth = ["t_s,x_m,y_m,z_m"] + [f"{a},0,0,{b}" for a, b in zip(t, z, strict=True)]
    est = ["t_s,x_m,y_m"] + [f"{a},{3.0 if b > 0 else 0.0},0" for a, b in zip(t, z, strict=True)]
    (tmp_path / "truth.csv").write_text("\n".join(truth) + "\n")
    (tmp_path / "estimates.csv").write_text("\n".join(est) + "\n")
    m = estimate_metrics(tmp_path)
    assert m["rms_error_airborne_m"] == 3.0 and m["max_error_airborne_m"] == 3.0
    assert m["max_error_m"] == 3.0 and abs(m["rms_error_m"] - 3.0 * np.sqrt(1 / 3)) < 1e-9
