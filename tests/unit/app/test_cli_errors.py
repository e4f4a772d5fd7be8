"""Bad input on the command line: one line `error: ...`, exit code 2, never a traceback."""

import subprocess
import sys

import pytest


def scenenav(*args):
    return subprocess.run([sys.executable, "-m", "scenenav.app.cli", *args], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize("args,needle", [
    (["run", "/nonexistent.yaml", "--out", "{tmp}/x"], "no such file"),
    (["run", "{bad_yaml}", "--out", "{tmp}/y"], "unknown key 'warp_drive'"),
    (["run", "--out", "{tmp}/z", "--set", "flight.altitude_m=-3"], "altitude_m"),
    (["run", "--out", "{tmp}/w", "--set", "world=/nonexistent/world"], "/nonexistent/world"),
    (["run", "--out", "{tmp}/v", "--set", "novalue"], "KEY=VALUE"),
    (["bench", "sim", "--sizes", "12xfoo"], "WIDTHxHEIGHT"),
    (["bench", "perception", "--gradient-refine-px", "500"], "gradient_refine_radius_px"),
    (["run", "--out", "{tmp}/g", "--set", "perception.gradient_refine_radius_px=-1"],
     "gradient_refine_radius_px"),
    (["run", "--out", "{tmp}/u", "--set", "world=generated:seed=1,warp=9"], "warp"),
    (["run", "--out", "{tmp}/o", "--set", "autopilot.params={{LAND_SPED: 1}}"], "LAND_SPED"),
    (["run", "--out", "{tmp}/n", "--set", "autopilot.params=[1, 2]"], "expected a mapping"),
    (["run", "--out", "{tmp}/t", "--set", "world=generated:seed=x"], "seed"),
    (["run", "--out", "{tmp}/s", "--set", "world=generated:width_px=10"], "width_px"),
    (["run", "--out", "{tmp}/r", "--set", "guidance.enabled=true",
      "--set", "guidance.goals_enu_m=[[0,0]]"], "flight.mode is autopilot"),
    (["run", "--out", "{tmp}/q", "--set", "guidance.enabled=true", "--set", "flight.mode=autopilot"],
     "goals_enu_m"),
    (["run", "--out", "{tmp}/p", "--set", "guidance.enabled=true", "--set", "flight.mode=autopilot",
      "--set", "guidance.goals_enu_m=[[0,0]]", "--set", "guidance.assistant_map=/nope.npz"], "/nope.npz"),
    (["run", "scenarios/gps_denied.yaml", "--out", "{tmp}/k", "--set", "autopilot.mavlink_tcp_port=0"],
     "when guidance.enabled"),
    (["run", "--out", "{tmp}/j", "--set", "clock.camera_answer_ticks=10"], "camera_answer_ticks"),
    (["run", "--out", "{tmp}/sm", "--set", "guidance.assistant_map_stride_m=-2"],
     "assistant_map_stride_m = -2.0: expected a ground distance in metres"),
    (["assistant-map", "build", "--world", "{tmp}", "--out", "{tmp}/map.npz", "--stride-m", "0"],
     "--stride-m = 0.0: expected a ground distance in metres"),
    (["assistant-map", "build", "--world", "{tmp}", "--out", "{tmp}/map.npz", "--stride-m", "nan"],
     "--stride-m = nan"),
    (["bench", "e2e", "--json", "--set", "clock.camera_answer_ticks=12"], "bench e2e --set"),
    (["bench", "e2e", "--json", "--set", "warp.drive=1"], "unknown key 'warp'"),
    (["experiment", "relief", "--world", "/nonexistent/world", "--json"], "/nonexistent/world"),
    (["sitl", "--out", "{tmp}/m", "--tcp-port", "0", "--external", "autopilot:mine"], "scenenav run --external"),
    (["sitl", "--out", "{tmp}/l", "--tcp-port", "0", "--external", "nonsense"], "ROLE:ID"),
    (["cnn", "decision-data", "--out", "{tmp}/dd", "--worlds", "101,9050"], "reserved for held-out"),
    (["cnn", "decision-data", "--out", "{tmp}/de", "--set", "flight.altitude_m=-3"], "altitude_m"),
    (["run", "--out", "{tmp}/lh", "--set", "external.listen_host=my-laptop"], "IPv4 address"),
    # TEST-NET-3: an address no interface of a test machine has
    (["run", "--out", "{tmp}/li", "--set", "external.listen_host=203.0.113.77"], "cannot listen on 203.0.113.77"),
    (["run", "--out", "{tmp}/lj", "--set", "autopilot.mavlink_tcp_host=203.0.113.78"],
     "autopilot.mavlink_tcp_host: cannot listen on 203.0.113.78"),
    (["sitl", "--out", "{tmp}/lk", "--tcp-port", "0", "--set", "external.listen_host=203.0.113.79"],
     "external.listen_host: cannot listen on 203.0.113.79"),
])
def test_one_line_error_exit_2(tmp_path, args, needle):
    bad = tmp_path / "bad.yaml"
    bad.write_text("warp_drive: 9\n")
    args = [a.format(tmp=tmp_path, bad_yaml=bad) for a in args]
    r = scenenav(*args)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert needle in lines[0]
    assert "Traceback" not in r.stderr


def test_every_subcommand_has_help(capsys):
    r = scenenav("--help")                      # the installed entry point, once
    assert r.returncode == 0
    from scenenav.app.cli import main  # each command's help through the same main()
    for cmd in ("run", "world", "node", "bench", "experiment", "assistant-map", "plan"):
        assert cmd in r.stdout
        with pytest.raises(SystemExit) as exc:
            main([cmd, "--help"])
        out = capsys.readouterr().out
        assert exc.value.code == 0 and "usage" in out.lower() and f"scenenav {cmd}" in out, cmd
