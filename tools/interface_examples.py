"""Print the worked examples of docs/interfaces.md, made with the real codec.

``PYTHONPATH=. python tools/interface_examples.py`` prints, per bus message, its JSON payload as
``scenenav.core.contracts.encode`` writes it (and for CameraFrame a hex dump of the length prefix and
header); paste the output into docs/interfaces.md section 10. tests/unit/app/test_docs.py decodes
every example of the page with the real codec, so the examples stay true.
"""

from __future__ import annotations

import math

import numpy as np

from scenenav.core import contracts as c

NAN = math.nan


def examples() -> list:
    """One message of each type with plausible values (a GPS-denied flight at 100 m)."""
    return [
        c.ClockTick(1_230_000, 123, 10_000, 11, "lockstep", "running"),
        c.ImuSample(1_230_000, 123, 0.01, (0.02, -0.01, 9.81), (0.001, 0.0, -0.002)),
        c.BaroSample(1_250_000, 100.42, 100124.5),
        c.CompassSample(1_250_000, 1.5708),
        c.GpsSample(1_200_000, 48.1374, 11.5755, 100.3, (2.0, 0.5, 0.0), 1.2, 2.0, 3, 12),
        c.PowerSample(1_200_000, 15.84, 21.3),
        c.FlowSample(1_200_000, 100_000, (0.012, 0.061), (-0.004, 0.002), 24.6, 212),
        c.MotorCommand(1_230_000, 123, (0.52, 0.52, 0.51, 0.51), True, "autopilot"),
        c.LockstepAck(1_200_000, "my_matcher", "camera", 12),
        c.VisionFix(1_200_000, 12, "my_matcher", "example-ncc", True, True, (61.25, -94.8),
                    (2.25, 0.1, 0.1, 2.56), NAN, (NAN, NAN, NAN, NAN), 0.71, 11.2, 0.62,
                    3.1, 18.4, 0.0, 0.0, 21.9, NAN, NAN, (0.006, 0.083), 100_000, 0.87),
        c.NavEstimate(1_230_000, (61.0, -95.1, 99.8), (2.0, 0.4, 0.0), (0.7071, 0.0, 0.0, -0.7071),
                      1.5708, (1.5, 1.6, 0.3), 6, "my_matcher"),
        c.AutopilotStatus(1_000_000, True, "AUTO", False, 2, 4, False, False),
        c.TruthPose(1_230_000, (60.7, -95.0, 100.1), (2.1, 0.4, 0.0), (0.7071, 0.0, 0.0, -0.7071),
                    (0.0, 0.0, 0.001), 1.5709),
        c.NodeInfo(0, "my_matcher", "perception", "example-ncc"),
        c.Event(1_230_000, "autopilot", 6, "vision: following my_matcher"),
    ]


def camera_frame() -> c.CameraFrame:
    f_px = 100.0 / math.tan(math.radians(30.0))
    return c.CameraFrame(1_200_000, 12, 200, 200, "rgb8", 60.0, "gimbal",
                         (round(f_px, 3), round(f_px, 3), 100.0, 100.0), (0.0, 0.0, 0.0, 0.0),
                         pixels=np.zeros((200, 200, 3), np.uint8))


def hex_dump(data: bytes) -> str:
    lines = []
    for off in range(0, len(data), 16):
        chunk = data[off:off + 16]
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        lines.append(f"{off:08x}  {chunk.hex(' '):<47}  {text}")
    return "\n".join(lines)


def markdown() -> str:
    out = []
    for msg in examples():
        name = type(msg).__name__
        out += [f"**{name}**", "", "```json", c.encode(msg).decode(), "```", ""]
    frame = c.encode(camera_frame())
    n = int.from_bytes(frame[:4], "little")
    out += ["**CameraFrame** (200 x 200 rgb8: 4 + "
            f"{n} header bytes, then 200 x 200 x 3 = 120000 pixel bytes; the length prefix and header):", "",
            "```text", hex_dump(frame[:4 + n]), "```", ""]
    return "\n".join(out)


if __name__ == "__main__":
    print(markdown(), end="")
