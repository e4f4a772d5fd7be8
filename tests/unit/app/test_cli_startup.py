"""The processes of a run start light: ``scenenav run|node|sitl|summarize`` build their parser without
the domain packages' commands (whose registration imports torch), and that parser is the same one
the whole ``scenenav`` parser holds for them."""

import argparse
import subprocess
import sys

import pytest

from scenenav.app.cli import (
    _BENCH_MODULES,
    _DOMAIN_COMMAND_MODULES,
    _OWN_BENCHES,
    _OWN_COMMANDS,
    _command_of,
    build_parser,
)


def _subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices[name]


@pytest.mark.parametrize("command", sorted(_OWN_COMMANDS))
def test_own_command_parsers_are_the_same_without_the_domain_commands(command):
    full, light = build_parser(), build_parser(domain_commands=False)
    assert _subparser(light, command).format_help() == _subparser(full, command).format_help()
    assert set(_subparser(full, "bench")._actions[-1].choices) > set(_subparser(light, "bench")._actions[-1].choices)


@pytest.mark.parametrize("command", sorted(_DOMAIN_COMMAND_MODULES) + ["bench"])
def test_a_domain_command_alone_has_the_same_parser_as_in_the_whole_one(command):
    full, light = build_parser(), build_parser(domain_commands=command)
    assert _subparser(light, command).format_help() == _subparser(full, command).format_help()
    others = set(_DOMAIN_COMMAND_MODULES) - {command}
    if command != "bench":
        same_module = {c for c, m in _DOMAIN_COMMAND_MODULES.items() if m == _DOMAIN_COMMAND_MODULES[command]}
        others -= same_module
    (sub,) = [a for a in light._actions if isinstance(a, argparse._SubParsersAction)]
    assert not others & set(sub.choices)          # the other domain modules were not registered


@pytest.mark.parametrize("name", sorted(_BENCH_MODULES) + sorted(_OWN_BENCHES))
def test_one_benchmark_alone_has_the_same_parser_as_in_the_whole_one(name):
    full, light = build_parser(), build_parser(domain_commands="bench", bench=name)
    full_bench, light_bench = _subparser(full, "bench"), _subparser(light, "bench")
    assert _subparser(light_bench, name).format_help() == _subparser(full_bench, name).format_help()
    assert set(_subparser(light, "bench")._actions[-1].choices) == _OWN_BENCHES | {name}


def test_the_command_is_found_after_the_global_option():
    assert _command_of(["--log-level", "INFO", "node", "sim"]) == "node"
    assert _command_of(["--log-level=DEBUG", "run", "--out", "x"]) == "run"
    assert _command_of(["plan", "--world", "w"]) == "plan"
    assert _command_of(["--help"]) is None and _command_of([]) is None


def test_a_node_process_parses_its_arguments_without_torch():
    code = ("import sys; from scenenav.app import cli; sys.argv = ['scenenav', '--log-level', 'INFO', "
            "'node', 'sim', '--help']\n"
            "try:\n    cli.main()\nexcept SystemExit:\n    pass\n"
            "print('torch' in sys.modules, 'scipy' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "--namespace" in r.stdout                      # the node's own help was printed
    assert r.stdout.strip().splitlines()[-1] == "False False"
    # the whole parser (any other command) still registers the domain commands: the planner's
    # benchmark imports scipy; the CNN's commands know the network without torch (cnn_spec)
    r = subprocess.run([sys.executable, "-c", code.replace("'node', 'sim', '--help'", "'--help'")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "campaign" in r.stdout and r.stdout.strip().splitlines()[-1] == "False True"


@pytest.mark.parametrize("command", [["cnn", "info"], ["train"], ["experiment", "table2"], ["bench", "e2e"]])
def test_commands_that_do_not_run_the_network_parse_without_torch(command):
    code = ("import sys; from scenenav.app import cli; sys.argv = ['scenenav', *sys.argv[1:], '--help']\n"
            "try:\n    cli.main()\nexcept SystemExit:\n    pass\n"
            "print('torch' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code, *command], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "usage: scenenav " + " ".join(command) in r.stdout
    assert r.stdout.strip().splitlines()[-1] == "False"
