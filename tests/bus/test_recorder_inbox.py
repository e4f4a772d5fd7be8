"""The recorder's inbox (``Bus.subscribe_inbox``): Zenoh's receive thread only queues, the recorder's
thread writes in batches; nothing is lost, also what arrived just before a stop."""

import time

from scenenav.app.recorder import RecorderNode, count_mcap_messages
from scenenav.app.scenario import RecorderConfig
from scenenav.core.bus import Bus, BusConfig, free_port
from scenenav.core.contracts import ClockMode, ClockTick, ImuSample, LockstepRole, RunState, TruthPose
from scenenav.core.keys import Keys
from tests.support.lineproc import wait_until


def _wait(cond) -> bool:
    return wait_until(cond, timeout_s=10.0, period_s=0.02)


def test_inbox_keeps_order_across_keys_and_ends_empty_after_close():
    port = free_port()
    hub = Bus(BusConfig("ib", port, listen_hub=True))
    node = Bus(BusConfig("ib", port))
    k = Keys("ib")
    try:
        inbox = node.subscribe_inbox(k.everything, 1024)
        seen = []
        hub.watch_liveliness(k.lockstep_member_all, lambda key, a: seen.append(a))
        node.declare_token(k.lockstep_member(LockstepRole.TICK, "n1"))
        assert _wait(lambda: seen == [True])
        for i in range(50):
            hub.publish(k.imu, ImuSample(i, i, 0.01, (0.0, 0.0, 9.8), (0.0, 0.0, 0.0)))
            hub.publish(k.clock, ClockTick(i, i, 10_000, -1, ClockMode.LOCKSTEP.value,
                                           RunState.RUNNING.value))
        got: list[str] = []

        def take_all() -> bool:
            while (item := inbox.take()) is not None:
                got.append(item[1])
            return len(got) == 100
        assert _wait(take_all)
        assert got == [k.imu, k.clock] * 50        # one publisher session: published order
        node.close()
        assert inbox.take() is None                # closed and empty: None, no exception
    finally:
        node.close()
        hub.close()


def test_recorder_writes_what_arrived_before_its_stop(tmp_path, monkeypatch):
    import scenenav.app.recorder as recorder
    monkeypatch.setattr(recorder, "DRAIN_PERIOD_S", 3600.0)   # only the stop drains
    port = free_port()
    hub = Bus(BusConfig("rb", port, listen_hub=True))
    k = Keys("rb")
    rec = RecorderNode(tmp_path, RecorderConfig(truth_every_n_ticks=1), BusConfig("rb", port))
    try:
        up = []
        hub.watch_liveliness(k.node_alive_all, lambda key, a: up.append(key))
        assert _wait(lambda: k.node_alive("recorder", "recorder") in up)
        n = 300
        for i in range(n):
            hub.publish(k.truth_pose, TruthPose(i * 10_000, (0.0, 0.0, float(i)), (0.0, 0.0, 0.0),
                                                (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0))
        hub.put_raw(k.imu, b"not json")
        time.sleep(1.0)                 # delivered into the inbox, not yet written
        assert rec.counts == {}
    finally:
        info = rec.close()          # drains the inbox before the files close
        hub.close()
    assert info["counts"]["TruthPose"] == n and info["dropped"] == 1
    rows = (tmp_path / "truth.csv").read_text().splitlines()
    assert len(rows) == n + 1
    assert count_mcap_messages(tmp_path / "bus.mcap") >= n
