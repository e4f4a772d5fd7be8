"""Every ``--json`` command of the CLI, at tiny sizes: its stdout parses with ``json.loads`` as a whole
(no table, banner or log line before or after the document). A new ``--json`` command fails
``test_every_json_command_is_covered`` until it is added to ``COMMANDS``."""

import argparse
import json
import subprocess
import sys

import pytest

from scenenav.app.cli import build_parser

#: command words -> tiny arguments, and a key the document must hold.
COMMANDS = {
    ("bench", "sim"): (["--seconds", "1", "--sizes", "200x200"], "real_time_factor"),
    ("bench", "perception"): (["--frames", "5", "--stride-px", "60", "--map-sizes", "1000"], "methods"),
    ("bench", "plan"): (["--size", "64x64"], "results"),
    ("bench", "render"): (["--frames", "3", "--sizes", "200x200", "--identity-poses", "2"], "render_ms_median"),
    ("bench", "autopilot"): (["--hold-s", "0.2", "--settle-s", "0", "--leg-m", "10"], "hold_rms_m"),
    ("bench", "e2e"): (["--duration-s", "3", "--quiet"], "real_time_factor"),
    ("bench", "campaign"): (["--flights", "1", "--duration-s", "2"], "runs"),
    ("bench", "soak"): (["--duration-s", "20", "--baseline-s", "5", "--swap-every-s", "10",
                         "--fuzz-per-min", "600"], "no_dropped_tick"),
    ("experiment", "relief"): (["--world", "generated:seed=3,width_px=700,height_px=700", "--positions", "3",
                                "--quiet"], "comparisons"),
    ("cnn", "bench"): (["--n", "2", "--repeats", "1", "--crop-px", "64"], "single_image_ms"),
}
#: ``--json`` commands whose stdout is parsed whole by a test elsewhere (each run costs a flight).
COVERED_ELSEWHERE = {
    ("node", "check"): "tests/e2e/test_external_node.py (three node check --json runs)",
}


def _json_commands(parser: argparse.ArgumentParser, words: tuple[str, ...] = ()) -> set[tuple[str, ...]]:
    found = set()
    for action in parser._actions:
        if "--json" in action.option_strings:
            found.add(words)
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found |= _json_commands(sub, (*words, name))
    return found


def test_every_json_command_is_covered():
    assert _json_commands(build_parser()) == set(COMMANDS) | set(COVERED_ELSEWHERE)


@pytest.mark.slow
@pytest.mark.parametrize("words", sorted(COMMANDS), ids=" ".join)
def test_json_stdout_is_one_document(words):
    args, key = COMMANDS[words]
    r = subprocess.run([sys.executable, "-m", "scenenav.app.cli", *words, *args, "--json"],
                       capture_output=True, text=True, timeout=280, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr[-3000:]
    doc = json.loads(r.stdout)
    assert key in doc, doc
