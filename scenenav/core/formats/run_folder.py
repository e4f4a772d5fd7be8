"""Names of the files in a run folder that more than one process reads or writes.

``mavlink.json``: written by the autopilot node once its MAVLink links are bound (atomically, JSON
object ``{"tcp_host": str | null, "tcp_port": int | null, "udp_port": int | null, "udp_out":
"HOST:PORT" | null, "udp_bind_host": str | null, "system_id": int}``, null for a link that is off);
read by the launcher (into run.json), the guidance node (the port it connects to), ``scenenav sitl``
and the soak benchmark.

``hub.json``: written by the simulator node once its Zenoh hub listens (``{"hub_port": int}``); the
launcher waits for it before it writes run.json.
"""

from __future__ import annotations

#: The autopilot's bound MAVLink endpoints (module docstring).
MAVLINK_FILE = "mavlink.json"
#: The simulator's Zenoh hub is listening (module docstring).
HUB_FILE = "hub.json"
