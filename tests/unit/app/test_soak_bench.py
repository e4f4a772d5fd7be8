"""The soak benchmark's parts: the MAVLink fuzzer keeps its rate per simulated minute when the run is
faster than real time (and per wall minute when slower), sending real bytes to a TCP port; the fd
figure is a floor, so transient sockets do not count as growth and a leak does."""

import json
import socket
import threading
import time

from scenenav.app.bench.soak import FD_FLOOR_SAMPLES, Fuzzer, RoleFigures, Sample, SoakConfig


def test_due_follows_the_faster_of_the_two_clocks(tmp_path):
    f = Fuzzer(tmp_path, SoakConfig(fuzz_frames_per_min=6000))
    assert f.due(wall_s=60.0, sim_s=30.0) == 6000
    assert f.due(wall_s=30.0, sim_s=120.0) == 12000
    assert f.due(0.0, 0.0) == 0


def test_the_fuzzer_catches_up_with_simulated_time(tmp_path):
    server = socket.create_server(("127.0.0.1", 0))
    received = bytearray()

    def serve():
        conn, _ = server.accept()
        conn.settimeout(5.0)
        try:
            while chunk := conn.recv(65536):
                received.extend(chunk)
        except OSError:
            pass
    threading.Thread(target=serve, daemon=True).start()
    (tmp_path / "mavlink.json").write_text(json.dumps({"tcp_port": server.getsockname()[1]}))
    (tmp_path / "truth.csv").write_text("t_s,x\n600.0,1\n")      # 10 simulated minutes already
    f = Fuzzer(tmp_path, SoakConfig(fuzz_frames_per_min=600))
    f.start()
    time.sleep(1.5)
    f.stop.set()
    f.join(5)
    # by wall time alone ~15 frames were due; by simulated time 6000: it sends up to a second's
    # worth (10) every 0.1 s to catch up
    assert 40 <= f.sent <= 6000
    assert f.sim_s == 600.0
    time.sleep(0.2)
    assert len(received) > f.sent      # every frame has at least one byte
    server.close()


def _figures(minute_5_fds, end_fds):
    fig = RoleFigures("autopilot")
    for i, n in enumerate(minute_5_fds):
        fig.add(Sample(300.0 + i, 150.0, n), baseline=True, end=True)
    for i, n in enumerate(end_fds):
        fig.add(Sample(1700.0 + i, 150.0, n), baseline=True, end=True)
    return fig


def test_transient_fds_are_not_growth_but_a_raised_floor_is():
    transient = [31, 33, 35, 31, 33, 31]
    assert len(transient) == FD_FLOOR_SAMPLES
    assert _figures(transient, [33, 31, 35, 31, 32, 33]).fd_growth == 0
    assert _figures(transient, [32, 34, 33, 36, 32, 33]).fd_growth == 1     # never back to 31
    fig = _figures(transient, [33, 31, 35, 31, 32, 33])
    assert fig.at_minute_5.sim_time_s == 300.0 and fig.at_end.sim_time_s == 1705.0


def test_fd_kinds_name_what_a_process_holds_and_the_floor_samples_keep_theirs():
    import os
    import socket

    from scenenav.app.bench.soak import fd_kind, fd_kinds
    assert [fd_kind(t) for t in ("socket:[123]", "pipe:[9]", "anon_inode:[eventfd]", "/dev/shm/x.zenoh",
                                 "/dev/null", "/tmp/run/bus.mcap", "net:[1]")] == \
        ["socket", "pipe", "anon", "shm", "dev", "file", "other"]
    before = fd_kinds(os.getpid())
    s = socket.socket()
    try:
        assert fd_kinds(os.getpid()).get("socket", 0) == before.get("socket", 0) + 1
    finally:
        s.close()
    fig = RoleFigures("recorder")
    fig.add(Sample(300.0, 150.0, 33, {"socket": 20}), baseline=True, end=False)
    fig.add(Sample(301.0, 150.0, 31, {"socket": 18}), baseline=True, end=False)
    fig.add(Sample(1700.0, 150.0, 32, {"socket": 19, "file": 1}), baseline=False, end=True)
    fig.add(Sample(1701.0, 150.0, 34, {"socket": 21}), baseline=False, end=True)
    assert fig.kinds_minute_5 == {"socket": 18} and fig.kinds_end == {"socket": 19, "file": 1}


def test_tcp_sockets_name_listeners_and_connections_by_port():
    import os
    import socket

    from scenenav.app.bench.soak import tcp_sockets
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    client = socket.create_connection(("127.0.0.1", port))
    accepted, _ = server.accept()
    try:
        named = tcp_sockets(os.getpid(), {port: "mavlink"})
        assert named.get("listen", 0) >= 1
        assert named.get("established mavlink", 0) == 2      # both ends of the connection are ours
        unnamed = tcp_sockets(os.getpid())
        assert unnamed.get("established peer", 0) >= 2
    finally:
        for s in (client, accepted, server):
            s.close()
    assert tcp_sockets(2 ** 22 + 7) == {}                      # no such process
