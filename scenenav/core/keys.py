"""Every Zenoh key expression of scenenav, in one place.

All keys of a run live under ``scenenav/<namespace>/`` so parallel runs and tests never cross-talk
(each also has its own ports, see scenenav.core.bus). ``truth/`` keys carry ground truth and are read
only by evaluation and logging.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from scenenav.core.contracts import LockstepRole

ROOT = "scenenav"
_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")


def check_name(kind: str, name: str) -> str:
    """Namespaces and node ids are single key chunks: letters, digits, '_' and '-'."""
    if not _NAME.match(name or ""):
        raise ValueError(f"{kind} {name!r}: expected letters, digits, '_' or '-' only")
    return name


@dataclass(frozen=True)
class Keys:
    """Key expressions for one namespace."""

    namespace: str

    def __post_init__(self) -> None:
        check_name("namespace", self.namespace)

    @property
    def root(self) -> str:
        return f"{ROOT}/{self.namespace}"

    # simulator -> everyone
    @property
    def clock(self) -> str:              # ClockTick
        return f"{self.root}/clock"

    @property
    def imu(self) -> str:                # ImuSample
        return f"{self.root}/sensors/imu"

    @property
    def baro(self) -> str:               # BaroSample
        return f"{self.root}/sensors/baro"

    @property
    def compass(self) -> str:            # CompassSample
        return f"{self.root}/sensors/compass"

    @property
    def gps(self) -> str:                # GpsSample
        return f"{self.root}/sensors/gps"

    @property
    def power(self) -> str:              # PowerSample
        return f"{self.root}/sensors/power"

    @property
    def flow(self) -> str:               # FlowSample
        return f"{self.root}/sensors/flow"

    @property
    def camera(self) -> str:             # CameraFrame (binary)
        return f"{self.root}/sensors/camera"

    # autopilot -> simulator
    @property
    def motors(self) -> str:             # MotorCommand
        return f"{self.root}/actuators/motors"

    # lockstep protocol
    def lockstep_ack(self, node_id: str) -> str:   # LockstepAck
        return f"{self.root}/lockstep/ack/{check_name('node id', node_id)}"

    @property
    def lockstep_ack_all(self) -> str:
        return f"{self.root}/lockstep/ack/*"

    def lockstep_member(self, role: LockstepRole, node_id: str) -> str:   # liveliness token
        return f"{self.root}/lockstep/member/{role.value}/{check_name('node id', node_id)}"

    @property
    def lockstep_member_all(self) -> str:
        return f"{self.root}/lockstep/member/**"

    # perception -> autopilot, logs
    def vision_fix(self, node_id: str) -> str:     # VisionFix
        return f"{self.root}/perception/fix/{check_name('node id', node_id)}"

    @property
    def vision_fix_all(self) -> str:
        return f"{self.root}/perception/fix/*"

    # autopilot -> logs, guidance
    @property
    def nav_estimate(self) -> str:       # NavEstimate
        return f"{self.root}/autopilot/estimate"

    @property
    def autopilot_status(self) -> str:   # AutopilotStatus
        return f"{self.root}/autopilot/status"

    # node presence and events
    def node_alive(self, role: str, node_id: str) -> str:   # liveliness token
        return f"{self.root}/nodes/{check_name('role', role)}/{check_name('node id', node_id)}"

    @property
    def node_alive_all(self) -> str:
        return f"{self.root}/nodes/**"

    def node_sees(self, role: str, node_id: str, seen_role: str, seen_id: str) -> str:   # liveliness token
        """Declared by node ``role/node_id`` while it sees (has a link to) ``seen_role/seen_id``
        (scenenav.core.presence)."""
        return (f"{self.root}/mesh/{check_name('role', role)}/{check_name('node id', node_id)}/"
                f"{check_name('role', seen_role)}/{check_name('node id', seen_id)}")

    @property
    def node_sees_all(self) -> str:
        return f"{self.root}/mesh/**"

    def node_info(self, node_id: str) -> str:      # NodeInfo
        return f"{self.root}/info/{check_name('node id', node_id)}"

    @property
    def node_info_all(self) -> str:
        return f"{self.root}/info/*"

    def events(self, node_id: str) -> str:         # Event
        return f"{self.root}/events/{check_name('node id', node_id)}"

    @property
    def events_all(self) -> str:
        return f"{self.root}/events/*"

    # ground truth (evaluation and logs only)
    @property
    def truth_pose(self) -> str:         # TruthPose
        return f"{self.root}/truth/pose"

    @property
    def everything(self) -> str:
        return f"{self.root}/**"


# Message type carried by each key (for the recorder and docs). Wildcard tails use the * form.
def key_types(keys: Keys) -> dict[str, str]:
    return {
        keys.clock: "ClockTick",
        keys.imu: "ImuSample",
        keys.baro: "BaroSample",
        keys.compass: "CompassSample",
        keys.gps: "GpsSample",
        keys.power: "PowerSample",
        keys.flow: "FlowSample",
        keys.camera: "CameraFrame",
        keys.motors: "MotorCommand",
        keys.lockstep_ack_all: "LockstepAck",
        keys.vision_fix_all: "VisionFix",
        keys.nav_estimate: "NavEstimate",
        keys.autopilot_status: "AutopilotStatus",
        keys.node_info_all: "NodeInfo",
        keys.events_all: "Event",
        keys.truth_pose: "TruthPose",
    }


def type_for_key(keys: Keys, key: str) -> str | None:
    """Message type name for a concrete key, or None if the key carries no message."""
    prefix = keys.root + "/"
    if not key.startswith(prefix):
        return None
    for pattern, name in key_types(keys).items():
        if pattern.endswith("/*"):
            base = pattern[:-1]
            if key.startswith(base) and "/" not in key[len(base):]:
                return name
        elif key == pattern:
            return name
    return None
