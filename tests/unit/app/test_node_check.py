"""``scenenav node check``'s rules judged on hand-made observations, and the ``external`` section."""

from __future__ import annotations

import math

import pytest

from scenenav.app.node_check import RULES, Observed, RunSide, judge, malformed_frames
from scenenav.app.scenario import load_scenario
from scenenav.core.contracts import CameraFrame, DecodeError, LockstepAck, LockstepRole, VisionFix, decode
from scenenav.core.errors import UserError
from scenenav.core.keys import Keys

KEYS = Keys("ns")
NODE = "n1"
HALF_M = (240.0, 265.0)


def _fix(seq: int, t_us: int, **changes) -> VisionFix:
    fields = dict(timestamp_us=t_us, frame_seq=seq, node_id=NODE, method="m", valid=True, accepted=True,
                  position_xy_enu_m=(10.0, -5.0), covariance_xy_m2=(4.0, 1.0, 1.0, 9.0), p_true=math.nan,
                  p_classes=(math.nan,) * 4, ncc_peak=0.8, ncc_psr=9.0, ncc_second_peak_ratio=0.5,
                  time_align_ms=1.0, time_ncc_ms=2.0, time_cnn_ms=0.0, time_lookup_ms=0.0, time_total_ms=3.0)
    fields.update(changes)
    return VisionFix(**fields)


def _good(n: int = 20) -> Observed:
    """A node that answers every frame 0.05 s after it, fix before ack, and leaves on time."""
    seen = Observed()
    seen.tokens = [(0.0, KEYS.node_alive("perception", NODE), True),
                   (0.0, KEYS.lockstep_member(LockstepRole.CAMERA, NODE), True)]
    for seq in range(n):
        t, t_us = 1.0 + seq, seq * 100_000
        seen.frames[seq] = (t, t_us)
        seen.fixes.append((t + 0.04, _fix(seq, t_us)))
        seen.acks.append((t + 0.05, LockstepAck(t_us, NODE, "camera", seq)))
    seen.injected_at, seen.last_seq_before_inject = 10.5, 10
    seen.finished_at = n + 1.0
    return seen


def _judge(seen: Observed, alive=True, code=0, left=0.3) -> dict[str, str | None]:
    """rule -> None when it passed, else its detail."""
    rules = judge(seen, KEYS, "perception", NODE, 2.0, HALF_M, alive, code, left)
    assert [r.rule for r in rules] == list(RULES)
    return {r.rule: None if r.passed else r.detail for r in rules}


def test_a_good_node_passes_every_rule():
    assert set(_judge(_good()).values()) == {None}


def test_each_defect_fails_its_own_rule():
    seen = _good()
    del seen.acks[3]                                            # frame 3 never acknowledged
    seen.fixes[5] = (seen.fixes[5][0], _fix(5, 555))            # publish time, not capture time
    seen.fixes[6] = (seen.fixes[6][0], _fix(6, 600_000, covariance_xy_m2=(4.0, 1.0, 0.0, 9.0)))
    seen.fixes[7] = (seen.fixes[7][0], _fix(7, 700_000, covariance_xy_m2=(1.0, 3.0, 3.0, 1.0)))  # not PSD
    seen.fixes[8] = (seen.fixes[8][0], _fix(8, 800_000, p_true=1.5))
    verdict = _judge(seen)
    assert {r for r, d in verdict.items() if d} == {"acks", "timestamps", "covariance", "fields"}
    assert "seq 3" in verdict["acks"] and "seq 5" in verdict["timestamps"]
    assert "seq 6: not symmetric" in verdict["covariance"] and "p_true outside [0, 1]" in verdict["fields"]
    seen.fixes[6] = (seen.fixes[6][0], _fix(6, 600_000))
    assert "seq 7: not positive semi-definite" in _judge(seen)["covariance"]


def test_a_heading_in_degrees_or_without_its_sigma_fails_fields():
    seen = _good()
    seen.fixes[4] = (seen.fixes[4][0], _fix(4, 400_000, heading_rad=1.2, heading_std_rad=0.02))   # fine
    assert _judge(seen)["fields"] is None
    seen.fixes[5] = (seen.fixes[5][0], _fix(5, 500_000, heading_rad=90.0, heading_std_rad=0.02))
    seen.fixes[6] = (seen.fixes[6][0], _fix(6, 600_000, heading_rad=1.0))
    fields = _judge(seen)["fields"]
    assert fields is not None
    assert "heading_rad outside [0, 2 pi) (radians clockwise from north, not degrees) (seq 5)" in fields
    assert "a heading_rad without a positive heading_std_rad (seq 6)" in fields


def test_missing_fix_late_ack_and_late_token():
    seen = _good()
    del seen.fixes[4]
    seen.acks[2] = (seen.frames[2][0] + 3.0, seen.acks[2][1])   # 3 s > the 2 s timeout
    del seen.tokens[1]                                          # no lockstep member token
    verdict = _judge(seen)
    assert "without a VisionFix (seq 4)" in verdict["fixes"]
    assert "later than 2 s (seq 2)" in verdict["acks"]
    assert "never declared: lockstep/member/camera/n1" in verdict["liveliness"]


def test_liveliness_is_judged_from_the_runs_side():
    late = judge(_good(), KEYS, "perception", NODE, 2.0, HALF_M, True, 0, 0.3,
                 RunSide(joined_before_clock=False, member_at_start=False))
    detail = {r.rule: r.detail for r in late if not r.passed}
    assert set(detail) == {"liveliness"}
    assert "clock did not start with" in detail["liveliness"] and "started without" in detail["liveliness"]


def test_fix_after_its_ack_fails_fixes():
    seen = _good()
    seen.fixes[1] = (seen.acks[-1][0] + 0.01, seen.fixes[1][1])     # after every later frame's ack too
    assert "after the ack for seq 1" in _judge(seen)["fixes"]


def test_a_held_fix_passes_when_it_leaves_before_the_ack_of_a_frame_at_most_1_s_younger():
    # frames every 0.1 s of capture time: a fix held for 5 frames (perception.confirm_successors 5)
    # leaves before frame 6's ack; one held past the ack of every frame within 1 s is too late
    held = _good()
    held.fixes[1] = (held.acks[6][0] - 0.01, held.fixes[1][1])
    assert _judge(held)["fixes"] is None
    stale = _good()
    stale.fixes[1] = (stale.acks[12][0] - 0.01, stale.fixes[1][1])     # frame 12: 1.1 s younger
    assert "after the ack for seq 1" in _judge(stale)["fixes"]


def test_malformed_and_leaving():
    seen = _good()
    verdict = _judge(seen, alive=False)
    assert "exited after the malformed frames" in verdict["malformed"]
    node_key = KEYS.node_alive("perception", NODE)
    blink = _good()
    blink.tokens += [(12.0, node_key, False), (12.5, node_key, True)]
    assert _judge(blink)["malformed"] is None                  # back before the end: Zenoh's link
    blink.tokens = blink.tokens[:-1]
    assert "token went away" in _judge(blink)["malformed"]
    seen.acks = [a for a in seen.acks if a[1].seq <= 10]
    assert "0 frames answered after" in _judge(seen)["malformed"]
    assert "still running" in _judge(_good(), code=None, left=None)["leaves"]
    assert "code 3" in _judge(_good(), code=3)["leaves"]
    assert "before the run ended" in _judge(_good(), code=0, left=-4.0)["leaves"]
    unfinished = _good()
    unfinished.finished_at = None
    assert "did not end" in _judge(unfinished)["leaves"]


def test_invalid_fixes_may_lack_position_and_covariance():
    seen = _good()
    seen.fixes[3] = (seen.fixes[3][0], _fix(3, 300_000, valid=False, accepted=False,
                                           position_xy_enu_m=(math.nan, math.nan),
                                           covariance_xy_m2=(math.nan,) * 4))
    assert set(_judge(seen).values()) == {None}
    seen.fixes[4] = (seen.fixes[4][0], _fix(4, 400_000, valid=False, accepted=True))
    assert "accepted without valid" in _judge(seen)["fields"]


def test_the_malformed_frames_are_malformed():
    for name, payload in malformed_frames():
        with pytest.raises(DecodeError):
            decode(CameraFrame, payload)
        assert name


def test_external_nodes_in_the_scenario():
    cfg = load_scenario(None, external=("perception:a", "guidance:b"))
    assert [m.spec for m in cfg.external.members()] == ["perception:a", "guidance:b"]
    assert [m.node_id for m in cfg.external.of_role("perception")] == ["a"]
    for spec, expected in (("perception", "ROLE:ID"), ("sim:x", "never external"),
                           ("perception:a b", "ROLE:ID"), ("recorder:r", "never external")):
        with pytest.raises(UserError, match=expected):
            load_scenario(None, external=(spec,))
    with pytest.raises(UserError, match="distinct node ids"):
        load_scenario(None, external=("perception:a", "guidance:a"))
    with pytest.raises(UserError, match="join_timeout_s"):
        load_scenario(None, ("external.join_timeout_s=0",))
    with pytest.raises(UserError, match="link_timeout_s"):
        load_scenario(None, ("external.link_timeout_s=-1",))
    assert load_scenario(None, ("external.link_timeout_s=45",)).external.link_timeout_s == 45.0
    assert load_scenario(None).external.listen_host == "127.0.0.1"
    with pytest.raises(UserError, match="listen_host"):
        load_scenario(None, ("external.listen_host=256.1.1.1",))


def test_bus_facts_name_the_remote_endpoints_only_beyond_loopback(monkeypatch):
    from scenenav.app import launcher
    local = launcher.bus_facts("ns", 7000)
    assert local == {"endpoint": "tcp/127.0.0.1:7000", "namespace": "ns", "key_prefix": "scenenav/ns"}
    one = launcher.bus_facts("ns", 7000, "192.168.5.4")
    assert one["remote_endpoints"] == ["tcp/192.168.5.4:7000"] and one["listen_host"] == "192.168.5.4"
    assert one["endpoint"] == "tcp/192.168.5.4:7000"        # nothing answers on loopback then
    assert launcher.hub_host("192.168.5.4") == "192.168.5.4"     # the hub answers only there
    assert launcher.hub_host("0.0.0.0") == launcher.hub_host("127.0.0.1") == "127.0.0.1"
    monkeypatch.setattr(launcher, "interface_addresses", lambda: ["10.1.2.3", "192.168.5.4"])
    every = launcher.bus_facts("ns", 7000, "0.0.0.0")
    assert every["remote_endpoints"] == ["tcp/10.1.2.3:7000", "tcp/192.168.5.4:7000"]


def test_a_node_listens_where_it_is_told_and_connects_to_the_hub():
    from scenenav.core.bus import BusConfig
    hub = BusConfig("ns", 7000, listen_hub=True, listen_host="0.0.0.0").zenoh_config()
    assert hub.get_json("listen/endpoints") == '["tcp/0.0.0.0:7000"]'
    assert hub.get_json("connect/endpoints") == "[]"
    node = BusConfig("ns", 7000, host="10.0.0.5", listen_host="10.0.0.9").zenoh_config()
    assert node.get_json("listen/endpoints") == '["tcp/10.0.0.9:0"]'
    assert node.get_json("connect/endpoints") == '["tcp/10.0.0.5:7000"]'
    default = BusConfig("ns", 7000).zenoh_config()
    assert default.get_json("listen/endpoints") == '["tcp/127.0.0.1:0"]'


class _Proc:
    """A process that has exited (``poll`` gives its code) from ``exits_after`` polls on."""

    def __init__(self, exits_after: int) -> None:
        self.polls = 0
        self.exits_after = exits_after
        self.returncode = None

    def poll(self):
        self.polls += 1
        if self.polls > self.exits_after:
            self.returncode = 0
        return self.returncode


class _Observer:
    def __init__(self, seen: Observed) -> None:
        self.seen = seen


@pytest.mark.parametrize("node_exits_before_end", [False, True])
def test_a_run_that_ends_right_after_the_malformed_frames(node_exits_before_end):
    """The run's clock finished within a second of the malformed frames (it raced on without the node
    after an ack timeout): a node that left after the run's end survived them; one that left before
    did not."""
    import time

    from scenenav.app.node_check import _watch
    seen = Observed()
    now = time.monotonic()
    seen.injected_at = now
    seen.tokens.append((now - 1.0, "x", True))
    seen.finished_at = now + (10.0 if node_exits_before_end else -1.0)
    alive, exited_at = _watch(_Proc(exits_after=2), _Proc(exits_after=0), _Observer(seen))
    assert exited_at is not None
    assert alive is (not node_exits_before_end)


def test_a_node_that_leaves_at_the_runs_end_while_the_launcher_closes_it_survived():
    """The malformed frames went out more than a second before the run's clock finished; the node left
    at the end while the launcher was still closing the run (CI, 2026-12-06: judged "exited after the
    malformed frames"). Leaving after the end is the normal end; leaving before it is not."""
    import time

    from scenenav.app.node_check import _watch
    for finished_offset_s, expected in ((-0.5, True), (30.0, False)):
        seen = Observed()
        now = time.monotonic()
        seen.injected_at = now - 2.0
        seen.tokens.append((now - 3.0, "x", True))
        seen.finished_at = now + finished_offset_s
        alive, exited_at = _watch(_Proc(exits_after=3), _Proc(exits_after=0), _Observer(seen))
        assert exited_at is not None and alive is expected, finished_offset_s


def test_a_token_removed_on_the_finished_tick_is_leaving_not_dying():
    # the node withdraws its token on the finished tick, as it should; that removal may arrive here
    # before the tick does (two links): after the last frame, it is the node leaving
    seen = _good()
    last_frame = max(t for t, _ in seen.frames.values())
    seen.tokens.append((last_frame + 0.5, KEYS.node_alive("perception", NODE), False))
    assert seen.finished_at > last_frame + 0.5
    assert _judge(seen)["malformed"] is None


def test_a_node_that_sent_nothing_passes_no_rule_on_what_it_sent():
    silent = _good()
    silent.fixes, silent.acks = [], []
    verdict = _judge(silent)
    for rule in ("encoding", "timestamps", "fields", "covariance"):
        assert "nothing to judge" in verdict[rule], (rule, verdict[rule])
    empty = Observed()
    verdict = _judge(empty)
    assert "no camera frame was published" in verdict["acks"]
    assert "no camera frame was published" in verdict["fixes"]
