"""docs/mavlink.md's ArduCopter compatibility table agrees with the handlers in the code.

Each row is ``| kind | name | status |``; the rows of a kind not marked "not implemented" must be
exactly what the code implements for that kind, so a handler added without its row (or a row
claimed without a handler) fails here.
"""

from __future__ import annotations

import re
from collections import Counter
from typing import cast

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support import REPO_ROOT

from autopilot_bridge import failsafe, mission, telemetry
from autopilot_bridge.mavlink_server import MavlinkServer, command_handler
from autopilot_bridge.modes import SUPPORTED_MODES
from autopilot_bridge.vehicle_interface import Vehicle

DOC = (REPO_ROOT / "docs" / "mavlink.md").read_text()
SECTION = "## ArduCopter compatibility table"
NOT_IMPLEMENTED = "not implemented"
STATUS = re.compile(r"^(as ArduCopter(: \S.*)?|differs: \S.*|not implemented)$")
KINDS = ("mode", "command", "mission item", "message in", "telemetry", "failsafe")


def table_rows() -> list[tuple[str, str, str]]:
    start = DOC.index(SECTION)
    end = DOC.find("\n## ", start + len(SECTION))
    rows = []
    for line in DOC[start:end if end >= 0 else None].splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("|") or cells[0] in ("kind", "---"):
            continue
        assert len(cells) == 3, f"row needs kind | name | status: {line!r}"
        rows.append((cells[0], cells[1], cells[2]))
    return rows


ROWS = table_rows()


def implemented(kind: str) -> set[str]:
    return {name for k, name, status in ROWS if k == kind and status != NOT_IMPLEMENTED}


def named(kind: str) -> set[str]:
    return {name for k, name, _ in ROWS if k == kind}


def test_rows_are_well_formed_and_unique():
    assert ROWS, "no compatibility table found"
    for kind, name, status in ROWS:
        assert kind in KINDS, (kind, name)
        assert STATUS.match(status), f"{kind} {name}: status {status!r}"
    duplicates = [key for key, n in Counter((k, n) for k, n, _ in ROWS).items() if n > 1]
    assert not duplicates, duplicates


def test_modes_are_every_arducopter_mode_and_supported_ones_match():
    every = {e.name.removeprefix("COPTER_MODE_") for e in mavlink2.enums["COPTER_MODE"].values()
             if not e.name.endswith("ENUM_END")}
    assert named("mode") == every
    assert implemented("mode") == {m.name for m in SUPPORTED_MODES}


def _command_id(name: str) -> int:
    value = getattr(mavlink2, f"MAV_CMD_{name}", None)
    assert isinstance(value, int), f"MAV_CMD_{name} is not a MAVLink command"
    return value


@pytest.mark.parametrize("kind", ["command", "mission item"])
def test_command_names_are_mavlink_commands(kind):
    for name in named(kind):
        _command_id(name)


def test_commands_match_the_dispatcher():
    handler = command_handler(cast(Vehicle, object()), cast(MavlinkServer, object()))
    assert {_command_id(n) for n in implemented("command")} == set(handler.supported_commands)


def test_mission_items_match_the_accepted_commands():
    assert {_command_id(n) for n in implemented("mission item")} == set(mission.ACCEPTED_COMMANDS)


@pytest.mark.parametrize("kind", ["message in", "telemetry"])
def test_message_names_are_mavlink_messages(kind):
    for name in named(kind):
        assert hasattr(mavlink2, f"MAVLINK_MSG_ID_{name}"), name


def test_messages_in_match_the_handlers():
    handled = set(MavlinkServer._HANDLERS) | set(mission.HANDLED_MESSAGES)
    assert implemented("message in") == handled


def test_telemetry_matches_the_encoders():
    assert {getattr(mavlink2, f"MAVLINK_MSG_ID_{n}") for n in implemented("telemetry")} == set(
        telemetry.STREAMABLE_MSG_IDS)


def test_failsafes_match_the_monitor():
    assert implemented("failsafe") == {k.name for k in failsafe.FailsafeKind}
