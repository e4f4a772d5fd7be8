"""Presence echoes on real Zenoh peers: a node that sees another node's token says so, and the
simulator's wait for the links of external nodes ends when the run's nodes have echoed them."""

import threading
import time
from types import SimpleNamespace

from scenenav.app.nodes import wait_external_links
from scenenav.app.scenario import parse_external
from scenenav.core.bus import Bus, BusConfig, free_port
from scenenav.core.keys import Keys
from scenenav.core.presence import announce_node, parse_node_key, parse_sees_key
from tests.support.lineproc import wait_until


def _wait(cond) -> bool:
    return wait_until(cond, timeout_s=15.0, period_s=0.02)


def test_parse_keys():
    k = Keys("pr")
    assert parse_node_key(k, k.node_alive("perception", "p1")) == ("perception", "p1")
    assert parse_node_key(k, "pr/nodes/perception") is None
    assert parse_node_key(k, "other/nodes/perception/p1") is None
    key = k.node_sees("recorder", "recorder", "perception", "p1")
    assert parse_sees_key(k, key) == (("recorder", "recorder"), ("perception", "p1"))
    assert parse_sees_key(k, k.node_alive("perception", "p1")) is None


def test_each_node_echoes_the_others_and_withdraws_on_departure():
    port = free_port()
    k = Keys("pr")
    hub = Bus(BusConfig("pr", port, listen_hub=True))
    a = Bus(BusConfig("pr", port))
    b = Bus(BusConfig("pr", port))
    links = set()
    lock = threading.Lock()

    def on_sees(key, alive):
        link = parse_sees_key(k, key)
        with lock:
            (links.add if alive else links.discard)(link)

    try:
        hub.watch_liveliness(k.node_sees_all, on_sees)
        pa = announce_node(a, k, "recorder", "recorder")
        announce_node(b, k, "perception", "p1")
        ab = (("recorder", "recorder"), ("perception", "p1"))
        ba = (("perception", "p1"), ("recorder", "recorder"))
        assert _wait(lambda: ab in links and ba in links)
        assert ("perception", "p1") in pa.sees()
        assert all(seen != ("recorder", "recorder") for (_obs, seen) in links if _obs == ab[0])
        b.close()
        assert _wait(lambda: ab not in links)      # the recorder withdrew its echo of p1
        assert ("perception", "p1") not in pa.sees()
        pa.close()
    finally:
        a.close()
        b.close()
        hub.close()


def _sim(port):
    bus = Bus(BusConfig("pw", port, listen_hub=True))
    keys = Keys("pw")
    announce_node(bus, keys, "sim", "sim")
    return SimpleNamespace(bus=bus, keys=keys)


def test_wait_for_links_ends_once_every_run_node_echoed_the_external_one():
    port = free_port()
    sim = _sim(port)
    k = Keys("pw")
    recorder = Bus(BusConfig("pw", port))
    external = Bus(BusConfig("pw", port))
    try:
        announce_node(recorder, k, "recorder", "recorder")
        seen = threading.Event()
        sim.bus.watch_liveliness(k.node_alive_all, lambda key, alive: alive and "recorder" in key and seen.set())
        assert seen.wait(15)     # the recorder is a node of the run the simulator knows of
        external.declare_token(k.node_alive("perception", "mine"))    # an outside node: no echo of its own
        t0 = time.monotonic()
        left = wait_external_links(sim, [parse_external("perception:mine")], None, timeout_s=15.0)
        assert left == []
        assert time.monotonic() - t0 < 15.0
    finally:
        external.close()
        recorder.close()
        sim.bus.close()


def test_wait_for_links_gives_up_and_names_the_missing_link():
    port = free_port()
    sim = _sim(port)
    k = Keys("pw")
    silent = Bus(BusConfig("pw", port))      # a run node that does not echo
    external = Bus(BusConfig("pw", port))
    try:
        silent.declare_token(k.node_alive("autopilot", "autopilot"))
        external.declare_token(k.node_alive("perception", "mine"))
        seen = threading.Event()
        sim.bus.watch_liveliness(k.node_alive_all, lambda key, alive: alive and "autopilot" in key and seen.set())
        assert seen.wait(15)
        left = wait_external_links(sim, [parse_external("perception:mine")], None, timeout_s=1.0)
        assert left == ["autopilot:autopilot->perception:mine"]
    finally:
        external.close()
        silent.close()
        sim.bus.close()
