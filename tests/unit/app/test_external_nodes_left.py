"""``summary["external_nodes_left"]``: an external node (not the launcher's child, so no exit code
is seen) whose token went away before the run's end is reported from the recorder's events."""

from __future__ import annotations

from scenenav.app.evaluation import external_nodes_left
from scenenav.app.scenario import load_scenario


def _events(run_dir, rows) -> None:
    lines = ["t_s,node_id,severity,text"] + [f"{t},recorder,6,{text}" for t, text in rows]
    (run_dir / "events.csv").write_text("\n".join(lines) + "\n")


def test_a_departure_before_the_end_is_reported_a_return_or_the_end_is_not(tmp_path):
    cfg = load_scenario(None, (), ("perception:outsider", "guidance:planner"))
    _events(tmp_path, [(0, "node up: perception/outsider"), (0, "node up: guidance/planner"),
                       (58.2, "node down: perception/outsider"),
                       (30.0, "node down: guidance/planner"), (31.5, "node up: guidance/planner"),
                       (120.0, "node down: guidance/planner"),           # the run's own end
                       (40.0, "node down: perception/perception")])      # not an external node
    left = external_nodes_left(tmp_path, cfg, end_s=120.0)
    assert [(e["node"], e["sim_time_s"]) for e in left] == [("perception:outsider", 58.2)]
    assert "left the run at t=58.2 s" in left[0]["what"]
    assert external_nodes_left(tmp_path, load_scenario(None), end_s=120.0) == []
    (tmp_path / "events.csv").unlink()
    assert external_nodes_left(tmp_path, cfg, end_s=120.0) == []
