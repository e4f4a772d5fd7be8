"""The launcher's perception swap schedule (``perception.swap_at_s`` / ``swap_every_s``).

The swap's state machine is driven here with the launcher's own ``PerceptionSwap`` over a run folder
whose ``fixes.csv`` the test writes, and a Launch whose ``spawn`` records instead of starting nodes;
the real swap on a live bus is flown by tests/e2e/test_perception_swap.py.
"""

from __future__ import annotations

from support.fake_launch import FakeLaunch as _Launch

from scenenav.app.launcher import SWAP_NODE_ID, PerceptionSwap
from scenenav.app.scenario import load_scenario


def _fix(run_dir, node: str) -> None:
    with (run_dir / "fixes.csv").open("a") as f:
        f.write(f"1.0,1,{node},cnn,1,1,0,0\n")


def test_swaps_repeat_back_and_forth_make_before_break(tmp_path):
    cfg = load_scenario(None, ("perception.method=cnn", "perception.swap_at_s=10",
                               "perception.swap_every_s=20", "perception.swap_method=statistical"))
    launch = _Launch(tmp_path)
    first = launch.spawn("perception", ["perception"])
    swap = PerceptionSwap(launch, cfg)
    swap.poll(5.0)
    assert len(launch.children) == 1                      # not yet
    swap.poll(10.0)
    second = launch.children[-1]
    assert second.name == SWAP_NODE_ID and second.args[-1] == "statistical"
    swap.poll(11.0)
    assert first.proc.poll() is None                      # kept until the new node answers
    _fix(tmp_path, SWAP_NODE_ID)
    swap.poll(12.0)
    assert first.proc.poll() is not None and second.proc.poll() is None
    swap.poll(25.0)
    assert len(launch.children) == 2                      # next swap at 30 s
    _fix(tmp_path, "perception")                          # an old row does not count as an answer
    swap.poll(30.0)
    third = launch.children[-1]
    assert third.name == "perception" and third.args[-1] == "cnn"
    swap.poll(31.0)
    assert second.proc.poll() is None
    _fix(tmp_path, "perception")
    swap.poll(32.0)
    assert second.proc.poll() is not None and third.proc.poll() is None
    assert swap.swaps == 2 and not swap.done


def test_one_swap_without_swap_every_s(tmp_path):
    cfg = load_scenario(None, ("perception.swap_at_s=10",))
    launch = _Launch(tmp_path)
    launch.spawn("perception", ["perception"])
    swap = PerceptionSwap(launch, cfg)
    swap.poll(10.0)
    _fix(tmp_path, SWAP_NODE_ID)
    swap.poll(11.0)
    assert swap.done
    swap.poll(100.0)
    assert len(launch.children) == 2


def test_a_swap_whose_new_node_dies_is_abandoned_and_the_old_node_kept(tmp_path):
    cfg = load_scenario(None, ("perception.swap_at_s=10", "perception.swap_every_s=20"))
    launch = _Launch(tmp_path)
    first = launch.spawn("perception", ["perception"])
    swap = PerceptionSwap(launch, cfg)
    swap.poll(10.0)
    second = launch.children[-1]
    second.proc.die(1)                                   # crashed while loading
    swap.poll(11.0)
    assert first.proc.poll() is None                     # still in charge, not stopped for nothing
    swap.poll(29.0)
    assert len(launch.children) == 2                     # the next swap keeps its schedule
    swap.poll(30.0)
    assert launch.children[-1].name == SWAP_NODE_ID and swap.swaps == 2
