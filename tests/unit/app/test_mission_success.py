"""Mission success (summary ``mission_succeeded``) against mission completion, and the campaign
report's two rates: a GPS-denied mission flown on a false lock completes its route far from where
it was sent (development world 10005, session 25: "completed" 162 m from home)."""

from __future__ import annotations

import numpy as np
import pytest

from scenenav.app.campaign_report import RunData, group_table
from scenenav.app.evaluation import mission_succeeded, plain_summary
from scenenav.app.scenario import EvaluationConfig
from scenenav.core.errors import UserError


@pytest.mark.parametrize(("completed", "distance", "expected"), [
    (True, 3.0, True),        # completed at home
    (True, 20.0, True),       # on the tolerance
    (True, 162.6, False),     # completed on a false lock, far from home
    (False, 2.0, False),      # a failsafe landing near home is not a completed mission
    (True, None, True),       # no goals (a MAVLink mission, a scripted route): completion decides
])
def test_a_mission_succeeds_when_completed_within_the_tolerance_of_its_last_goal(completed, distance, expected):
    assert mission_succeeded(completed, distance, 20.0) is expected


def test_the_goal_tolerance_must_be_positive():
    assert EvaluationConfig().goal_tolerance_m == 20.0
    for bad in (0.0, -5.0, float("nan")):
        with pytest.raises((UserError, ValueError), match="goal_tolerance_m"):
            EvaluationConfig(goal_tolerance_m=bad)


def test_the_plain_summary_tells_a_completed_mission_that_did_not_succeed():
    base = {"end_position_enu_m": [150.0, -80.0], "landed": True, "goal_enu_m": [0.0, 0.0],
            "end_distance_to_goal_m": 170.0, "mission_completed": True, "goal_tolerance_m": 20.0}
    text = plain_summary(dict(base, mission_succeeded=False))
    assert "completed but did not succeed: it ended over 20 m from its last goal" in text
    assert "did not succeed" not in plain_summary(dict(base, end_distance_to_goal_m=4.0, mission_succeeded=True))


def _run(completed, succeeded):
    row = {"run_status": "ok", "mission_completed": completed, "group": "g"}
    if succeeded is not None:
        row["mission_succeeded"] = succeeded
    return RunData(row=row, est_errors_m=np.ones(3), fix_errors_m=np.ones(3))


def test_the_report_gives_completed_and_succeeded_missions_apart():
    """Four runs: completed near home, completed far off, a failsafe landing, and an old summary
    without ``mission_succeeded`` (counted as its completion)."""
    data = [_run(True, True), _run(True, False), _run(False, False), _run(True, None)]
    (group,) = group_table(data, ())
    assert group["missions completed"][0] == pytest.approx(0.75)
    assert group["mission success rate"][0] == pytest.approx(0.5)
