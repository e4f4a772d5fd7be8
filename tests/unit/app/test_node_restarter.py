"""The launcher's ``NodeRestarter`` (``perception.max_restarts``): which failed children it starts
again, how often, and when not. Driven over a fake Launch and a run folder whose truth.csv the test
writes; the restart of a SIGKILLed perception node in a real GPS-denied flight is
tests/faults/test_fault_perception_restart.py."""

from __future__ import annotations

from support.fake_launch import FakeLaunch

from scenenav.app.launcher import SWAP_NODE_ID, NodeRestarter

ARGS = ["perception", "--run-dir", "R", "--node-id", "perception"]


def _ticked(run_dir, t_s: float) -> None:
    path = run_dir / "truth.csv"
    if not path.exists():
        path.write_text("t_s,x\n")
    with path.open("a") as f:
        f.write(f"{t_s},0\n")


def test_a_failed_perception_node_is_restarted_with_its_arguments_up_to_the_limit(tmp_path):
    launch = FakeLaunch(tmp_path)
    launch.spawn("sim", ["sim"])
    node = launch.spawn("perception", ARGS)
    r = NodeRestarter(launch, max_restarts=2, wall0=0.0)
    _ticked(tmp_path, 12.5)
    r.poll()
    assert r.restarts == []                                  # running: nothing to do
    node.proc.die(-9)
    r.poll()
    r.poll()                                                 # one death, one restart
    (again,) = launch.running("perception")
    assert again is not node and again.args == ARGS
    assert [(x.node, x.sim_time_s) for x in r.restarts] == [("perception", 12.5)]
    again.proc.die(1)
    _ticked(tmp_path, 40.0)
    r.poll()
    (third,) = launch.running("perception")
    third.proc.die(1)
    r.poll()
    assert launch.running("perception") == []                # two restarts used up
    assert [x.sim_time_s for x in r.restarts] == [12.5, 40.0]
    assert r.restarts[1].describe() == "perception restarted at t=40.0 s"


def test_no_restart_before_the_first_tick_after_a_clean_stop_or_while_another_serves(tmp_path):
    launch = FakeLaunch(tmp_path)
    node = launch.spawn("perception", ARGS)
    r = NodeRestarter(launch, max_restarts=5, wall0=0.0)
    node.proc.die(1)
    r.poll()                                                 # starting: the launcher stops the run
    assert launch.running("perception") == [] and r.restarts == []
    _ticked(tmp_path, 3.0)
    stopped = launch.spawn("perception", ARGS)
    stopped.proc.send_signal(2)                              # exit 0: asked to stop
    r.poll()
    being_stopped = launch.spawn("perception", ARGS)
    being_stopped.stopping = True                            # the launcher is stopping it
    being_stopped.proc.die(-15)
    r.poll()
    assert r.restarts == []
    launch.spawn(SWAP_NODE_ID, ARGS[:-1] + [SWAP_NODE_ID])   # a swap's node is in charge
    dead = launch.spawn("perception", ARGS)
    dead.proc.die(-9)
    r.poll()
    assert r.restarts == [] and launch.running("perception") == []
    other = launch.spawn("guidance", ["guidance"])           # only perception nodes are restarted
    other.proc.die(1)
    r.poll()
    assert launch.running("guidance") == []


def test_zero_restarts_means_never(tmp_path):
    launch = FakeLaunch(tmp_path)
    node = launch.spawn("perception", ARGS)
    _ticked(tmp_path, 5.0)
    r = NodeRestarter(launch, max_restarts=0, wall0=0.0)
    node.proc.die(-9)
    r.poll()
    assert launch.running("perception") == [] and r.restarts == []
