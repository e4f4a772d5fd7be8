"""The example perception node (examples/perception_node_python/node.py) with chosen contract rules
broken, for ``scenenav node check``'s tests: ``python broken_perception_node.py --break RULE,...
RUN_DIR``. RULE: ``ack`` (one frame is never acknowledged), ``timestamp`` (fixes carry the publish
time instead of the capture time), ``covariance`` (valid fixes have an asymmetric covariance),
``malformed`` (the node dies on a malformed camera frame)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples" / "perception_node_python"))
import node as example  # noqa: E402

BREAKS = ("ack", "timestamp", "covariance", "malformed")
SKIPPED_ACK_NTH = 5      # ``ack``: the 5th frame the node sees is never acknowledged
LATENCY_US = 50_000      # ``timestamp``: the camera's publication delay, added to the capture time


def break_node(breaks: set[str]) -> None:
    cls = example.PerceptionNode
    if "ack" in breaks:
        publish_ack = cls.publish_ack

        def skip_one(self, header):
            self.seen_frames = getattr(self, "seen_frames", 0) + 1
            if self.seen_frames != SKIPPED_ACK_NTH:
                publish_ack(self, header)
        cls.publish_ack = skip_one
    if "timestamp" in breaks or "covariance" in breaks:
        publish_fix = cls.publish_fix

        def bent(self, fix):
            fix = dict(fix)
            if "timestamp" in breaks:
                fix["timestamp_us"] += LATENCY_US
            if "covariance" in breaks and fix["valid"]:
                c = fix["covariance_xy_m2"]
                fix["covariance_xy_m2"] = [c[0], 1.0, 0.0, c[3]]
            publish_fix(self, fix)
        cls.publish_fix = bent
    if "malformed" in breaks:
        on_camera = cls.on_camera

        def die(self, sample):
            try:
                example.decode_camera_frame(sample.payload.to_bytes())
            except ValueError:
                os._exit(3)       # a node that crashes on garbage
            on_camera(self, sample)
        cls.on_camera = die


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--break", dest="breaks", required=True)
    args, rest = p.parse_known_args()
    chosen = set(args.breaks.split(","))
    assert chosen <= set(BREAKS), chosen
    break_node(chosen)
    sys.exit(example.main(rest))
