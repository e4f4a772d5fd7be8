"""external.json (scenenav.app.nodes.wait_external_nodes): ``waited_s`` is the wall time from the
start of the simulator's wait for the external nodes (the hub listens) to the arrival of the last
node's token, or to the moment the run gave up; ``joined_after_s`` the same per node; ``ended``
says how the wait ended. A fake bus delivers the liveliness tokens at chosen wall times."""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from types import SimpleNamespace

import pytest

from scenenav.app.nodes import EXTERNAL_FILE, ExternalWaitEnd, external_wait_facts, wait_external_nodes
from scenenav.app.scenario import ExternalConfig, ScenarioConfig
from scenenav.core.keys import Keys

#: Slack of a measured wall time on a loaded machine (seconds; the CI machine runs two test processes
#: on two cores, so a timer thread may be scheduled a few hundred milliseconds late).
SLACK_S = 0.3
#: The fake tokens' timers start before the wait does: by the time between the test's declaring them
#: and its call (``FakeBus.lag_s``, measured) plus at most this much inside the call (seconds).
LEAD_S = 0.02


class FakeBus:
    """Liveliness watches whose tokens the test declares, now (history) or after a delay."""

    def __init__(self, keys: Keys, up_now: tuple[str, ...] = ()) -> None:
        self.keys = keys
        self.up_now = up_now                         # ROLE:ID already up when watched
        self.watches: dict[str, object] = {}
        self.timers: list[threading.Timer] = []
        self.first_declared_s: float | None = None   # time.monotonic() of the first declare_after

    def watch_liveliness(self, key, on_change) -> None:
        self.watches[key] = on_change
        for spec in self.up_now:
            role, node_id = spec.split(":")
            if key == self.keys.node_alive(role, node_id):
                on_change(key, True)

    def declare_after(self, spec: str, delay_s: float, alive: bool = True) -> None:
        role, node_id = spec.split(":")
        key = self.keys.node_alive(role, node_id)
        if self.first_declared_s is None:
            self.first_declared_s = time.monotonic()
        timer = threading.Timer(delay_s, lambda: self.watches[key](key, alive))
        self.timers.append(timer)
        timer.start()


def _earliest(bus: FakeBus, delay_s: float, called_s: float) -> float:
    """The least ``joined_after_s`` a token declared ``delay_s`` after the bus's first declaration
    can show when the wait was called at ``called_s`` (monotonic): a loaded machine may call late."""
    assert bus.first_declared_s is not None
    return delay_s - (called_s - bus.first_declared_s) - LEAD_S


def _cfg(*nodes: str, join_timeout_s: float = 5.0) -> ScenarioConfig:
    return dataclasses.replace(ScenarioConfig(),
                               external=ExternalConfig(nodes=nodes, join_timeout_s=join_timeout_s))


def _node(up_now: tuple[str, ...] = ()) -> SimpleNamespace:
    keys = Keys("t")
    return SimpleNamespace(keys=keys, bus=FakeBus(keys, up_now))


def _facts(run_dir) -> dict:
    return json.loads((run_dir / EXTERNAL_FILE).read_text())


def test_waited_s_runs_to_the_last_token_and_each_node_has_its_own(tmp_path):
    node = _node()
    cfg = _cfg("perception:a", "guidance:b")
    unix0 = time.time()
    node.bus.declare_after("perception:a", 0.2)
    node.bus.declare_after("guidance:b", 0.5)
    t0 = time.monotonic()
    assert wait_external_nodes(node, cfg, tmp_path)
    wall_s = time.monotonic() - t0
    f = _facts(tmp_path)
    assert f["joined"] == ["perception:a", "guidance:b"] and f["missing"] == []
    assert f["ended"] == "joined"
    after = f["joined_after_s"]
    assert _earliest(node.bus, 0.2, t0) <= after["perception:a"] < 0.2 + SLACK_S, f
    assert _earliest(node.bus, 0.5, t0) <= after["guidance:b"] < 0.5 + SLACK_S, f
    assert f["waited_s"] == after["guidance:b"] <= wall_s      # the last arrival, not the file's writing
    # began_unix_s is written rounded to the millisecond, so it may read up to 0.5 ms before unix0
    assert unix0 - 0.0005 <= f["began_unix_s"] < unix0 + SLACK_S
    assert f["join_timeout_s"] == 5.0


def test_a_node_up_before_the_wait_joins_at_once(tmp_path):
    # a node started first (waiting for run.json) is delivered by the watch's history
    node = _node(up_now=("perception:a",))
    assert wait_external_nodes(node, _cfg("perception:a"), tmp_path)
    f = _facts(tmp_path)
    assert f["joined_after_s"] == {"perception:a": f["waited_s"]} and 0.0 <= f["waited_s"] < SLACK_S


def test_a_node_that_joins_leaves_and_comes_back_counts_from_its_return(tmp_path):
    node = _node()
    node.bus.declare_after("perception:a", 0.1)
    node.bus.declare_after("guidance:b", 0.15, alive=False)       # never up: a no-op departure
    node.bus.declare_after("perception:a", 0.2, alive=False)
    node.bus.declare_after("perception:a", 0.4)
    node.bus.declare_after("guidance:b", 0.3)
    t0 = time.monotonic()
    assert wait_external_nodes(node, _cfg("perception:a", "guidance:b"), tmp_path)
    f = _facts(tmp_path)
    assert _earliest(node.bus, 0.4, t0) <= f["joined_after_s"]["perception:a"] == f["waited_s"] \
        < 0.4 + SLACK_S, f


def test_a_timeout_records_the_whole_wait(tmp_path, caplog):
    node = _node()
    node.bus.declare_after("perception:a", 0.05)
    t0 = time.monotonic()
    with caplog.at_level(logging.ERROR, logger="scenenav.app.nodes"):
        assert not wait_external_nodes(node, _cfg("perception:a", "guidance:b", join_timeout_s=0.4),
                                       tmp_path)
    f = _facts(tmp_path)
    assert f["ended"] == "timeout" and f["missing"] == ["guidance:b"] and f["joined"] == ["perception:a"]
    assert 0.4 <= f["waited_s"] < 0.4 + SLACK_S, f
    assert _earliest(node.bus, 0.05, t0) <= f["joined_after_s"]["perception:a"] < 0.05 + SLACK_S
    assert "guidance:b did not join within 0.4 s" in caplog.text


def test_a_stop_ends_the_wait_promptly_and_says_so(tmp_path, caplog):
    node = _node()
    stop = threading.Event()
    timer = threading.Timer(0.1, stop.set)
    timer.start()
    with caplog.at_level(logging.INFO, logger="scenenav.app.nodes"):
        assert not wait_external_nodes(node, _cfg("perception:a"), tmp_path, stop)
    f = _facts(tmp_path)
    assert f["ended"] == "stopped" and f["missing"] == ["perception:a"]
    assert 0.1 <= f["waited_s"] < 0.1 + SLACK_S, f
    assert "did not join within" not in caplog.text and "stopped after" in caplog.text


@pytest.mark.parametrize("joined_at_s, ended_s, ended, expected", [
    ({"p:a": 10.25, "g:b": 11.0}, 11.5, ExternalWaitEnd.JOINED,
     {"joined": ["p:a", "g:b"], "missing": [], "waited_s": 1.0, "joined_after_s": {"p:a": 0.25, "g:b": 1.0}}),
    ({"p:a": 10.25}, 13.0004, ExternalWaitEnd.TIMEOUT,
     {"joined": ["p:a"], "missing": ["g:b"], "waited_s": 3.0, "joined_after_s": {"p:a": 0.25}}),
    ({}, 10.2, ExternalWaitEnd.STOPPED,
     {"joined": [], "missing": ["p:a", "g:b"], "waited_s": 0.2, "joined_after_s": {}}),
])
def test_external_wait_facts(joined_at_s, ended_s, ended, expected):
    f = external_wait_facts(["p:a", "g:b"], joined_at_s, 10.0, ended_s, ended, 1.7e9, 3.0)
    assert f == expected | {"ended": ended.value, "began_unix_s": 1.7e9, "join_timeout_s": 3.0}
